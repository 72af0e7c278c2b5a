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
from .raycast import mark_free_image


def share_bands(focal_px: float, share: float, max_levels: int = 4) -> np.ndarray:
    """Band ends (voxels from the camera) per block level: a 2^l-pixel block is narrower
    than ``share`` voxels up to share * f / 2^l voxels. Index 0 is unused."""
    levels = 0
    while levels < max_levels and share * focal_px / 2 ** (levels + 1) >= 1.0:
        levels += 1
    return np.array([np.inf] + [share * focal_px / 2 ** lv for lv in range(1, levels + 1)])


@nb.njit(cache=True, parallel=True)
def _ray_lengths(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int,
                 R: np.ndarray, t: np.ndarray, origin: np.ndarray, resolution: float,
                 max_range: float, shape: tuple[int, int, int], stamp: np.ndarray,
                 occupied_code: int) -> np.ndarray:
    """Ray lengths (voxels; NaN: no ray) of every ``stride``-th pixel, stamping the voxel
    of each end point within ``max_range`` occupied."""
    rows = (depth.shape[0] + stride - 1) // stride
    cols = (depth.shape[1] + stride - 1) // stride
    lengths = np.full((rows, cols), np.nan, dtype=np.float32)
    n0, n1, n2 = shape
    for r in nb.prange(rows):
        v = r * stride
        for c in range(cols):
            u = c * stride
            z = float(depth[v, u])
            if not (z > 0.0):  # NaN, zero or negative: no measurement
                continue
            x, y = (u - cx) / fx, (v - cy) / fy
            dist = z * np.sqrt(x * x + y * y + 1.0)  # inf for sky
            if dist <= max_range:
                ijk = np.empty(3, dtype=np.int64)
                for a in range(3):
                    point = t[a] + z * (R[a, 0] * x + R[a, 1] * y + R[a, 2])
                    ijk[a] = int(np.floor((point - origin[a]) / resolution))
                if 0 <= ijk[0] < n0 and 0 <= ijk[1] < n1 and 0 <= ijk[2] < n2:
                    stamp[(ijk[0] * n1 + ijk[1]) * n2 + ijk[2]] = occupied_code
            lengths[r, c] = (min(dist, max_range) - 1e-6) / resolution
    return lengths


def integrate_depth(grid: OccupancyGrid, depth: np.ndarray, camera: Pinhole,
                    T_world_cam: np.ndarray, max_range: float = 4.0, stride: int = 1,
                    share: float = 0.5) -> tuple[int, int]:
    """Update ``grid`` with one z-depth image (m); ``T_world_cam`` in OpenCV convention.

    Returns the number of voxels marked free and occupied.
    """
    occupied_code, free_code = grid.begin_scan()
    stamp = grid.stamp.reshape(-1)
    R = np.ascontiguousarray(T_world_cam[:3, :3], dtype=np.float64)
    intrinsics = (camera.fx, camera.fy, camera.cx, camera.cy)
    lengths = _ray_lengths(np.ascontiguousarray(depth), *intrinsics, stride, R,
                           np.ascontiguousarray(T_world_cam[:3, 3], dtype=np.float64),
                           grid.origin, grid.resolution, max_range, grid.shape, stamp,
                           occupied_code)
    # Free space: from the camera to just before each end point (or to max_range).
    origin = (T_world_cam[:3, 3] - grid.origin) / grid.resolution
    bands = share_bands(camera.fy / stride, share) if share > 0 else np.array([np.inf])
    mark_free_image(grid.shape, origin, R, intrinsics, stride, lengths, stamp, occupied_code,
                    free_code, bands)
    return grid.end_scan(occupied_code, free_code)
