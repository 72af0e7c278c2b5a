"""Lines of sight through an occupancy grid."""

from __future__ import annotations

import numpy as np

from mapping import OccupancyGrid


def blocking_mask(grid: OccupancyGrid, occluding: float = 0.5) -> np.ndarray:
    """Voxels with P >= ``occluding``, padded by one voxel of blocking (unknown) border."""
    padded = np.ones(tuple(n + 2 for n in grid.shape), dtype=bool)
    padded[1:-1, 1:-1, 1:-1] = grid.probability() >= occluding
    return padded


def line_of_sight(grid: OccupancyGrid, cameras: np.ndarray, points: np.ndarray,
                  occluding: float = 0.5, stop_short: float = 0.0,
                  chunk: int = 4096) -> np.ndarray:
    """Boolean (n, k): is each of ``points`` (k, 3) seen from each camera (n, 3)?

    A line is blocked where it passes through a voxel with P >= ``occluding`` (unknown
    voxels block at the default 0.5). The last ``stop_short`` metres before each point
    are not checked (the voxels holding the point itself). Space outside the grid
    counts as unknown. Lines are sampled every half voxel.
    """
    padded = blocking_mask(grid, occluding)
    flat = padded.reshape(-1)
    dims = np.array(padded.shape)
    step = 0.5  # voxels
    cams = ((np.asarray(cameras) - grid.origin) / grid.resolution).astype(np.float32) + 1.0
    out = np.empty((len(cams), len(points)), dtype=bool)
    for k, point in enumerate(np.asarray(points)):
        p = ((point - grid.origin) / grid.resolution).astype(np.float32) + 1.0
        for s in range(0, len(cams), chunk):
            c = cams[s:s + chunk]
            delta = p - c  # (c, 3) in voxels
            length = np.linalg.norm(delta, axis=1)
            span = np.maximum(length - stop_short / grid.resolution, 0.0)
            count = int(np.ceil(span.max() / step)) + 1 if len(span) else 1
            t = np.minimum(np.arange(count, dtype=np.float32)[None, :] * step, span[:, None])
            t /= np.maximum(length, 1e-6)[:, None]
            index = np.zeros(t.shape, dtype=np.int64)
            for axis in range(3):
                coord = np.floor(c[:, axis, None] + t * delta[:, axis, None]).astype(np.int64)
                np.clip(coord, 0, dims[axis] - 1, out=coord)
                index = index * dims[axis] + coord
            out[s:s + chunk, k] = ~flat[index].any(axis=1)
    return out
