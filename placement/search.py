"""Searching the rating function over known-free voxels, for several targets (sec. 3).

Strategies: ``exhaustive`` rates every candidate; ``coarse`` every ``coarse_step``-th
voxel along each axis; ``bounded`` only candidates within ``max_distance`` of a target;
``random`` a random subset of ``samples`` candidates. Each returns the rating field of
what it evaluated; each candidate keeps the target that rates it best (sec. 2.3.5).
:func:`rate_positions` rates positions chosen otherwise, each for its best target or the
one it is aimed at.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numba as nb
import numpy as np

from taskcam.mapping import LOG_ODDS_SCALE, OccupancyGrid, circle_in_plane, stored_log_odds

from .errors import PlacementError
from .occluders import Hull, expanded_hulls, grid_occluders, target_outline
from .rating import CameraModel, Ratings, TargetModel, Weights, rate_aimed, rate_best
from .tfv import clearance_map

Strategy = Literal["exhaustive", "coarse", "bounded", "random"]


@dataclass(frozen=True)
class Region:
    """Where a camera may go: heights (m), spheres (centre, radius) to keep out of, and a
    horizontal disc (centre x, y; radius) to stay within."""

    z_min: float = -np.inf
    z_max: float = np.inf
    keep_out: tuple[tuple[tuple[float, float, float], float], ...] = ()
    within: tuple[tuple[float, float], float] | None = None


@dataclass(frozen=True)
class SearchSettings:
    strategy: Strategy = "exhaustive"
    coarse_step: int = 2  # voxels, for "coarse"
    max_distance: float = np.inf  # m from the nearest target, for "bounded"
    samples: int = 2000  # candidates, for "random"
    unknown_occludes: bool = True  # never-observed voxels count as occluders
    block: int = 4  # voxels a side of the pieces an occluder is hulled in
    directions: int = 16384  # of the sphere TFV is computed on
    levels: int = 48  # distances TFV is computed at, over the depth of field
    cone: bool = True  # exact cone expansion of occluders; False: the paper's uniform one


@dataclass(frozen=True)
class RatingField:
    """The rating of every evaluated candidate, each for the target that rates it best."""

    ratings: Ratings
    target: np.ndarray  # index into the targets searched, per candidate
    strategy: str = "exhaustive"
    hulls: dict[str, list[Hull]] = field(default_factory=dict)  # expanded, per target
    order: np.ndarray | None = None  # the order candidates are tried in, if not by rating

    @property
    def evaluated(self) -> int:
        return len(self.target)

    def ranked(self) -> np.ndarray:
        """Indices of candidates with a positive rating, best first (ties by index); or
        ``order`` when a placement method other than the rating function set it."""
        if self.order is not None:
            return self.order
        total = self.ratings.total
        order = np.lexsort((np.arange(len(total)), -total))
        return order[total[order] > 0]


def target_points(target: TargetModel, rim: int = 4) -> np.ndarray:
    """The target's centre and ``rim`` points at 0.9 of its radius (a slot: its corners,
    at 0.9 of the way out), 1 mm above its face."""
    n = target.normal / np.linalg.norm(target.normal)
    ring = (0.9 * target_outline(target) if target.half_length > 0
            else circle_in_plane(n, 0.9 * target.radius, rim))
    return target.position + 0.001 * n + np.vstack([np.zeros(3), ring])


@nb.njit(cache=True)
def _candidates(log_odds: np.ndarray, origin: np.ndarray, resolution: float, limit: float,
                z_min: float, z_max: float, keep_out: np.ndarray, within: np.ndarray,
                targets: np.ndarray, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
    n0, n1, n2 = log_odds.shape
    positions = np.empty((log_odds.size, 3))
    occupancy = np.empty(log_odds.size)
    count = 0
    for i in range(n0):
        x = origin[0] + (i + 0.5) * resolution
        for j in range(n1):
            y = origin[1] + (j + 0.5) * resolution
            if within[2] >= 0 and (x - within[0]) ** 2 + (y - within[1]) ** 2 > within[2] ** 2:
                continue
            for k in range(n2):
                value = log_odds[i, j, k]
                if value >= limit:
                    continue
                z = origin[2] + (k + 0.5) * resolution
                if z < z_min or z > z_max:
                    continue
                ok = True
                for q in range(len(keep_out)):
                    dx, dy, dz = x - keep_out[q, 0], y - keep_out[q, 1], z - keep_out[q, 2]
                    if dx * dx + dy * dy + dz * dz < keep_out[q, 3] ** 2:
                        ok = False
                if not ok:
                    continue
                ok = False
                for t in range(len(targets)):
                    dx, dy, dz = x - targets[t, 0], y - targets[t, 1], z - targets[t, 2]
                    d = np.sqrt(dx * dx + dy * dy + dz * dz)
                    if near <= d <= far:
                        ok = True
                if not ok:
                    continue
                positions[count, 0], positions[count, 1], positions[count, 2] = x, y, z
                occupancy[count] = 1.0 / (1.0 + np.exp(-value / LOG_ODDS_SCALE))
                count += 1
    return positions[:count].copy(), occupancy[:count].copy()


def _region_arrays(region: Region) -> tuple[np.ndarray, np.ndarray]:
    """The region's keep-out spheres (k, 4) and disc (x, y, r; r < 0 for none) as arrays."""
    keep_out = np.array([[*c, r] for c, r in region.keep_out], dtype=float).reshape(-1, 4)
    within = (np.array([*region.within[0], region.within[1]], dtype=float)
              if region.within is not None else np.array([0.0, 0.0, -1.0]))
    return keep_out, within


