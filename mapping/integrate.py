"""Integration of a depth image into an occupancy grid.

Each valid pixel is a ray from the camera centre to its measured point: the voxels it
crosses are observed free, the voxel of its end point occupied. Sky pixels (``inf``)
and pixels beyond ``max_range`` observe free space up to ``max_range`` and nothing
occupied; NaN and non-positive depths observe nothing. Every voxel is updated at most
once per image, and occupied wins over free. Rays are traversed exactly (3-D DDA).

Near the camera many rays cross the same voxels. With ``share`` > 0 a block of
neighbouring rays is traversed by one of them wherever the block is narrower than
``share`` voxels and all its rays reach further (see ``raycast.mark_free_image``);
``share = 0`` traverses every ray from the camera.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .camera import Pinhole
from .grid import OccupancyGrid
from .raycast import mark_free, mark_free_image


def share_bands(focal_px: float, share: float, max_levels: int = 4) -> np.ndarray:
    """Band ends (voxels from the camera) per block level: a 2^l-pixel block is narrower
    than ``share`` voxels up to share * f / 2^l voxels. Index 0 is unused."""
    levels = 0
    while levels < max_levels and share * focal_px / 2 ** (levels + 1) >= 1.0:
        levels += 1
    return np.array([np.inf] + [share * focal_px / 2 ** lv for lv in range(1, levels + 1)])


@nb.njit(cache=True, parallel=True)
def _rays(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int,
          R: np.ndarray, t: np.ndarray, origin: np.ndarray, resolution: float,
          max_range: float, shape: tuple[int, int, int], stamp: np.ndarray,
          occupied_code: int) -> tuple[np.ndarray, np.ndarray]:
    """World ray directions and lengths (voxels; NaN: no ray) of every ``stride``-th pixel,
    stamping the voxel of each end point within ``max_range`` occupied."""
    rows, cols = (depth.shape[0] + stride - 1) // stride, (depth.shape[1] + stride - 1) // stride
    dirs = np.empty((rows, cols, 3))
    lengths = np.full((rows, cols), np.nan)
    n0, n1, n2 = shape
    for r in nb.prange(rows):
        v = r * stride
        for c in range(cols):
            u = c * stride
            z = float(depth[v, u])
            if not (z > 0.0):  # NaN, zero or negative: no measurement
                continue
            x, y = (u - cx) / fx, (v - cy) / fy
            norm = np.sqrt(x * x + y * y + 1.0)
            d0 = (R[0, 0] * x + R[0, 1] * y + R[0, 2]) / norm
            d1 = (R[1, 0] * x + R[1, 1] * y + R[1, 2]) / norm
            d2 = (R[2, 0] * x + R[2, 1] * y + R[2, 2]) / norm
            dirs[r, c, 0], dirs[r, c, 1], dirs[r, c, 2] = d0, d1, d2
            dist = z * norm  # inf for sky
            if dist <= max_range:
                i = int(np.floor((t[0] + dist * d0 - origin[0]) / resolution))
                j = int(np.floor((t[1] + dist * d1 - origin[1]) / resolution))
                k = int(np.floor((t[2] + dist * d2 - origin[2]) / resolution))
                if 0 <= i < n0 and 0 <= j < n1 and 0 <= k < n2:
                    stamp[(i * n1 + j) * n2 + k] = occupied_code
            lengths[r, c] = (min(dist, max_range) - 1e-6) / resolution
    return dirs, lengths


def integrate_depth(grid: OccupancyGrid, depth: np.ndarray, camera: Pinhole,
                    T_world_cam: np.ndarray, max_range: float = 4.0, stride: int = 1,
                    share: float = 0.5) -> tuple[int, int]:
    """Update ``grid`` with one z-depth image (m); ``T_world_cam`` in OpenCV convention.

    Returns the number of voxels marked free and occupied.
    """
    occupied_code, free_code = grid.begin_scan()
    stamp = grid.stamp.reshape(-1)
    dirs, lengths = _rays(np.ascontiguousarray(depth), camera.fx, camera.fy, camera.cx,
                          camera.cy, stride, np.ascontiguousarray(T_world_cam[:3, :3]),
                          np.ascontiguousarray(T_world_cam[:3, 3]), grid.origin,
                          grid.resolution, max_range, grid.shape, stamp, occupied_code)
    # Free space: from the camera to just before each end point (or to max_range).
    origin = (T_world_cam[:3, 3] - grid.origin) / grid.resolution
    if share > 0:
        mark_free_image(grid.shape, origin, dirs, lengths, stamp, occupied_code, free_code,
                        share_bands(camera.fy / stride, share))
    else:
        ok = np.isfinite(lengths)
        mark_free(grid.shape, origin, dirs[ok], lengths[ok], stamp, occupied_code, free_code)
    return grid.end_scan(occupied_code, free_code)
