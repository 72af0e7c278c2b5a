"""Where an object lies before it is moved, from the map: the pose the CAD update starts
from (sec. 3, steps 1-4 move the object's voxels from its last known pose).

The task knows where the object was put (the scene's description: a nominal pose), to a
few centimetres and degrees (:class:`Misplacement`). What the robots mapped says where
it is. The occupied voxels near the nominal pose (their centres within reach, half a
voxel diagonal, plus the misplacement of the model there), above the surface it rests
on (:func:`support_layer`: the floor's hits share those voxels), are matched by the CAD
model in the three parameters a resting object can change, its yaw and horizontal
place; height and tilt stay the nominal's:

1. a search over the misplacement (offsets a fifth of a voxel apart, 11 yaws) for the
   pose whose model passes nearest the most voxel centres (a Gaussian kernel half a
   voxel wide on each centre's distance to the model); ties are averaged;
2. the voxels within reach (plus a quarter voxel) of the model there are the object's;
   others (a table or post beside it, within the search margin) are left out;
3. :func:`taskcam.mapping.cad.fit_model` fits the model to those centres (robust loss at the
   voxel's scale), from the search's pose.

Voxel centres are quantised: an occupied voxel says only that the object passes
somewhere within it, and its centre lies up to half a diagonal from the surface. So a
fit is poor only when its median centre is more than 0.7 voxel from the model (a good
one is at most 0.63 on grids filled by :func:`taskcam.mapping.cad.voxels_of`, 0.46 on the
default scene's maps). Its covariance treats each centre as the surface point plus
independent quantisation noise sigma_q = resolution / sqrt(12): Gauss-Newton's
(J^T J / sigma_q^2)^-1, combined with the nominal's covariance (a direction the voxels
leave free keeps the spread the search allows), plus what does not average out over
voxels: the voxel set is the same for every pose within a fraction of a voxel, so
sigma_q per horizontal axis, and in yaw sqrt(2) sigma_q over the object's horizontal
length (its two ends each quantised). On 40 maps of the default scene with the panel
put at random (5 cm voxels, nominal up to 5 cm and 10 deg off) the horizontal error
was 12 mm median, 24 mm at the 90th percentile, the yaw's 2.5 and 6.6 deg, against
stated standard deviations of about 19 mm and 6.8 deg: cautious by about 1.6.

When the map cannot say (the nominal pose outside the grid, too few occupied voxels
there, a poor fit, a fit that left the misplacement), :func:`fit_lying_pose` says why
and :func:`lying_pose` falls back on the nominal pose with the misplacement's
uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .cad import BoxModel, fit_model, fit_residuals, to_object, voxels_of
from .errors import MappingError
from .grid import OccupancyGrid

# Floor hits land in the voxels whose height reaches the surface the object rests on:
# those are the surface's, not the object's, and are left out of the fit. Rendered depth
# puts them exactly at its height; this much more covers millimetres of depth noise.
SUPPORT_TOLERANCE_M = 0.01
# Too few occupied voxels to fit three parameters to: at least this many, and at least
# this share of the voxels the model touches at the nominal pose above its support
# (those of voxels_of: more than a sensor marks, since a voxel the model merely touches
# through a face counts; the default scene's maps mark 42-53 % of them).
MIN_VOXELS = 6
MIN_SEEN_FRACTION = 0.25
# The search for the pose nearest the most occupied voxels: horizontal offsets this many
# voxels apart, and this many yaws to each side of the nominal; a voxel counts by how
# near its centre is to the model (a Gaussian this many voxels wide): a hard count within
# reach let a pose that also touched a post 7 cm beyond the panel's end win.
SEARCH_STEP_VOXELS = 0.2
YAW_STEPS = 5
KERNEL_VOXELS = 0.5
# The object's voxels: centres within reach of the model at the search's pose and this
# many voxels more (the search's pose is itself that far off: a quarter voxel more kept
# the fits on voxels_of grids at 6 mm RMS, against 9 mm with none).
TRIM_VOXELS = 0.25
# A good fit has its median voxel centre within this share of a voxel of the model.
MAX_MEDIAN_VOXELS = 0.7
# The fit's robust (soft-L1) loss scales, in voxels: coarse to fine as for camera points.
LOSS_SCALES_VOXELS = (1.0, 0.5)
# The parameters of a resting object (fit_model's order: rotation vector, translation).
PLANAR = (False, False, True, True, True, False)
# Height and tilt of an object resting on a level floor: its CAD resting pose, to the
# floor's flatness and the edge it stands on.
RESTING_SD_M = 0.002
RESTING_SD_RAD = math.radians(1.0)


@dataclass(frozen=True)
class Misplacement:
    """How far the object may lie from its nominal pose, at most: horizontally (m) and in
    yaw (rad). The fit looks for its voxels within this of the nominal pose; a fit that
    moves further is rejected; without a fit the pose is uniformly anywhere within these
    bounds (standard deviation bound / sqrt(3))."""

    offset_m: float = 0.05
    yaw_rad: float = math.radians(10.0)

    def __post_init__(self) -> None:
        if not (self.offset_m >= 0 and 0 <= self.yaw_rad < math.pi / 2):
            raise MappingError(f"a misplacement is an offset >= 0 m and a yaw in [0, pi/2) "
                               f"rad, got {self}")

    def covariance(self) -> np.ndarray:
        """The nominal pose's covariance (6x6, :func:`taskcam.mapping.cad.pose_covariance`)."""
        sd = np.array([RESTING_SD_RAD, RESTING_SD_RAD, self.yaw_rad / math.sqrt(3),
                       self.offset_m / math.sqrt(3), self.offset_m / math.sqrt(3),
                       RESTING_SD_M])
        return np.diag(sd ** 2)


