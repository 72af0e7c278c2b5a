"""Integration of a depth image into an occupancy grid.

Each valid pixel is a ray from the camera centre to its measured point: the voxels it
crosses are observed free, the voxel of its end point occupied. Sky pixels (``inf``)
and pixels beyond ``max_range`` observe free space up to ``max_range`` and nothing
occupied; NaN and non-positive depths observe nothing. Every voxel is updated at most
once per image, and occupied wins over free.

Rays are sampled every ``resolution / oversample`` metres: a voxel that a ray only
grazes at a corner may be skipped.
"""

from __future__ import annotations

import numpy as np

from .camera import Pinhole, camera_to_world
from .grid import OccupancyGrid


def _clip_to_box(origin: np.ndarray, dirs: np.ndarray, length: np.ndarray,
                 lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameter interval [t0, t1] of each ray (unit dirs) inside the box and its length."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        ta, tb = (lo - origin) * inv, (hi - origin) * inv
    tmin = np.nan_to_num(np.minimum(ta, tb), nan=-np.inf)
    tmax = np.nan_to_num(np.maximum(ta, tb), nan=np.inf)
    t0 = np.maximum(tmin.max(axis=1), 0.0)
    t1 = np.minimum(tmax.min(axis=1), length)
    return t0, t1


def integrate_depth(grid: OccupancyGrid, depth: np.ndarray, camera: Pinhole,
                    T_world_cam: np.ndarray, max_range: float = 4.0, stride: int = 1,
                    oversample: float = 2.0, chunk: int = 8192) -> tuple[int, int]:
    """Update ``grid`` with one z-depth image (m); ``T_world_cam`` in OpenCV convention.

    Returns the number of voxels marked free and occupied.
    """
    _, _, rays = camera.rays(stride)
    z = depth[::stride, ::stride].astype(float).ravel()
    rays = rays.reshape(-1, 3)
    valid = np.isfinite(z) & (z > 0) | np.isposinf(z)
    z, rays = z[valid], rays[valid]
    norm = np.linalg.norm(rays, axis=1)
    dist = np.where(np.isinf(z), np.inf, z * norm)
    hit = dist <= max_range
    dirs_world = (rays / norm[:, None]) @ T_world_cam[:3, :3].T
    origin = T_world_cam[:3, 3]
    shape = np.array(grid.shape)
    strides = np.array([grid.shape[1] * grid.shape[2], grid.shape[2], 1])

    end_points = camera_to_world(T_world_cam, rays[hit] * z[hit, None])
    end_idx = grid.index(end_points)
    end_idx = end_idx[grid.inside(end_idx)]
    occupied = np.unique(end_idx @ strides)

    # Free space: from the camera to just before the end point (or to max_range).
    length = np.minimum(dist, max_range) - 1e-6
    t0, t1 = _clip_to_box(origin, dirs_world, length, grid.origin, grid.upper)
    keep = t1 > t0
    dirs_world, t0, t1 = dirs_world[keep], t0[keep], t1[keep]
    step = grid.resolution / oversample
    seen = np.zeros(grid.log_odds.size, dtype=bool)
    for s in range(0, len(t0), chunk):
        d, a, b = dirs_world[s:s + chunk], t0[s:s + chunk], t1[s:s + chunk]
        count = int(np.ceil((b - a).max() / step)) + 1
        t = a[:, None] + step * np.arange(count, dtype=np.float32)[None, :]
        t = np.minimum(t, b[:, None])  # the last sample lands on the segment's end
        rel = ((origin - grid.origin) / grid.resolution).astype(np.float32)
        idx = np.floor(rel + t[..., None] * (d / grid.resolution).astype(np.float32)[:, None, :])
        idx = np.clip(idx.astype(np.int64), 0, shape - 1)
        seen[idx @ strides] = True
    seen[occupied] = False
    free = np.flatnonzero(seen)
    grid.update(free, occupied)
    return len(free), len(occupied)
