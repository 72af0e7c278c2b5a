"""Keeping the map current as a known object moves, from its CAD model (sec. 3, steps 1-4).

Rather than remap the scene whenever an object with a known model moves:

1. the voxels belonging to the object are identified: those its model, at its last
   known pose, passes through; they are removed (set free);
2. the points of the current view that belong to the object are fitted to the model;
3. the fit gives the object's current pose;
4. the model at that pose marks its voxels occupied.

A model is a union of boxes in the object's frame; poses are 4x4 ``T_world_object``.
A voxel belongs to the model when the model passes within half a voxel diagonal of its
centre (the voxel touches it), as a sensor would have mapped it.

A pose may come with a covariance (6x6: a rotation vector in the world frame applied on
the left, then the translation): its voxels then carry that uncertainty, the probability
that the model touches each (:func:`occupancy_of`), in freeing and occupying alike
(:func:`move_object`). Where the object lies before its first move comes from the map
(mapping/cad_prior.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import ndtr

from .errors import MappingError
from .grid import LOG_ODDS_SCALE, OccupancyGrid, stored_log_odds

FREE_SPACE_M = 0.004  # how far in front of a seen point the camera's ray counts as free


@dataclass(frozen=True)
class BoxModel:
    """Boxes in the object frame: centres and half extents (n, 3), metres."""

    centres: np.ndarray
    halves: np.ndarray

    @property
    def size(self) -> float:
        """The object's largest extent (m), the scale task tolerances refer to."""
        lo = np.min(self.centres - self.halves, axis=0)
        hi = np.max(self.centres + self.halves, axis=0)
        return float(np.max(hi - lo))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of object-frame points (n, 3) to the model: negative
        inside."""
        return self.distance_and_gradient(points)[0]

    def distance_and_gradient(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`distance` (n,) and its gradient (n, 3, a unit vector; object frame):
        that of the nearest box, away from its nearest face or edge."""
        return _box_distance(np.ascontiguousarray(np.atleast_2d(points), dtype=float),
                             np.ascontiguousarray(self.centres, dtype=float),
                             np.ascontiguousarray(self.halves, dtype=float))


@nb.njit(cache=True)
def _box_distance(points: np.ndarray, centres: np.ndarray, halves: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of each point to the nearest box (the first, on a tie) and its
    unit gradient; inside a box, towards its nearest face (the first axis, on a tie)."""
    n = points.shape[0]
    distance = np.full(n, np.inf)
    gradient = np.zeros((n, 3))
    side, beyond, out = np.empty(3), np.empty(3), np.empty(3)
    for i in range(n):
        for b in range(centres.shape[0]):
            deepest = 0
            for k in range(3):
                q = points[i, k] - centres[b, k]
                side[k] = -1.0 if q < 0.0 else 1.0
                beyond[k] = abs(q) - halves[b, k]
                out[k] = max(beyond[k], 0.0)
                if beyond[k] > beyond[deepest]:
                    deepest = k
            outside = np.sqrt((out[0] * out[0] + out[1] * out[1]) + out[2] * out[2])
            d = outside + min(beyond[deepest], 0.0)
            if not d < distance[i]:
                continue
            distance[i] = d
            for k in range(3):
                gradient[i, k] = out[k] / outside * side[k] if outside > 0.0 else 0.0
            if outside == 0.0:
                gradient[i, deepest] = side[deepest]
    return distance, gradient


@nb.njit(cache=True)
def _tangent_rows(u: np.ndarray, arm: np.ndarray) -> np.ndarray:
    """Per point (n, 6): arm x u, then -u (a signed distance's derivative by a rotation
    vector on the left and by the translation, for a world gradient u at offset arm)."""
    J = np.empty((u.shape[0], 6))
    for i in range(u.shape[0]):
        J[i, 0] = u[i, 1] * arm[i, 2] - u[i, 2] * arm[i, 1]
        J[i, 1] = u[i, 2] * arm[i, 0] - u[i, 0] * arm[i, 2]
        J[i, 2] = u[i, 0] * arm[i, 1] - u[i, 1] * arm[i, 0]
        J[i, 3], J[i, 4], J[i, 5] = -u[i, 0], -u[i, 1], -u[i, 2]
    return J


def to_object(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (n, 3) in the frame of an object at ``pose``."""
    return (np.atleast_2d(points) - pose[:3, 3]) @ pose[:3, :3]


def voxels_of(grid: OccupancyGrid, model: BoxModel, pose: np.ndarray) -> np.ndarray:
    """Boolean mask (grid shape) of the voxels the model at ``pose`` touches."""
    reach = 0.5 * np.sqrt(3) * grid.resolution
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    world = np.concatenate([(pose[:3, :3] @ (c + corners * h).T).T + pose[:3, 3]
                            for c, h in zip(model.centres, model.halves, strict=True)])
    lo = np.clip(grid.index(world.min(axis=0) - reach), 0, np.array(grid.shape) - 1)
    hi = np.clip(grid.index(world.max(axis=0) + reach), 0, np.array(grid.shape) - 1)
    mask = np.zeros(grid.shape, bool)
    if np.any(hi < lo):
        return mask
    ranges = [np.arange(a, b + 1) for a, b in zip(lo, hi, strict=True)]
    idx = np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, 3)
    near = model.distance(to_object(pose, grid.centers(idx))) <= reach
    mask[tuple(idx[near].T)] = True
    return mask


