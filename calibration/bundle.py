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

import numpy as np
from scipy.optimize import least_squares
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


def _from_params(p: np.ndarray) -> np.ndarray:
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec(p[:3]).as_matrix()
    g[:3, 3] = p[3:6]
    return g


def refine(camera: StereoCamera, keyframes: list[Keyframe], points: np.ndarray,
           pixel_sigma: float = 0.3) -> BundleResult:
    """Refine the unknown keyframes' poses and the fiducials (initial ``points``)."""
    free = [k for k, f in enumerate(keyframes) if not f.known]
    n = len(points)
    obs = [(k, i, z) for k, f in enumerate(keyframes) for i, z in f.observations.items()]
    kf_idx = np.array([k for k, _, _ in obs])
    pt_idx = np.array([i for _, i, _ in obs])
    z = np.array([o[2] for o in obs])
    slot = {k: j for j, k in enumerate(free)}

    def unpack(x: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        poses = [f.g01 if f.known else _from_params(x[6 * slot[k]:6 * slot[k] + 6])
                 for k, f in enumerate(keyframes)]
        return poses, x[6 * len(free):].reshape(n, 3)

    def residuals(x: np.ndarray) -> np.ndarray:
        poses, pts = unpack(x)
        R = np.array([p[:3, :3] for p in poses])[kf_idx]
        t = np.array([p[:3, 3] for p in poses])[kf_idx]
        c = np.einsum("kij,kj->ki", R, pts[pt_idx]) + t
        u = camera.fx * c[:, 0] / c[:, 2] + camera.cx
        v = camera.fy * c[:, 1] / c[:, 2] + camera.cy
        ur = u - camera.fx * camera.baseline / c[:, 2]
        return np.concatenate([u - z[:, 0], v - z[:, 1], ur - (z[:, 0] - z[:, 2])]) / pixel_sigma

    x0 = np.concatenate([*[_to_params(keyframes[k].g01) for k in free], points.ravel()])
    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=3.0, x_scale="jac",
                        max_nfev=200)
    poses, pts = unpack(fit.x)
    r = residuals(fit.x) * pixel_sigma
    covs = []
    try:
        info = np.linalg.pinv(fit.jac.T @ fit.jac)
    except np.linalg.LinAlgError:
        info = np.full((len(fit.x), len(fit.x)), np.nan)
    for k, f in enumerate(keyframes):
        if f.known:
            covs.append(np.zeros((6, 6)))
            continue
        j = 6 * slot[k]
        # the covariance of the rotation vector and translation of g01: close enough to
        # the camera-frame perturbation the EKF takes for the small angles here
        covs.append(info[j:j + 6, j:j + 6])
    return BundleResult(poses, pts, covs, float(np.sqrt(np.mean(r ** 2))), float(fit.cost))


def triangulate(camera: StereoCamera, z: np.ndarray, g01: np.ndarray) -> np.ndarray:
    """World point of a measurement (u, v, d) from a camera at g01."""
    T = invert(g01)
    return T[:3, :3] @ camera.point(z) + T[:3, 3]
