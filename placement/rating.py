"""The rating function RF = DOF^a * Res^b * TFV^g * TAV^d * (1 - P) (eq. 1-4).

Positions are candidate camera centres (m); the camera is assumed to point straight
at the target, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """A camera as the rating sees it: field of view (rad) over ``pixels``; depth of field (m)."""

    fov: float
    pixels: int
    near: float
    far: float


@dataclass(frozen=True)
class TargetModel:
    """A target as the rating sees it (m); ``st_error`` is eq. 4's secondary tolerance."""

    name: str
    position: np.ndarray
    normal: np.ndarray
    radius: float
    st_error: float = 0.0


@dataclass(frozen=True)
class Weights:
    """Exponents of eq. 1."""

    alpha: float = 1.0
    beta: float = 1.0
    gamma: float = 1.0
    delta: float = 1.0


def depth_of_field(distance: np.ndarray, camera: CameraModel) -> np.ndarray:
    """1 inside the depth of field [near, far], 0 outside (sec. 2.3.1)."""
    return ((distance >= camera.near) & (distance <= camera.far)).astype(float)


def resolution(distance: np.ndarray, camera: CameraModel, st_error: float = 0.0) -> np.ndarray:
    """Res = 1 / R with R = 2 d tan(fov / 2) / n + ST_error (eq. 2, eq. 4), in 1/m."""
    R = 2.0 * distance * np.tan(camera.fov / 2) / camera.pixels + st_error
    return 1.0 / R


def angular_visibility(positions: np.ndarray, target: TargetModel) -> np.ndarray:
    """TAV = cos(beta) for |beta| <= 90 deg, else 0 (eq. 3)."""
    to_camera = positions - target.position
    cos = to_camera @ target.normal / np.maximum(np.linalg.norm(to_camera, axis=1), 1e-12)
    return np.clip(cos, 0.0, 1.0)


@dataclass(frozen=True)
class Ratings:
    """Each term of eq. 1, and the total, per candidate position."""

    positions: np.ndarray
    dof: np.ndarray
    resolution: np.ndarray
    tfv: np.ndarray
    tav: np.ndarray
    free: np.ndarray
    total: np.ndarray

    def terms(self, i: int) -> dict[str, float]:
        return {"total": float(self.total[i]), "dof": float(self.dof[i]),
                "resolution": float(self.resolution[i]), "tfv": float(self.tfv[i]),
                "tav": float(self.tav[i]), "free": float(self.free[i])}


def rate(positions: np.ndarray, target: TargetModel, camera: CameraModel, tfv: np.ndarray,
         occupancy: np.ndarray, weights: Weights = Weights()) -> Ratings:
    """Rate camera positions (n, 3) viewing ``target``.

    ``tfv`` is each position's target field visibility in [0, 1] and ``occupancy`` the
    probability P that its voxel is occupied.
    """
    distance = np.linalg.norm(positions - target.position, axis=1)
    dof = depth_of_field(distance, camera)
    res = resolution(distance, camera, target.st_error)
    tav = angular_visibility(positions, target)
    free = 1.0 - occupancy
    total = (dof ** weights.alpha * res ** weights.beta * tfv ** weights.gamma
             * tav ** weights.delta * free)
    return Ratings(positions, dof, res, tfv, tav, free, total)