MAX_EVALUATIONS = 60  # per loss scale: a good fit takes a few dozen; a bad one never ends


def fit_residuals(model: BoxModel, pose: np.ndarray, points: np.ndarray,
               ahead: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The fit's residuals (m) at ``pose``: the points' distances to the model, then
    how deep each point ``ahead`` lies inside it (0 outside); and their derivatives by
    a rotation vector applied on the left of the pose's rotation and by its
    translation (n, 6), the parameters' tangent at ``pose``."""
    clouds = [points] if ahead is None else [points, ahead]
    values, rows = [], []
    for k, cloud in enumerate(clouds):
        arm = cloud - pose[:3, 3]  # world offsets from the object's origin
        d, g = model.distance_and_gradient(arm @ pose[:3, :3])
        J = _tangent_rows(g @ pose[:3, :3].T, arm)  # with the gradient in the world frame
        if k == 1:  # only the depth inside counts
            inside = d < 0
            d, J = np.where(inside, d, 0.0), J * inside[:, None]
        values.append(d)
        rows.append(J)
    return np.concatenate(values), np.vstack(rows)


def pose_left_jacobian(w: np.ndarray) -> np.ndarray:
    """(6, 6): how a rotation vector ``w`` and a translation map to the tangent at
    exp(w) (SO(3)'s left Jacobian, and the identity for the translation)."""
    theta = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:
        left = np.eye(3) + 0.5 * W
    else:
        left = (np.eye(3) + (1 - np.cos(theta)) / theta**2 * W
                + (theta - np.sin(theta)) / theta**3 * W @ W)
    J = np.eye(6)
    J[:3, :3] = left
    return J


def fit_model(model: BoxModel, points: np.ndarray, initial: np.ndarray,
              viewpoints: np.ndarray | None = None,
              loss_scales_m: tuple[float, ...] = (0.02, 0.005),
              give_up_median_m: float = np.inf,
              free: tuple[bool, bool, bool, bool, bool, bool] | None = None
              ) -> tuple[np.ndarray, float]:
    """The pose (4x4) that puts the world points (n, 3) on the model's surface, from
    ``initial``; and the RMS distance (m) of the points to it. Robust (soft-L1) against
    the odd point that is not the object's, coarse to fine: the first loss scale lets a
    start a few centimetres off be pulled in, the last one ignores stray points. A fit
    whose points lie a median ``give_up_median_m`` or more from the model after a stage
    is not refined further.

    With ``viewpoints`` (n, 3: the camera centre that saw each point) the space just in
    front of each point, which the camera saw through, must be outside the model: the
    points lie on the faces turned to the camera, not on the far side of a thin part.

    ``free`` says which of the six parameters the fit may change (a rotation vector in
    the world frame applied on the left, then the world translation): (False, False,
    True, True, True, False) fits only the yaw and the horizontal place of an object
    resting on a level support. None: all six."""
    pose = np.array(initial, dtype=float)
    chosen = np.ones(6, bool) if free is None else np.array(free, bool)
    ahead = None
    if viewpoints is not None:
        toward = viewpoints - points
        ahead = points + FREE_SPACE_M * toward / np.linalg.norm(toward, axis=1, keepdims=True)
    for scale in loss_scales_m:
        R0, t0 = Rotation.from_matrix(pose[:3, :3]), pose[:3, 3].copy()

        def pose_of(x: np.ndarray, R0: Rotation = R0, t0: np.ndarray = t0) -> np.ndarray:
            T = np.eye(4)
            T[:3, :3] = (Rotation.from_rotvec(x[:3]) * R0).as_matrix()
            T[:3, 3] = t0 + x[3:]
            return T

        last: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}  # the solver asks twice

        def evaluate(x: np.ndarray, pose_of: Any = pose_of,
                     last: dict[bytes, tuple[np.ndarray, np.ndarray]] = last
                     ) -> tuple[np.ndarray, np.ndarray]:
            key = x.tobytes()
            if key not in last:
                last.clear()
                last[key] = fit_residuals(model, pose_of(x), points, ahead)
            return last[key]

        def full(x: np.ndarray) -> np.ndarray:
            if chosen.all():
                return x
            every = np.zeros(6)
            every[chosen] = x
            return every

        def residuals(x: np.ndarray, evaluate: Any = evaluate) -> np.ndarray:
            return evaluate(full(x))[0]

        def jacobian(x: np.ndarray, evaluate: Any = evaluate) -> np.ndarray:
            x = full(x)
            return (evaluate(x)[1] @ pose_left_jacobian(x[:3]))[:, chosen]

        found = least_squares(residuals, np.zeros(int(chosen.sum())), jac=jacobian,
                              loss="soft_l1", f_scale=scale,
                              x_scale=np.array([0.1, 0.1, 0.1, 0.05, 0.05, 0.05])[chosen],
                              max_nfev=MAX_EVALUATIONS)
        pose = pose_of(full(found.x))
        distances = model.distance(to_object(pose, points))
        if np.median(np.abs(distances)) >= give_up_median_m:
            break
    return pose, float(np.sqrt(np.mean(distances ** 2)))


