"""Integration of a depth image into an occupancy grid.

Each valid pixel is a ray from the camera centre to its measured point: the voxels it
crosses are observed free, the voxel of its end point occupied. Sky pixels (``inf``)
and pixels beyond ``max_range`` observe free space up to ``max_range`` and nothing
occupied; NaN and non-positive depths observe nothing. Every voxel is updated at most
once per image, and occupied wins over free. Rays are traversed exactly (3-D DDA).
"""

from __future__ import annotations

import numpy as np

from .camera import Pinhole, camera_to_world
from .grid import OccupancyGrid
from .raycast import mark_free


def integrate_depth(grid: OccupancyGrid, depth: np.ndarray, camera: Pinhole,
                    T_world_cam: np.ndarray, max_range: float = 4.0,
                    stride: int = 1) -> tuple[int, int]:
    """Update ``grid`` with one z-depth image (m); ``T_world_cam`` in OpenCV convention.

    Returns the number of voxels marked free and occupied.
    """
    _, _, rays = camera.rays(stride)
    z = depth[::stride, ::stride].astype(float).ravel()
    rays = rays.reshape(-1, 3)
    valid = (np.isfinite(z) & (z > 0)) | np.isposinf(z)
    z, rays = z[valid], rays[valid]
    norm = np.linalg.norm(rays, axis=1)
    dist = np.where(np.isinf(z), np.inf, z * norm)
    hit = dist <= max_range
    occupied_code, free_code = grid.begin_scan()

    end_idx = grid.index(camera_to_world(T_world_cam, rays[hit] * z[hit, None]))
    grid.stamp.reshape(-1)[grid.flat(end_idx[grid.inside(end_idx)])] = occupied_code

    # Free space: from the camera to just before the end point (or to max_range).
    dirs = (rays / norm[:, None]) @ T_world_cam[:3, :3].T
    length = (np.minimum(dist, max_range) - 1e-6) / grid.resolution
    origin = (T_world_cam[:3, 3] - grid.origin) / grid.resolution
    mark_free(grid.shape, origin, dirs, length, grid.stamp.reshape(-1), occupied_code,
              free_code)
    return grid.end_scan(occupied_code, free_code)
