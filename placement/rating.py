"""The rating function RF = DOF^a * Res^b * TFV^g * TAV^d * (1 - P) (eq. 1-4).

Positions are candidate camera centres (m); the camera is assumed to point straight
at the target, as in the paper.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
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
    """A target as the rating sees it (m); ``st_error`` is eq. 4's secondary tolerance.
    A disc of ``radius``; or, with ``half_length`` > 0, a slot: a rectangle in the
    target's plane, ``half_length`` either side along ``axis`` and ``radius`` across."""

    name: str
    position: np.ndarray
    normal: np.ndarray
    radius: float
    st_error: float = 0.0
    half_length: float = 0.0
    axis: np.ndarray | None = None

    def shape(self) -> tuple[float, ...]:
        """What its outline depends on besides the plane: radius, half length, axis."""
        axis = () if self.axis is None else tuple(np.round(self.axis, 9))
        return (self.radius, self.half_length, *axis)


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


@nb.njit(cache=True, inline="always")
def _pow(x: float, e: float) -> float:
    """x ** e, without calling pow for the common exponents 1 and 0 (0 ** 0 = 1)."""
    if e == 1.0:
        return x
    if e == 0.0:
        return 1.0
    return x ** e


@nb.njit(cache=True, parallel=True)
def _rate(positions: np.ndarray, targets: np.ndarray, normals: np.ndarray, near: float,
          far: float, per_pixel: float, st_errors: np.ndarray, tfv: np.ndarray,
          occupancy: np.ndarray, w: np.ndarray, out: np.ndarray, which: np.ndarray) -> None:
    """Per candidate, the target that rates it best (the first on ties) and, in the rows
    of ``out``, that target's DOF, Res, TFV, TAV, 1 - P and RF (eq. 1-4)."""
    for i in nb.prange(len(positions)):
        free = 1.0 - occupancy[i]
        best = -1.0
        for t in range(len(targets)):
            dx = positions[i, 0] - targets[t, 0]
            dy = positions[i, 1] - targets[t, 1]
            dz = positions[i, 2] - targets[t, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            dof = 1.0 if near <= d <= far else 0.0
            res = 1.0 / (d * per_pixel + st_errors[t])
            cos = (dx * normals[t, 0] + dy * normals[t, 1] + dz * normals[t, 2]) / max(d, 1e-12)
            tav = min(max(cos, 0.0), 1.0)
            total = (_pow(dof, w[0]) * _pow(res, w[1]) * _pow(tfv[t, i], w[2])
                     * _pow(tav, w[3]) * free)
            if total > best:
                best = total
                which[i] = t
                out[0, i], out[1, i], out[2, i], out[3, i] = dof, res, tfv[t, i], tav
        out[4, i], out[5, i] = free, best


def rate_best(positions: np.ndarray, targets: Sequence[TargetModel], camera: CameraModel,
              tfv: np.ndarray, occupancy: np.ndarray, weights: Weights = Weights()
              ) -> tuple[Ratings, np.ndarray]:
    """Rate camera positions (n, 3) for every target (``tfv``: (targets, n)) in one pass;
    each keeps the target that rates it best (sec. 2.3.5). Returns the ratings and the
    index of that target per position."""
    positions = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
    out = np.empty((6, len(positions)))
    which = np.zeros(len(positions), dtype=np.int64)
    normals = np.array([np.asarray(t.normal, float) / np.linalg.norm(t.normal)
                        for t in targets])
    _rate(positions, np.array([np.asarray(t.position, float) for t in targets]), normals,
          camera.near, camera.far, 2.0 * np.tan(camera.fov / 2) / camera.pixels,
          np.array([t.st_error for t in targets], dtype=float),
          np.ascontiguousarray(np.reshape(tfv, (len(targets), len(positions))), dtype=float),
          np.ascontiguousarray(occupancy, dtype=np.float64),
          np.array([weights.alpha, weights.beta, weights.gamma, weights.delta]), out, which)
    dof, res, tfv_, tav, free, total = out
    return Ratings(positions, dof, res, tfv_, tav, free, total), which


def rate(positions: np.ndarray, target: TargetModel, camera: CameraModel, tfv: np.ndarray,
         occupancy: np.ndarray, weights: Weights = Weights()) -> Ratings:
    """Rate camera positions (n, 3) viewing ``target``. ``tfv`` is each position's target
    field visibility in [0, 1] and ``occupancy`` the probability P of its voxel."""
    return rate_best(positions, [target], camera, tfv, occupancy, weights)[0]


def rate_aimed(positions: np.ndarray, targets: Sequence[TargetModel], aims: np.ndarray,
               camera: CameraModel, tfv: np.ndarray, occupancy: np.ndarray,
               weights: Weights = Weights()) -> Ratings:
    """Rate camera positions (n, 3) each for the target it is aimed at (``aims``: an
    index into ``targets`` per position; ``tfv``: (targets, n))."""
    positions = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
    aims = np.asarray(aims)
    terms = np.empty((6, len(positions)))
    for k, target in enumerate(targets):
        mine = np.flatnonzero(aims == k)
        if len(mine):
            r = rate(positions[mine], target, camera, np.asarray(tfv)[k, mine],
                     np.asarray(occupancy)[mine], weights)
            terms[:, mine] = (r.dof, r.resolution, r.tfv, r.tav, r.free, r.total)
    return Ratings(positions, *terms)
