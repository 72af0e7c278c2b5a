"""Target field visibility (sec. 2.3.3, step iii): expanded hulls seen from the target.

Definition implemented (the angular clearance): for a camera at distance d from the
(reduced) target, in direction u from it, TFV = theta / pi, where theta is the geodesic
angle on the sphere of radius d around the target from u to the nearest direction in
which an expanded hull lies closer than d — the angle through which the camera can
move on that sphere before the target is occluded. TFV is 0 when the target is occluded
now and 1 when nothing occludes it at that distance.

Computed on a Fibonacci sphere of ``directions`` unit vectors: one ray per direction
from the target gives the distance to the nearest hull (the projection of every hull
onto the sphere, with its depth); for a ladder of ``levels`` distances the exact angle
from every direction to the nearest direction occluded closer than that distance is
found by a compiled search over the occluded directions, shallowest first. A camera takes the
clearance of its nearest sphere direction at the first level at or beyond its distance
(so a camera between levels is rated as if slightly farther: conservative).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba as nb
import numpy as np
from scipy.spatial import cKDTree

from .occluders import Hull

LOOKUP = (1024, 512)  # azimuth x polar cells of the direction lookup table


@lru_cache(maxsize=4)
def sphere(directions: int) -> tuple[np.ndarray, np.ndarray]:
    """Fibonacci-sphere unit vectors (n, 3) and a table from (azimuth, polar) cell to the
    nearest of them."""
    i = np.arange(directions) + 0.5
    z = 1 - 2 * i / directions
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    az = (np.arange(LOOKUP[0]) + 0.5) / LOOKUP[0] * 2 * np.pi - np.pi
    pol = (np.arange(LOOKUP[1]) + 0.5) / LOOKUP[1] * np.pi
    A, P = np.meshgrid(az, pol, indexing="ij")
    cells = np.stack([np.sin(P) * np.cos(A), np.sin(P) * np.sin(A), np.cos(P)], -1)
    _, table = cKDTree(dirs).query(cells.reshape(-1, 3))
    return dirs, table.reshape(LOOKUP).astype(np.int32)


@nb.njit(cache=True, parallel=True)
def _lookup(offsets: np.ndarray, levels: np.ndarray, clearance: np.ndarray,
            table: np.ndarray) -> np.ndarray:
    """Clearance / pi at each offset's distance level and nearest sphere direction."""
    out = np.empty(len(offsets))
    na, npol = table.shape
    for i in nb.prange(len(offsets)):
        x, y, z = offsets[i, 0], offsets[i, 1], offsets[i, 2]
        d = np.sqrt(x * x + y * y + z * z)
        k = min(np.searchsorted(levels, d), len(levels) - 1)
        az = np.arctan2(y, x)
        pol = np.arccos(min(max(z / max(d, 1e-12), -1.0), 1.0))
        a = min(max(int((az + np.pi) / (2 * np.pi) * na), 0), na - 1)
        p = min(max(int(pol / np.pi * npol), 0), npol - 1)
        out[i] = clearance[k, table[a, p]] / np.pi
    return out


@nb.njit(cache=True, parallel=True)
def _ray_hull_depth(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, b: np.ndarray,
                    start: np.ndarray) -> np.ndarray:
    """Distance along each ray from ``origin`` to the first hull it enters (0 if it starts
    inside one; inf if none). Hull h is rows start[h]:start[h + 1] of A x <= b."""
    out = np.full(len(dirs), np.inf)
    for r in nb.prange(len(dirs)):
        d = dirs[r]
        best = np.inf
        for h in range(len(start) - 1):
            enter, leave = 0.0, np.inf
            for f in range(start[h], start[h + 1]):
                rate = A[f, 0] * d[0] + A[f, 1] * d[1] + A[f, 2] * d[2]
                room = b[f] - (A[f, 0] * origin[0] + A[f, 1] * origin[1] + A[f, 2] * origin[2])
                if rate > 1e-12:
                    leave = min(leave, room / rate)
                elif rate < -1e-12:
                    enter = max(enter, room / rate)
                elif room < 0.0:
                    leave = -1.0  # parallel to a face, outside it
                if enter > leave or enter >= best:
                    break
            if enter <= leave and enter < best:
                best = enter
        out[r] = best
    return out


def hull_depths(target: np.ndarray, hulls: list[Hull], dirs: np.ndarray) -> np.ndarray:
    """Steps (iii): the hulls projected on the sphere around the target, as the distance
    (m) at which each direction first meets one."""
    if not hulls:
        return np.full(len(dirs), np.inf)
    A = np.vstack([h.A for h in hulls])
    b = np.concatenate([h.b for h in hulls])
    start = np.cumsum([0] + [len(h.b) for h in hulls]).astype(np.int64)
    return _ray_hull_depth(np.asarray(target, float), dirs, A, b, start)


@dataclass(frozen=True)
class ClearanceMap:
    """Angular clearance (rad) per distance level and sphere direction."""

    levels: np.ndarray  # distances (m), increasing
    clearance: np.ndarray  # (levels, directions)
    depth: np.ndarray  # (directions,) distance to the nearest hull
    directions: int

    def tfv(self, offsets: np.ndarray) -> np.ndarray:
        """TFV in [0, 1] of cameras at ``offsets`` (n, 3) from the target."""
        _, table = sphere(self.directions)
        return _lookup(np.ascontiguousarray(offsets, dtype=np.float64).reshape(-1, 3),
                       self.levels, self.clearance, table)


@nb.njit(cache=True, parallel=True)
def _clearance(dirs: np.ndarray, occluded: np.ndarray, first: np.ndarray, levels: int
               ) -> np.ndarray:
    """Per level and direction, the angle to the nearest occluded direction whose first
    level is at or below it; ``occluded`` (m, 3) sorted by ``first``."""
    out = np.empty((levels, len(dirs)))
    for i in nb.prange(len(dirs)):
        best = -1.0  # cosine of the nearest so far
        j = 0
        for k in range(levels):
            while j < len(occluded) and first[j] <= k:
                c = (dirs[i, 0] * occluded[j, 0] + dirs[i, 1] * occluded[j, 1]
                     + dirs[i, 2] * occluded[j, 2])
                if c > best:
                    best = c
                j += 1
            # a direction that is itself occluded has clearance 0, not arccos(1 - eps)
            out[k, i] = 0.0 if best > 1.0 - 1e-12 else np.arccos(max(best, -1.0))
    return out


def clearance_map(target: np.ndarray, hulls: list[Hull], near: float, far: float,
                  levels: int = 48, directions: int = 16384) -> ClearanceMap:
    """The angular clearance of every sphere direction at ``levels`` distances from
    ``near`` to ``far`` (m): for every direction, the angle to the nearest direction
    occluded closer than each level's distance (an exact search, compiled)."""
    dirs, _ = sphere(directions)
    depth = hull_depths(target, hulls, dirs)
    ladder = np.linspace(near, far, levels)
    occluded = np.flatnonzero(depth < ladder[-1])
    first = np.searchsorted(ladder, depth[occluded], side="right")  # depth < ladder[first]
    order = np.argsort(first, kind="stable")
    clearance = _clearance(dirs, np.ascontiguousarray(dirs[occluded[order]]), first[order],
                           levels)
    return ClearanceMap(ladder, clearance, depth, directions)
