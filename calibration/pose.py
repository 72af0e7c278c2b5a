"""The camera's pose from fiducials (sec. 2.4): the paper's linear fit, a rigid fit, PnP.

Every estimator returns ``g01``, the 4x4 transform taking points of the common (world)
frame into the camera frame (OpenCV convention: +z forward), from fiducials known in the
world frame (``world``, n x 3) and seen by the camera: as camera-frame points from stereo
(``camera``, n x 3: (k u, k v, k f) of eq. 5, k from the disparity), and as pixels.

- ``linear`` (eq. 5-6): g01 = u (rᵀr)⁻¹ rᵀ with the 12 entries of [R | X] free; needs
  four points not in one plane. Its 3x3 block is not exactly a rotation with noisy
  data; the nearest rotation (SVD) is used and the departure reported.
- ``kabsch``: the least-squares rotation and translation (Kabsch/Umeyama, no scale);
  needs three points not on one line.
- ``sqpnp``: OpenCV's SQPnP on the pixels alone; needs three points.

Degenerate geometry raises :class:`DegenerateGeometryError` with one sentence saying why;
:func:`estimate_pose` then falls back to the next estimator and says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import CalibrationError

METHODS = ("linear", "kabsch", "sqpnp")
FLAT = 1e-3  # smallest-to-largest spread ratio below which points count as flat
FALLBACK = {"linear": ("kabsch", "sqpnp"), "kabsch": ("sqpnp",), "sqpnp": ("kabsch",)}


class DegenerateGeometryError(CalibrationError):
    """The fiducials cannot determine the pose with this estimator."""


@dataclass(frozen=True)
class PoseEstimate:
    """g01 (world to camera, 4x4), the estimator that produced it and its fit."""

    g01: np.ndarray
    method: str
    rms_px: float  # reprojection error of the fiducials
    count: int
    note: str = ""  # why a fallback was used, or the linear fit's departure from a rotation

    @property
    def pose(self) -> np.ndarray:
        """T_world_cam: the camera's pose in the world (the inverse of g01)."""
        return invert(self.g01)


def invert(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def rotation_deg(A: np.ndarray, B: np.ndarray) -> float:
    """The angle (deg) of the rotation between the rotation blocks of two poses (3x3 or
    4x4)."""
    rel = A[:3, :3].T @ B[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1.0, 1.0))))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M in the Frobenius norm."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def spread(points: np.ndarray) -> np.ndarray:
    """Singular values of the centred points, largest first (m)."""
    return np.linalg.svd(points - points.mean(axis=0), compute_uv=False)


def linear_fit(world: np.ndarray, camera: np.ndarray) -> tuple[np.ndarray, float]:
    """Eq. 6: g01 = u (rᵀr)⁻¹ rᵀ, r the homogeneous world points, u the camera points.
    Returns g01 with its rotation block made orthonormal, and how far the fitted block
    was from a rotation (Frobenius norm)."""
    n = len(world)
    if n < 4:
        raise DegenerateGeometryError(f"the linear fit needs at least 4 fiducials, got {n}")
    s = spread(world)
    if s[2] < FLAT * s[0]:
        raise DegenerateGeometryError(
            f"the {n} fiducials lie in one plane (spread {s[2] * 1e3:.2f} mm across it "
            f"against {s[0] * 1e3:.0f} mm along it), so the linear fit's r^T r is singular")
    r = np.column_stack([world, np.ones(n)])  # (n, 4)
    u = np.column_stack([camera, np.ones(n)])
    g = np.linalg.solve(r.T @ r, r.T @ u).T  # u = g r for every point, least squares
    R = nearest_rotation(g[:3, :3])
    departure = float(np.linalg.norm(g[:3, :3] - R))
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = camera.mean(axis=0) - R @ world.mean(axis=0)
    return out, departure


def kabsch(world: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """The rotation and translation minimising sum |camera - (R world + t)|^2."""
    n = len(world)
    if n < 3:
        raise DegenerateGeometryError(f"the rigid fit needs at least 3 fiducials, got {n}")
    s = spread(world)
    if s[1] < FLAT * s[0]:
        raise DegenerateGeometryError(f"the {n} fiducials lie on one line, so the rotation about "
                                 "it is undetermined")
    cw, cc = world.mean(axis=0), camera.mean(axis=0)
    U, _, Vt = np.linalg.svd((camera - cc).T @ (world - cw))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, cc - R @ cw
    return out


def sqpnp(world: np.ndarray, pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """OpenCV's SQPnP: the pose from the pixels of known world points."""
    n = len(world)
    if n < 3:
        raise DegenerateGeometryError(f"PnP needs at least 3 fiducials, got {n}")
    ok, rvec, tvec = cv2.solvePnP(world.astype(np.float64), pixels.astype(np.float64),
                                  K.astype(np.float64), None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise DegenerateGeometryError(f"SQPnP found no pose for the {n} fiducials")
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    return out


def reprojection_rms(g01: np.ndarray, world: np.ndarray, pixels: np.ndarray,
                     K: np.ndarray) -> float:
    cam = world @ g01[:3, :3].T + g01[:3, 3]
    proj = cam @ K.T
    err = proj[:, :2] / proj[:, 2:] - pixels
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def estimate_pose(world: np.ndarray, camera: np.ndarray, pixels: np.ndarray, K: np.ndarray,
                  method: str = "kabsch") -> PoseEstimate:
    """g01 by ``method``; on degenerate geometry, by its fallbacks in turn (the note says
    why). Raises DegenerateGeometryError if none can."""
    if method not in METHODS:
        raise CalibrationError(f"unknown pose estimator {method!r}; one of "
                               f"{', '.join(METHODS)}")
    reasons = []
    for m in (method, *FALLBACK[method]):
        try:
            note = ""
            if m == "linear":
                g, departure = linear_fit(world, camera)
                note = f"fitted 3x3 block {departure:.2e} from a rotation"
            elif m == "kabsch":
                g = kabsch(world, camera)
            else:
                g = sqpnp(world, pixels, K)
        except DegenerateGeometryError as exc:
            reasons.append(f"{m}: {exc}")
            continue
        if reasons:
            note = "; ".join(reasons) + f"; used {m}"
        return PoseEstimate(g, m, reprojection_rms(g, world, pixels, K), len(world), note)
    raise DegenerateGeometryError("; ".join(reasons))