def pose_covariance(position_sd_m: float | np.ndarray, rotation_sd_rad: float | np.ndarray
                    ) -> np.ndarray:
    """A pose's 6x6 covariance from standard deviations (a scalar or one per world axis)
    of its rotation vector (rad, applied on the left: the world frame) and its position
    (m), in :func:`fit_model`'s order: rotation first, then translation."""
    sd = np.concatenate([np.broadcast_to(np.asarray(rotation_sd_rad, float), 3),
                         np.broadcast_to(np.asarray(position_sd_m, float), 3)])
    return np.diag(sd ** 2)


SPREAD_SDS = 4.0  # voxels this many of their own standard deviations beyond reach: P ~ 0


def _reach(grid: OccupancyGrid) -> float:
    """A voxel is touched by a model passing this close to its centre: half its diagonal."""
    return 0.5 * np.sqrt(3) * grid.resolution


def occupancy_of(grid: OccupancyGrid, model: BoxModel, pose: np.ndarray,
                 covariance: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The voxels (indices, (n, 3)) the model at an uncertain ``pose`` may touch and the
    probability (n,) that it does. The covariance (6x6, rotation vector on the left then
    translation, world frame, as :func:`pose_covariance`) moves the model's signed
    distance to a voxel's centre by a standard deviation sigma = sqrt(J C J^T), J its
    derivative by the pose there (the rotation's share grows with the voxel's lever arm);
    linearised, P(touched) = P(distance <= reach) = Phi((reach - d) / sigma), reach half
    a voxel diagonal as in :func:`voxels_of`: 0.5 where the model at ``pose`` just
    reaches the voxel (its surface half a voxel diagonal from the centre, not on it:
    so that a zero sd is exactly voxels_of, and a 1 cm panel in 5 cm voxels, whose centres
    lie outside it, keeps its voxels), falling across that boundary. With no (or a
    zero) covariance the probability is 1 on exactly the voxels of :func:`voxels_of`
    (and they alone are returned)."""
    reach = _reach(grid)
    C = np.zeros((6, 6)) if covariance is None else np.asarray(covariance, float)
    if C.shape != (6, 6):
        raise MappingError(f"a pose covariance is 6x6 (rotation vector, then translation), "
                           f"got shape {C.shape}")
    if not C.any():
        idx = np.argwhere(voxels_of(grid, model, pose))
        return idx, np.ones(len(idx))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    local = np.concatenate([c + corners * h for c, h in zip(model.centres, model.halves,
                                                              strict=True)])
    world = local @ pose[:3, :3].T + pose[:3, 3]
    # a bound on sigma within ``margin`` of the model: |J| <= sqrt(1 + arm^2), the
    # largest eigenvalue of C for the rest; the margin grows with the arms it reaches
    biggest = float(np.linalg.eigvalsh(C)[-1])
    lever = float(np.max(np.linalg.norm(world - pose[:3, 3], axis=1)))
    limit = float(np.max(np.array(grid.shape) * grid.resolution))  # the grid's extent
    margin = reach
    for _ in range(20):
        wider = min(reach + SPREAD_SDS * np.sqrt(biggest * (1 + (lever + margin) ** 2)), limit)
        if wider - margin < 1e-4:
            break
        margin = wider
    first, last = grid.index(world.min(axis=0) - margin), grid.index(world.max(axis=0) + margin)
    if np.any(last < 0) or np.any(first >= np.array(grid.shape)):  # wholly outside the grid
        return np.zeros((0, 3), np.int64), np.zeros(0)
    lo, hi = (np.clip(i, 0, np.array(grid.shape) - 1) for i in (first, last))
    ranges = [np.arange(a, b + 1) for a, b in zip(lo, hi, strict=True)]
    idx = np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, 3)
    centres = grid.centers(idx)
    arm = centres - pose[:3, 3]
    d, g = model.distance_and_gradient(arm @ pose[:3, :3])
    J = _tangent_rows(g @ pose[:3, :3].T, arm)
    sigma = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, C, J), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(sigma > 0, ndtr((reach - d) / np.where(sigma > 0, sigma, 1.0)),
                     (d <= reach).astype(float))
    keep = p > ndtr(-SPREAD_SDS)
    return idx[keep], p[keep]


def move_object(grid: OccupancyGrid, model: BoxModel, old: np.ndarray | None,
                new: np.ndarray | None, old_covariance: np.ndarray | None = None,
                new_covariance: np.ndarray | None = None, keep: np.ndarray | None = None
                ) -> tuple[int, int]:
    """Step 1 and 4: the voxels of the object at ``old`` become free, those at ``new``
    occupied (either may be None); returns how many voxels were freed and occupied
    (those the object at that pose touches with probability at least 0.5).

    A pose's covariance (6x6, as :func:`occupancy_of`; None: certain) spreads its
    voxels' probabilities over the boundary (:func:`occupancy_of`, p_old and p_new).
    Freeing sets a voxel to p_old clamp_min + (1 - p_old) p: free where the object
    certainly was, unchanged where it certainly was not, between where it may have been.
    Occupying raises a voxel to p_new (clipped to the clamps), never lowers it: the
    object's pose is no evidence that what else is there has gone. A voxel the new pose
    touches ends at least at p_new, whatever freeing the old did to it. Voxels in the
    boolean mask ``keep`` (grid shape; the surface the object lay on, say) are not freed.
    Without covariances this is the certain update: clamp_min on the voxels of
    :func:`voxels_of` at ``old``, then clamp_max on those at ``new``."""
    lo_min, lo_max = (int(stored_log_odds(p))
                      for p in (grid.model.clamp_min, grid.model.clamp_max))
    freed = occupied = 0
    if old is not None:
        idx, p = occupancy_of(grid, model, old, old_covariance)
        if keep is not None:
            spared = np.asarray(keep, bool)[tuple(idx.T)]
            idx, p = idx[~spared], p[~spared]
        where = tuple(idx.T)
        before = grid.log_odds[where].astype(float) / LOG_ODDS_SCALE
        after = p * grid.model.clamp_min + (1 - p) / (1 + np.exp(-before))
        stored = np.where(p >= 1.0, lo_min, stored_log_odds(np.clip(after, 1e-9, 1 - 1e-9)))
        grid.log_odds[where] = stored.astype(np.int16)
        freed = int(np.sum(p >= 0.5))
    if new is not None:
        idx, p = occupancy_of(grid, model, new, new_covariance)
        where = tuple(idx.T)
        clipped = np.clip(p, grid.model.clamp_min, grid.model.clamp_max)
        raised = np.where(p >= 1.0, lo_max, stored_log_odds(clipped))
        grid.log_odds[where] = np.maximum(grid.log_odds[where], raised).astype(np.int16)
        occupied = int(np.sum(p >= 0.5))
    return freed, occupied