@dataclass(frozen=True)
class LyingPose:
    """Where the object lies (4x4 ``T_world_object``) and how well that is known: a
    6x6 covariance (rotation vector on the left, then translation; world frame), from
    the map (``source`` "map") or the nominal pose ("nominal": ``why`` says why the map
    could not give it); the height of the surface it rests on (its lowest corner, m:
    :func:`support_layer` of it is the voxels freeing it should keep); the occupied
    voxels fitted and their median distance to the model at the pose (m)."""

    pose: np.ndarray
    covariance: np.ndarray
    source: str
    why: str
    support_z: float
    voxels: int = 0
    median_m: float | None = None

    @property
    def position_sd_m(self) -> np.ndarray:
        """Standard deviation of the position along the world axes (m)."""
        return np.sqrt(np.diag(self.covariance)[3:])

    @property
    def yaw_sd_rad(self) -> float:
        """Standard deviation of the yaw, the rotation about the world's vertical (rad)."""
        return float(np.sqrt(self.covariance[2, 2]))

    def summary(self) -> dict[str, Any]:
        return {"source": self.source, "why": self.why, "voxels": self.voxels,
                "support_z": round(self.support_z, 4),
                "position": [round(float(v), 4) for v in self.pose[:3, 3]],
                "yaw_deg": round(math.degrees(math.atan2(self.pose[1, 0], self.pose[0, 0])), 2),
                "position_sd_m": [round(float(v), 4) for v in self.position_sd_m],
                "yaw_sd_deg": round(math.degrees(self.yaw_sd_rad), 2),
                "median_m": None if self.median_m is None else round(self.median_m, 4)}


def quantisation_sd(grid: OccupancyGrid) -> float:
    """Standard deviation (m) of a point uniformly anywhere in a voxel, per axis."""
    return grid.resolution / math.sqrt(12.0)


def support_layer(grid: OccupancyGrid, support_z: float,
                  tolerance_m: float = SUPPORT_TOLERANCE_M) -> np.ndarray:
    """Boolean mask (grid shape) of the voxels whose height reaches within
    ``tolerance_m`` of a level surface at ``support_z`` (m), or lies below it: the
    surface's voxels (a floor's hits), which an object resting on it shares."""
    bottoms = grid.origin[2] + np.arange(grid.shape[2]) * grid.resolution
    layers = bottoms < support_z + tolerance_m
    return np.broadcast_to(layers, grid.shape).copy()