def candidates(grid: OccupancyGrid, targets: Sequence[TargetModel], camera: CameraModel,
               free_threshold: float, region: Region) -> tuple[np.ndarray, np.ndarray]:
    """Centres (n, 3) of known-free voxels (P < ``free_threshold``) in the region and in
    some target's depth of field, in grid order, and their occupancy probabilities."""
    limit = float(stored_log_odds(free_threshold))
    keep_out, within = _region_arrays(region)
    return _candidates(grid.log_odds, grid.origin, grid.resolution, limit, region.z_min,
                       region.z_max, keep_out, within,
                       np.array([t.position for t in targets], dtype=float), camera.near,
                       camera.far)


def region_voxels(grid: OccupancyGrid, region: Region) -> np.ndarray:
    """Centres (n, 3; m) of every voxel of ``grid`` in ``region``, whatever the map holds
    there (free, occupied or never observed), in grid order."""
    keep_out, within = _region_arrays(region)
    positions, _ = _candidates(grid.log_odds, grid.origin, grid.resolution, np.inf,
                               region.z_min, region.z_max, keep_out, within, np.zeros((1, 3)),
                               0.0, np.inf)
    return positions


def _select(grid: OccupancyGrid, positions: np.ndarray, targets: Sequence[TargetModel],
            settings: SearchSettings, rng: np.random.Generator | None) -> np.ndarray:
    """Which candidates the strategy evaluates (a boolean mask)."""
    if settings.strategy == "coarse":
        idx = grid.index(positions)
        return np.all(idx % settings.coarse_step == 0, axis=1)
    if settings.strategy == "bounded":
        d = np.min([np.linalg.norm(positions - t.position, axis=1) for t in targets], axis=0)
        return d <= settings.max_distance
    if settings.strategy == "random":
        if rng is None:
            raise PlacementError("rng None: the random search strategy needs a "
                                 "numpy Generator")
        keep = np.zeros(len(positions), dtype=bool)
        keep[rng.choice(len(positions), min(settings.samples, len(positions)),
                        replace=False)] = True
        return keep
    return np.ones(len(positions), dtype=bool)


def search(grid: OccupancyGrid, targets: Sequence[TargetModel], camera: CameraModel,
           weights: Weights = Weights(), free_threshold: float = 0.05,
           region: Region = Region(), settings: SearchSettings = SearchSettings(),
           rng: np.random.Generator | None = None,
           extra_occluders: Sequence[np.ndarray] = (),
           grid_hulls: dict[tuple[float, ...], list[Hull]] | None = None) -> RatingField:
    """Rate the candidates the strategy picks, for every target; keep each one's best.

    ``extra_occluders`` are point sets (m), e.g. other robots' bodies, each hulled after
    expansion by the target like the grid's occluders. ``grid_hulls`` keeps the grid's
    expanded occluders by target plane and radius: searches of one map with the same
    ``settings`` that share a dict hull the map once.
    """
    positions, occupancy = candidates(grid, targets, camera, free_threshold, region)
    keep = _select(grid, positions, targets, settings, rng)
    return rate_positions(grid, targets, camera, positions[keep], occupancy[keep], weights,
                          settings, extra_occluders, grid_hulls)


def rate_positions(grid: OccupancyGrid, targets: Sequence[TargetModel], camera: CameraModel,
                   positions: np.ndarray, occupancy: np.ndarray, weights: Weights = Weights(),
                   settings: SearchSettings = SearchSettings(),
                   extra_occluders: Sequence[np.ndarray] = (),
                   grid_hulls: dict[tuple[float, ...], list[Hull]] | None = None,
                   aims: np.ndarray | None = None) -> RatingField:
    """The rating of camera ``positions`` (n, 3; m) whose voxels' P(occupied) is
    ``occupancy``, occluders as :func:`search` takes them: each for the target that
    rates it best, or with ``aims`` (a target index per position) for that target."""
    grid_hulls = {} if grid_hulls is None else grid_hulls
    hulls: dict[str, list[Hull]] = {}
    tfv = np.empty((len(targets), len(positions)))
    hulls_by_plane: dict[tuple[float, ...], tuple[float, list[Hull]]] = {}
    for k, target in enumerate(targets):
        n = target.normal / np.linalg.norm(target.normal)
        plane = (*np.round(n, 9), round(float(n @ target.position), 9))
        # discs on one plate share their occluders, expanded hulls scaled by radius; a
        # slot's rectangle is not a scaled disc: its own
        sharing = plane if target.half_length <= 0 else (*plane, *target.shape())
        if sharing not in hulls_by_plane:
            key = (*plane, *target.shape())
            if key not in grid_hulls:
                grid_hulls[key] = expanded_hulls(grid_occluders(
                    grid, target, unknown_occludes=settings.unknown_occludes,
                    block=settings.block), target)
            hulls_by_plane[sharing] = (target.radius, [
                *grid_hulls[key], *expanded_hulls(list(extra_occluders), target)])
        radius, first = hulls_by_plane[sharing]  # and their expanded hulls, scaled
        hulls[target.name] = (first if target.radius == radius else
                              [h.grown(target.radius / radius) for h in first])
        tfv[k] = clearance_map(target.position, hulls[target.name], camera.near, camera.far,
                               settings.levels, settings.directions, settings.cone
                               ).tfv(positions - target.position)
    if aims is None:
        ratings, which = rate_best(positions, targets, camera, tfv, occupancy, weights)
    else:
        ratings, which = rate_aimed(positions, targets, aims, camera, tfv, occupancy,
                                    weights), np.asarray(aims)
    return RatingField(ratings, which, settings.strategy, hulls)
