"""Lines of sight through an occupancy grid, by exact voxel traversal."""

from __future__ import annotations

import numpy as np

from taskcam.mapping import OccupancyGrid, first_hits


def line_of_sight(grid: OccupancyGrid, cameras: np.ndarray, points: np.ndarray,
                  occluding: float = 0.5, stop_short: float = 0.0,
                  chunk: int = 65536, blocked: np.ndarray | None = None) -> np.ndarray:
    """Boolean (n, k): is each of ``points`` (k, 3) seen from each camera (n, 3)?

    A line is blocked where it passes through a voxel with P >= ``occluding`` (unknown
    voxels block at the default 0.5), or, if given, where ``blocked`` (bool per voxel) is
    True. The last ``stop_short`` metres before each point are not checked (the voxels
    holding the point itself). A line that leaves the grid is blocked: outside is unknown.
    """
    if blocked is None:
        blocked = grid.probability() >= occluding
    blocked = np.ascontiguousarray(blocked).reshape(-1)
    cameras, points = np.atleast_2d(cameras), np.atleast_2d(points)
    starts = np.repeat(cameras, len(points), axis=0)
    ends = np.tile(points, (len(cameras), 1))
    delta = ends - starts
    length = np.linalg.norm(delta, axis=1)
    dirs = delta / np.maximum(length, 1e-12)[:, None]
    span = np.maximum(length - stop_short, 0.0) / grid.resolution
    origins = (starts - grid.origin) / grid.resolution
    seen = grid.inside(grid.index(starts)) & grid.inside(grid.index(ends))
    for s in range(0, len(starts), chunk):
        seen[s:s + chunk] &= ~first_hits(grid.shape, origins[s:s + chunk], dirs[s:s + chunk],
                                         span[s:s + chunk], blocked)
    return seen.reshape(len(cameras), len(points))