def _corners(model: BoxModel, pose: np.ndarray) -> np.ndarray:
    """The world corners of the model's boxes at ``pose`` (8 per box, 3)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    local = np.concatenate([c + signs * h for c, h in zip(model.centres, model.halves,
                                                            strict=True)])
    return local @ pose[:3, :3].T + pose[:3, 3]


def fit_lying_pose(grid: OccupancyGrid, model: BoxModel, nominal: np.ndarray,
                   misplacement: Misplacement | None = None
                   ) -> tuple[LyingPose | None, str]:
    """The pose of the object resting near ``nominal`` (4x4) fitted to the occupied
    voxels of ``grid`` there, with its covariance; or None and why not (the map does
    not cover it, too few occupied voxels, a poor fit, a fit that moved beyond the
    misplacement). The voxels fitted are the occupied ones whose centres lie within
    reach (half a voxel diagonal) plus the misplacement (its offset, and its yaw at the
    model's horizontal lever arm) of the model at ``nominal``, above the surface it
    rests on (the height of its lowest corner: :func:`support_layer`)."""
    moved = misplacement or Misplacement()
    nominal = np.asarray(nominal, float)
    res = grid.resolution
    reach = 0.5 * math.sqrt(3) * res
    corners = _corners(model, nominal)
    lever = float(np.max(np.linalg.norm((corners - nominal[:3, 3])[:, :2], axis=1)))
    margin = reach + moved.offset_m + moved.yaw_rad * lever
    lo_world, hi_world = grid.origin, grid.origin + np.array(grid.shape) * res
    inside = np.all((corners >= lo_world) & (corners <= hi_world), axis=1)
    if not inside.any():
        return None, (f"the nominal pose lies outside the grid ({np.round(lo_world, 3).tolist()}"
                      f" to {np.round(hi_world, 3).tolist()} m)")
    support_z = float(corners[:, 2].min())
    support = support_layer(grid, support_z)
    first = np.clip(grid.index(corners.min(axis=0) - margin), 0, np.array(grid.shape) - 1)
    last = np.clip(grid.index(corners.max(axis=0) + margin), 0, np.array(grid.shape) - 1)
    ranges = [np.arange(a, b + 1) for a, b in zip(first, last, strict=True)]
    idx = np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, 3)
    near = model.distance(to_object(nominal, grid.centers(idx))) <= margin
    idx = idx[near & ~support[tuple(idx.T)]]
    states = grid.states()
    occupied = idx[states[tuple(idx.T)] == 1]
    expected = voxels_of(grid, model, nominal) & ~support
    n_expected = int(expected.sum())
    unknown = int(np.sum(states[expected] == 0))
    needed = max(MIN_VOXELS, math.ceil(MIN_SEEN_FRACTION * n_expected))
    partly = "" if inside.all() else ", the model partly outside the grid"
    if len(occupied) < needed:
        return None, (f"{len(occupied)} occupied voxels within {margin:.3f} m of the nominal "
                      f"pose above its support, {needed} needed; of the {n_expected} voxels "
                      f"the model touches there {unknown} were never observed{partly}")
    centres = grid.centers(occupied)
    sigma_q = quantisation_sd(grid)
    start = _best_overlap(model, nominal, centres, moved, res)
    mine = model.distance(to_object(start, centres)) <= reach + TRIM_VOXELS * res
    if mine.sum() < needed:
        return None, (f"{mine.sum()} of the {len(occupied)} occupied voxels near the nominal "
                      f"pose fit the model within the misplacement, {needed} needed")
    centres = centres[mine]
    pose, _ = fit_model(model, centres, start,
                        loss_scales_m=tuple(f * res for f in LOSS_SCALES_VOXELS),
                        free=PLANAR)
    d, J = fit_residuals(model, pose, centres, None)
    median = float(np.median(np.abs(d)))
    if median > MAX_MEDIAN_VOXELS * res:
        return None, (f"the model fits the {len(centres)} occupied voxels poorly: median "
                      f"{median * 1e3:.1f} mm from it, {MAX_MEDIAN_VOXELS * res * 1e3:.1f} mm "
                      f"allowed")
    offset = float(np.linalg.norm(pose[:2, 3] - nominal[:2, 3]))
    turn = float(np.arccos(np.clip((np.trace(nominal[:3, :3].T @ pose[:3, :3]) - 1) / 2,
                                   -1.0, 1.0)))
    if offset > moved.offset_m + res / 2 or turn > moved.yaw_rad + sigma_q / lever:
        return None, (f"the fit moved {offset * 1e3:.0f} mm and {math.degrees(turn):.1f} deg "
                      f"from the nominal pose, beyond the misplacement (and half a voxel)")
    flat = corners[:, :2]
    length = float(np.max(np.linalg.norm(flat[:, None] - flat[None], axis=2)))
    covariance = _covariance(J, sigma_q, moved.covariance(), length)
    return LyingPose(pose, covariance, "map", f"fitted to {len(centres)} occupied voxels",
                     support_z, len(centres), median), ""


def _best_overlap(model: BoxModel, nominal: np.ndarray, centres: np.ndarray,
                  moved: Misplacement, res: float) -> np.ndarray:
    """The pose within the misplacement of ``nominal`` (horizontal offsets within its
    radius on a grid SEARCH_STEP_VOXELS apart, 2 YAW_STEPS + 1 yaws) whose model passes
    nearest the most voxel ``centres`` (each weighted by a Gaussian KERNEL_VOXELS wide of
    its distance to the model); the mean of those that score best."""
    step = SEARCH_STEP_VOXELS * res
    n = max(1, math.ceil(moved.offset_m / step))
    offsets = np.linspace(-moved.offset_m, moved.offset_m, 2 * n + 1)
    yaws = np.linspace(-moved.yaw_rad, moved.yaw_rad, 2 * YAW_STEPS + 1)
    best, found = -1.0, list[tuple[float, float, float]]()
    for yaw in yaws:
        R = _yawed(yaw) @ nominal[:3, :3]
        for dx in offsets:
            for dy in offsets:
                if dx * dx + dy * dy > moved.offset_m ** 2 + 1e-12:
                    continue
                t = nominal[:3, 3] + np.array([dx, dy, 0.0])
                d = model.distance((centres - t) @ R)
                score = float(np.sum(np.exp(-0.5 * (d / (KERNEL_VOXELS * res)) ** 2)))
                if score > best:
                    best, found = score, []
                if score == best:
                    found.append((yaw, dx, dy))
    yaw, dx, dy = np.mean(np.array(found), axis=0)
    start = nominal.copy()
    start[:3, :3] = _yawed(float(yaw)) @ nominal[:3, :3]
    start[:2, 3] += (dx, dy)
    return start


def _yawed(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _covariance(J: np.ndarray, sigma_q: float, prior: np.ndarray, length: float
                ) -> np.ndarray:
    """The fitted pose's covariance (6x6): in the fitted parameters (yaw, x, y) the
    nominal's covariance P updated by the fit's residual derivatives J (n, 6) with noise
    sigma_q on each, P - P J^T (J P J^T + sigma_q^2 I)^-1 J P (the information form's
    (J^T J / sigma_q^2 + P^-1)^-1, defined for a zero P too), plus the quantisation that
    does not average out: sigma_q per horizontal axis, sqrt(2) sigma_q / ``length`` in
    yaw. Height and tilt keep the nominal's."""
    chosen = np.array(PLANAR)
    Jf = J[:, chosen]
    P = prior[np.ix_(chosen, chosen)]
    S = Jf @ P @ Jf.T + sigma_q ** 2 * np.eye(len(Jf))
    fitted = P - P @ Jf.T @ np.linalg.solve(S, Jf @ P)
    fitted = 0.5 * (fitted + fitted.T) + np.diag(
        [(math.sqrt(2) * sigma_q / length) ** 2, sigma_q ** 2, sigma_q ** 2])
    covariance = prior.copy()
    covariance[np.ix_(chosen, chosen)] = fitted
    return covariance


def lying_pose(grid: OccupancyGrid, model: BoxModel, nominal: np.ndarray,
               misplacement: Misplacement | None = None) -> LyingPose:
    """Where the object lies: :func:`fit_lying_pose`, or when the map cannot give it, the
    nominal pose with the misplacement's uncertainty (and why)."""
    moved = misplacement or Misplacement()
    found, why = fit_lying_pose(grid, model, nominal, moved)
    if found is not None:
        return found
    nominal = np.array(nominal, float)
    return LyingPose(nominal, moved.covariance(), "nominal", why,
                     float(_corners(model, nominal)[:, 2].min()))


__all__ = ["LyingPose", "Misplacement", "fit_lying_pose", "lying_pose", "quantisation_sd",
           "support_layer"]
