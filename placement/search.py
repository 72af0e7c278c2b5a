"""Exhaustive search of the rating function over known-free voxels, for several targets."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from mapping import OccupancyGrid

from .rating import CameraModel, Ratings, TargetModel, Weights, rate
from .visibility import line_of_sight


@dataclass(frozen=True)
class Region:
    """Where a camera may go: heights (m) and spheres (centre, radius) to keep out of."""

    z_min: float = -np.inf
    z_max: float = np.inf
    keep_out: tuple[tuple[tuple[float, float, float], float], ...] = ()


@dataclass(frozen=True)
class RatingField:
    """The rating of every candidate, each for the target that rates it best."""

    ratings: Ratings
    target: np.ndarray  # index into the targets searched, per candidate

    def ranked(self) -> np.ndarray:
        """Indices of candidates with a positive rating, best first (ties by index)."""
        total = self.ratings.total
        order = np.lexsort((np.arange(len(total)), -total))
        return order[total[order] > 0]


def target_points(target: TargetModel, rim: int = 4) -> np.ndarray:
    """The target's centre and ``rim`` points at 0.9 of its radius, 1 mm above its face."""
    n = target.normal / np.linalg.norm(target.normal)
    helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    a = np.linspace(0, 2 * np.pi, rim, endpoint=False)
    ring = 0.9 * target.radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    return target.position + 0.001 * n + np.vstack([np.zeros(3), ring])


def candidates(grid: OccupancyGrid, targets: Sequence[TargetModel], camera: CameraModel,
               free_threshold: float, region: Region) -> tuple[np.ndarray, np.ndarray]:
    """Centres (n, 3) of known-free voxels in the region and in some target's depth of field,
    and their occupancy probabilities."""
    p = grid.probability()
    idx = np.argwhere(p < free_threshold)
    pos = grid.centers(idx)
    keep = (pos[:, 2] >= region.z_min) & (pos[:, 2] <= region.z_max)
    for centre, radius in region.keep_out:
        keep &= np.linalg.norm(pos - np.asarray(centre), axis=1) >= radius
    in_field = np.zeros(len(pos), dtype=bool)
    for t in targets:
        d = np.linalg.norm(pos - t.position, axis=1)
        in_field |= (d >= camera.near) & (d <= camera.far)
    keep &= in_field
    idx = idx[keep]
    return pos[keep], p[idx[:, 0], idx[:, 1], idx[:, 2]]


def search(grid: OccupancyGrid, targets: Sequence[TargetModel], camera: CameraModel,
           weights: Weights = Weights(), free_threshold: float = 0.05,
           occluding_threshold: float = 0.5, region: Region = Region()) -> RatingField:
    """Rate every candidate voxel for every target; keep each candidate's best target.

    TFV here is the fraction of the target's centre and rim points in line of sight
    through the grid (unknown and occupied voxels block).
    """
    positions, occupancy = candidates(grid, targets, camera, free_threshold, region)
    rated = []
    for target in targets:
        tfv = np.zeros(len(positions))
        # Lines of sight only where the other terms leave the rating positive.
        rest = rate(positions, target, camera, np.ones(len(positions)), occupancy, weights)
        live = rest.total > 0
        seen = line_of_sight(grid, positions[live], target_points(target), occluding_threshold,
                             stop_short=1.5 * grid.resolution)
        tfv[live] = seen.mean(axis=1)
        rated.append(rate(positions, target, camera, tfv, occupancy, weights))
    which = np.argmax(np.stack([r.total for r in rated]), axis=0)  # first best on ties
    cols = np.arange(len(positions))

    def pick(name: str) -> np.ndarray:
        return np.stack([getattr(r, name) for r in rated])[which, cols]

    terms = {f.name: pick(f.name) for f in fields(Ratings) if f.name != "positions"}
    return RatingField(Ratings(positions=positions, **terms), which)
