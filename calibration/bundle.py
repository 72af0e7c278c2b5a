"""Joint refinement of camera poses and fiducial positions from stereo keyframes.

A keyframe is a stereo pair taken from one camera pose: each fiducial seen in it has a
left pixel (u, v) and a disparity d (its right pixel is u - d on the same row). The
first keyframe's pose is known (before the robot moved nothing had erred); the others'
are unknown. Minimising every pixel's reprojection error over the unknown poses and the
fiducials' positions (scipy least squares, a soft-L1 loss against the odd bad match)
triangulates each fiducial from every keyframe that saw it — a baseline as long as the
camera's path, not just the head's 12 cm — and fixes the last pose from them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

from .ekf import StereoCamera
from .pose import invert


@dataclass
class Keyframe:
    """A stereo view: g01 (world to camera; the known or initial pose) and observations
    {fiducial index: (u, v, d)}."""

    g01: np.ndarray
    observations: dict[int, np.ndarray]
    known: bool = False


@dataclass(frozen=True)
class BundleResult:
    poses: list[np.ndarray]  # g01 of every keyframe, refined
    points: np.ndarray  # (n, 3) fiducial positions, refined
    pose_cov: list[np.ndarray]  # 6x6 (rotation vector, translation; camera frame) each
    rms_px: float
    cost: float


def _to_params(g01: np.ndarray) -> np.ndarray:
    return np.concatenate([Rotation.from_matrix(g01[:3, :3]).as_rotvec(), g01[:3, 3]])


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (n, 3, 3) of vectors (n, 3)."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobians (n, 3, 3) of rotation vectors (n, 3): R(w + dw) is
    exp(J dw) R(w) to first order."""
    theta = np.linalg.norm(w, axis=1)[:, None, None]
    W = _skew(w)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(safe)) / safe ** 2)
    b = np.where(small, 1 / 6, (safe - np.sin(safe)) / safe ** 3)
    return np.eye(3) + a * W + b * (W @ W)


class BundleProblem:
    """The least-squares problem: parameters x (the free keyframes' rotation vectors and
    translations, then the points), whitened residuals (u, v and right u of every
    observation, over the pixel sigma) and their sparse Jacobian, in closed form."""

    def __init__(self, camera: StereoCamera, keyframes: list[Keyframe], points: np.ndarray,
                 pixel_sigma: float) -> None:
        self.camera, self.keyframes, self.sigma = camera, keyframes, pixel_sigma
        self.free = [k for k, f in enumerate(keyframes) if not f.known]
        self.n, self.n_pose = len(points), 6 * len(self.free)
        obs = [(k, i, z) for k, f in enumerate(keyframes) for i, z in f.observations.items()]
        self.kf_idx = np.array([k for k, _, _ in obs], int)
        self.pt_idx = np.array([i for _, i, _ in obs], int)
        self.z = np.array([o[2] for o in obs]).reshape(-1, 3)
        slot = {k: j for j, k in enumerate(self.free)}
        self.pose_slot = np.array([slot.get(int(k), -1) for k in self.kf_idx], int)  # -1: known
        self.known_R = np.array([f.g01[:3, :3] for f in keyframes])
        self.known_t = np.array([f.g01[:3, 3] for f in keyframes])
        self.x0 = np.concatenate([*[_to_params(keyframes[k].g01) for k in self.free],
                                  points.ravel()])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotations (K, 3, 3) and translations (K, 3) of every keyframe; points (n, 3)."""
        R, t = self.known_R.copy(), self.known_t.copy()
        if self.free:
            params = x[:self.n_pose].reshape(-1, 6)
            R[self.free] = Rotation.from_rotvec(params[:, :3]).as_matrix()
            t[self.free] = params[:, 3:]
        return R, t, x[self.n_pose:].reshape(self.n, 3)

    def camera_points(self, x: np.ndarray) -> np.ndarray:
        R, t, pts = self.unpack(x)
        return np.einsum("kij,kj->ki", R[self.kf_idx], pts[self.pt_idx]) + t[self.kf_idx]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        cam, z = self.camera, self.z
        c = self.camera_points(x)
        u = cam.fx * c[:, 0] / c[:, 2] + cam.cx
        v = cam.fy * c[:, 1] / c[:, 2] + cam.cy
        ur = u - cam.fx * cam.baseline / c[:, 2]
        return np.concatenate([u - z[:, 0], v - z[:, 1], ur - (z[:, 0] - z[:, 2])]) / self.sigma

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        fx, fy, b = self.camera.fx, self.camera.fy, self.camera.baseline
        m, n_pose = len(self.z), self.n_pose
        R, _, _ = self.unpack(x)
        c = self.camera_points(x)
        inv = 1 / c[:, 2]
        dc = np.zeros((m, 3, 3))  # d(u, v, u_right) / d(camera point)
        dc[:, 0, 0], dc[:, 0, 2] = fx * inv, -fx * c[:, 0] * inv ** 2
        dc[:, 1, 1], dc[:, 1, 2] = fy * inv, -fy * c[:, 1] * inv ** 2
        dc[:, 2, 0], dc[:, 2, 2] = fx * inv, -fx * (c[:, 0] - b) * inv ** 2
        dc /= self.sigma
        d_point = dc @ R[self.kf_idx]
        rows, cols, vals = [], [], []
        every = np.arange(m)
        moving = np.flatnonzero(self.pose_slot >= 0)
        params = x[:n_pose].reshape(-1, 6)[self.pose_slot[moving]]
        # the camera point R X + t: d/dw = -[R X]x J_left(w), d/dt = I
        d_rot = dc[moving] @ (-_skew(c[moving] - params[:, 3:]) @ left_jacobian(params[:, :3]))
        for r in range(3):  # residual blocks: u, v, u_right
            for q in range(3):
                rows += [r * m + every, r * m + moving, r * m + moving]
                cols += [n_pose + 3 * self.pt_idx + q, 6 * self.pose_slot[moving] + q,
                         6 * self.pose_slot[moving] + 3 + q]
                vals += [d_point[:, r, q], d_rot[:, r, q], dc[moving, r, q]]
        return csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * m, n_pose + 3 * self.n))


def refine(camera: StereoCamera, keyframes: list[Keyframe], points: np.ndarray,
           pixel_sigma: float = 0.3) -> BundleResult:
    """Refine the unknown keyframes' poses and the fiducials (initial ``points``)."""
    problem = BundleProblem(camera, keyframes, points, pixel_sigma)
    fit = least_squares(problem.residuals, problem.x0, jac=problem.jacobian, loss="soft_l1",
                        f_scale=3.0, x_scale="jac", max_nfev=100, tr_solver="lsmr")
    R, t, pts = problem.unpack(fit.x)
    poses = [np.block([[R[k], t[k][:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
             for k in range(len(keyframes))]
    r = problem.residuals(fit.x) * pixel_sigma
    cov = marginal_pose_covariance(fit.jac, problem.n_pose)
    block = {k: slice(6 * j, 6 * j + 6) for j, k in enumerate(problem.free)}
    covs = [np.zeros((6, 6)) if f.known else cov[block[k], block[k]]
            for k, f in enumerate(keyframes)]
    return BundleResult(poses, pts, covs, float(np.sqrt(np.mean(r ** 2))), float(fit.cost))


def marginal_pose_covariance(jac: Any, n_pose: int) -> np.ndarray:
    """The poses' marginal covariance (n_pose x n_pose; rotation vector and translation
    of each g01) from the Jacobian of the whitened residuals: the inverse of the Schur
    complement of the fiducials' 3x3 blocks in JᵀJ (block-diagonal: a residual sees one
    fiducial), all blocks at once."""
    J = csr_matrix(jac)
    Jp, Jx = J[:, :n_pose], J[:, n_pose:]
    n_points = Jx.shape[1] // 3
    Hx = (Jx.T @ Jx).tocoo()
    same = Hx.row // 3 == Hx.col // 3
    blocks = np.zeros((n_points, 3, 3))
    np.add.at(blocks, (Hx.row[same] // 3, Hx.row[same] % 3, Hx.col[same] % 3), Hx.data[same])
    cross = _dense(Jp.T @ Jx).reshape(n_pose, n_points, 3)
    weighed = np.einsum("pia,iab->pib", cross, np.linalg.pinv(blocks))
    S = _dense(Jp.T @ Jp) - weighed.reshape(n_pose, -1) @ cross.reshape(n_pose, -1).T
    return np.asarray(np.linalg.pinv(S))


def _dense(m: Any) -> np.ndarray:
    return np.asarray(m.toarray() if hasattr(m, "toarray") else m, dtype=float)


def triangulate(camera: StereoCamera, z: np.ndarray, g01: np.ndarray) -> np.ndarray:
    """World point of a measurement (u, v, d) from a camera at g01."""
    T = invert(g01)
    return T[:3, :3] @ camera.point(z) + T[:3, 3]
