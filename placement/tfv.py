"""Target field visibility (sec. 2.3.3, step iii): expanded hulls seen from the target.

Definition implemented (the angular clearance): for a camera at distance d from the
(reduced) target, in direction u from it, TFV = theta / pi, where theta is the geodesic
angle on the sphere of radius d around the target from u to the nearest direction in
which an expanded hull lies closer than d — the angle through which the camera can
move on that sphere before the target is occluded. TFV is 0 when the target is occluded
now and 1 when nothing occludes it at that distance.

"Occluded from distance d in direction u": some expanded hull meets the sight line from
the target to the camera t + d u. The paper expands each occluder by the whole target
(exact for a camera at infinity, conservative near the camera). By default the expansion
is exact for the finite camera: the rays from a camera to every point of the target
disc fill a cone, and a sight-line point a fraction s of the way from the camera needs
the occluder expanded by the target scaled by s — so a hull's faces move in linearly
from the target (whole target) to the camera (none). ``cone=False`` gives the paper's.

Computed on a Fibonacci sphere of ``directions`` unit vectors: one ray per direction
from the target gives the distance to the nearest hull (the projection of every hull
onto the sphere, with its depth); for a ladder of ``levels`` distances the exact angle
from every direction to the nearest direction occluded closer than that distance is
found by a compiled search over the occluded directions, shallowest first. A camera takes the
clearance of its nearest sphere direction at the first level at or beyond its distance
(so a camera between levels is rated as if slightly farther: conservative). Whether a
camera close to an occluded direction is occluded now is decided exactly, by its own
sight line against the hulls, so that TFV > 0 means "every hull clears the cone".
"""

from __future__ import annotations

from collections.abc import Callable
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


@nb.njit(cache=True, inline="always")
def _cell(offset: np.ndarray, levels: np.ndarray, na: int, npol: int) -> tuple[int, int, int]:
    """An offset's distance level and its cell (azimuth, polar) of the direction table."""
    x, y, z = offset[0], offset[1], offset[2]
    d = np.sqrt(x * x + y * y + z * z)
    k = min(np.searchsorted(levels, d), len(levels) - 1)
    az = np.arctan2(y, x)
    pol = np.arccos(min(max(z / max(d, 1e-12), -1.0), 1.0))
    a = min(max(int((az + np.pi) / (2 * np.pi) * na), 0), na - 1)
    p = min(max(int(pol / np.pi * npol), 0), npol - 1)
    return k, a, p


@nb.njit(cache=True, parallel=True)
def _lookup(offsets: np.ndarray, levels: np.ndarray, clearance: np.ndarray,
            table: np.ndarray) -> np.ndarray:
    """Clearance / pi at each offset's distance level and nearest sphere direction."""
    out = np.empty(len(offsets))
    for i in nb.prange(len(offsets)):
        k, a, p = _cell(offsets[i], levels, table.shape[0], table.shape[1])
        out[i] = clearance[k, table[a, p]] / np.pi
    return out


@nb.njit(cache=True, inline="always")
def _interval(origin: np.ndarray, d: np.ndarray, scale: float, A: np.ndarray, b: np.ndarray,
              reach: np.ndarray, grown: bool, lo_f: int, hi_f: int, lo: float, hi: float,
              cut: float) -> tuple[float, float]:
    """The values x in [lo, hi] with x (scale A.d + reach) <= b - A.origin on every face of
    rows lo_f:hi_f (``reach`` counted only if ``grown``); empty (lo > hi) as soon as it
    is, or once lo reaches ``cut``."""
    for f in range(lo_f, hi_f):
        rate = scale * (A[f, 0] * d[0] + A[f, 1] * d[1] + A[f, 2] * d[2])
        if grown:
            rate += reach[f]
        room = b[f] - (A[f, 0] * origin[0] + A[f, 1] * origin[1] + A[f, 2] * origin[2])
        if rate > 1e-12:
            hi = min(hi, room / rate)
        elif rate < -1e-12:
            lo = max(lo, room / rate)
        elif room < 0.0:
            return np.inf, -np.inf  # parallel to a face, outside it
        if lo > hi or lo >= cut:
            return np.inf, -np.inf
    return lo, hi


@nb.njit(cache=True)
def _cone_feasible(origin: np.ndarray, d: np.ndarray, dist: float, A: np.ndarray,
                   b: np.ndarray, reach: np.ndarray, lo_f: int, hi_f: int) -> bool:
    """Does the hull, expanded at each point of the sight line by the part of the target
    the cone from a camera ``dist`` away along ``d`` needs there, meet that line? A point
    a fraction t of the way to the camera needs the target scaled by 1 - t: it must satisfy
    A x <= b - t reach, i.e. t (dist A.d + reach) <= b - A.origin, for some t in [0, 1]."""
    lo, hi = _interval(origin, d, dist, A, b, reach, True, lo_f, hi_f, 0.0, 1.0, np.inf)
    return lo <= hi


@nb.njit(cache=True)
def _misses(origin: np.ndarray, d: np.ndarray, dist: float, centre: np.ndarray,
            radius: float) -> bool:
    """Does the segment from ``origin`` along unit ``d`` for ``dist`` miss the sphere?"""
    x, y, z = centre[0] - origin[0], centre[1] - origin[1], centre[2] - origin[2]
    s = min(max(x * d[0] + y * d[1] + z * d[2], 0.0), dist)
    x, y, z = x - s * d[0], y - s * d[1], z - s * d[2]
    return x * x + y * y + z * z > radius * radius


@nb.njit(cache=True)
def _entry(origin: np.ndarray, d: np.ndarray, A: np.ndarray, b: np.ndarray,
           reach: np.ndarray, lo_f: int, hi_f: int, best: float) -> float:
    """Distance along the ray from ``origin`` along ``d`` at which it enters the hull
    (rows lo_f:hi_f of A x <= b): 0 if it starts inside, inf if it misses it or enters
    at or beyond ``best``."""
    lo, hi = _interval(origin, d, 1.0, A, b, reach, False, lo_f, hi_f, 0.0, np.inf, best)
    return lo if lo <= hi else np.inf


@nb.njit(cache=True)
def _hull_depth(origin: np.ndarray, d: np.ndarray, A: np.ndarray, b: np.ndarray,
                reach: np.ndarray, lo_f: int, hi_f: int, cone: bool, top: float) -> float:
    """The smallest camera distance, at most ``top``, from which the hull occludes the ray
    (inf if none). Without ``cone``, where the ray enters the fully expanded hull; with
    it, the exact distance for the cone expansion, by bisection above that entry (the
    occluded distances along a ray reach to infinity: a farther camera's cone contains a
    nearer one's)."""
    enter = _entry(origin, d, A, b, reach, lo_f, hi_f, np.inf)
    if enter > top:
        return np.inf
    if not cone:
        return enter
    if not _cone_feasible(origin, d, top, A, b, reach, lo_f, hi_f):
        return np.inf
    if _cone_feasible(origin, d, enter, A, b, reach, lo_f, hi_f):
        return enter
    low = enter
    while top - low > 1e-7:
        mid = 0.5 * (low + top)
        if _cone_feasible(origin, d, mid, A, b, reach, lo_f, hi_f):
            top = mid
        else:
            low = mid
    return top


@nb.njit(cache=True, parallel=True)
def _ray_hull_depth(origin: np.ndarray, dirs: np.ndarray, A: np.ndarray, b: np.ndarray,
                    reach: np.ndarray, start: np.ndarray, centre: np.ndarray,
                    radius: np.ndarray, cone: bool, limit: float) -> np.ndarray:
    """Per ray from ``origin``, the smallest camera distance at which any hull occludes it
    (0 if the origin is inside one; inf if none within ``limit``). Hull h is rows
    start[h]:start[h + 1] of A x <= b, inside the sphere ``centre[h]``, ``radius[h]``."""
    out = np.full(len(dirs), np.inf)
    for r in nb.prange(len(dirs)):
        best = np.inf
        for h in range(len(start) - 1):
            if _misses(origin, dirs[r], min(best, limit), centre[h], radius[h]):
                continue
            best = min(best, _hull_depth(origin, dirs[r], A, b, reach, start[h], start[h + 1],
                                         cone, min(best, limit)))
        out[r] = best
    return out


@nb.njit(cache=True, parallel=True)
def _occluded(origin: np.ndarray, offsets: np.ndarray, A: np.ndarray, b: np.ndarray,
              reach: np.ndarray, start: np.ndarray, centre: np.ndarray, radius: np.ndarray,
              cone: bool) -> np.ndarray:
    """Per camera at ``offsets`` from ``origin``: does any hull occlude it, exactly?"""
    out = np.zeros(len(offsets), dtype=np.bool_)
    for i in nb.prange(len(offsets)):
        dist = np.sqrt(offsets[i, 0] ** 2 + offsets[i, 1] ** 2 + offsets[i, 2] ** 2)
        d = offsets[i] / dist
        for h in range(len(start) - 1):
            if _misses(origin, d, dist, centre[h], radius[h]):
                continue
            if _entry(origin, d, A, b, reach, start[h], start[h + 1], dist) < dist and (
                    not cone or _cone_feasible(origin, d, dist, A, b, reach, start[h],
                                               start[h + 1])):
                out[i] = True
                break
    return out


@dataclass(frozen=True)
class PackedHulls:
    """Hulls as one face table for the compiled kernels: hull h is rows
    start[h]:start[h + 1] of A x <= b, with the target outline's reach per face, inside
    the bounding sphere centre[h], radius[h] (m)."""

    A: np.ndarray
    b: np.ndarray
    reach: np.ndarray
    start: np.ndarray
    centre: np.ndarray
    radius: np.ndarray

    @staticmethod
    def of(hulls: list[Hull]) -> PackedHulls:
        centre = np.array([h.vertices.mean(axis=0) for h in hulls]).reshape(-1, 3)
        radius = np.array([np.linalg.norm(h.vertices - c, axis=1).max() + 1e-9
                           for h, c in zip(hulls, centre, strict=True)])
        return PackedHulls(np.vstack([h.A for h in hulls] or [np.zeros((0, 3))]),
                           np.concatenate([h.b for h in hulls] or [np.zeros(0)]),
                           np.concatenate([h.reach for h in hulls] or [np.zeros(0)]),
                           np.cumsum([0] + [len(h.b) for h in hulls]).astype(np.int64),
                           centre, radius)

    def depths(self, origin: np.ndarray, dirs: np.ndarray, cone: bool, limit: float
               ) -> np.ndarray:
        """See :func:`hull_depths`."""
        return _ray_hull_depth(origin, dirs, self.A, self.b, self.reach, self.start,
                               self.centre, self.radius, cone, limit)

    def occluded(self, origin: np.ndarray, offsets: np.ndarray, cone: bool) -> np.ndarray:
        """Per camera at ``offsets`` (n, 3) from ``origin``: is it occluded, exactly?"""
        return _occluded(origin, offsets, self.A, self.b, self.reach, self.start,
                         self.centre, self.radius, cone)

    def hidden_directions(self, origin: np.ndarray, distance: float, directions: int,
                          cone: bool) -> np.ndarray:
        """Indices (increasing) of the ``sphere(directions)`` directions from which a
        camera ``distance`` (m) from ``origin`` is occluded: :meth:`occluded` on the
        directions whose sight line can meet a hull's bounding sphere (the others clear
        every hull); the same as on all of them."""
        dirs, _ = sphere(directions)
        near = self.facing(origin, directions)
        return near[self.occluded(origin, distance * dirs[near], cone)]

    def facing(self, origin: np.ndarray, directions: int) -> np.ndarray:
        """Indices (increasing) of the ``sphere(directions)`` directions within the cone
        that some hull's bounding sphere subtends from ``origin`` (every direction if
        ``origin`` is inside one), a hair wider for rounding."""
        out: list[np.ndarray] = []
        tree = _sphere_tree(directions)
        for centre, radius in zip(self.centre, self.radius, strict=True):
            away = centre - origin
            reach = float(np.linalg.norm(away))
            if reach <= radius * (1 + 1e-9):
                return np.arange(directions)
            half = np.arcsin(radius / reach) + 1e-6  # rad
            chord = 2 * np.sin(min(half, np.pi) / 2)
            out.append(np.asarray(tree.query_ball_point(away / reach, chord), dtype=np.int64))
        return np.unique(np.concatenate(out)) if out else np.zeros(0, np.int64)


def hull_depths(target: np.ndarray, hulls: list[Hull], dirs: np.ndarray, cone: bool = True,
                limit: float = 10.0) -> np.ndarray:
    """Step (iii): the hulls projected on the sphere around the target, as the camera
    distance (m) from which each direction is occluded. ``cone``: the exact expansion
    (the target scaled down toward the camera along the sight line), searched up to
    ``limit`` (m; beyond it, inf); otherwise the paper's uniform expansion by the whole
    target (conservative near the camera)."""
    return PackedHulls.of(hulls).depths(np.asarray(target, float), dirs, cone, float(limit))


@dataclass(frozen=True)
class ClearanceMap:
    """Angular clearance (rad) per distance level and sphere direction, and the hulls it
    came from (for the exact check near the occlusion boundary)."""

    levels: np.ndarray  # distances (m), increasing
    clearance: np.ndarray  # (levels, directions)
    depth: np.ndarray  # (directions,) camera distance from which each is occluded
    directions: int
    target: np.ndarray  # (3,) the reduced target (m)
    hulls: PackedHulls
    cone: bool

    def tfv(self, offsets: np.ndarray) -> np.ndarray:
        """TFV in [0, 1] of cameras at ``offsets`` (n, 3) from the target. A camera within
        two direction spacings of an occluded direction is checked exactly against the
        hulls at its own direction and distance (so the sphere's sampling never makes an
        occluded camera look visible)."""
        _, table = sphere(self.directions)
        offsets = np.ascontiguousarray(offsets, dtype=np.float64).reshape(-1, 3)
        tfv = _lookup(offsets, self.levels, self.clearance, table)
        margin = 2.0 * np.sqrt(4 * np.pi / self.directions) / np.pi  # in TFV units
        near = np.flatnonzero((tfv > 0) & (tfv < margin))
        tfv[near[self.hulls.occluded(self.target, offsets[near], self.cone)]] = 0.0
        return tfv


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
                  levels: int = 48, directions: int = 16384, cone: bool = True
                  ) -> ClearanceMap:
    """The angular clearance of every sphere direction at ``levels`` distances from
    ``near`` to ``far`` (m): for every direction, the angle to the nearest direction
    occluded closer than each level's distance (an exact search, compiled). ``cone``:
    see :func:`hull_depths`."""
    dirs, _ = sphere(directions)
    target = np.asarray(target, dtype=float)
    packed = PackedHulls.of(hulls)
    depth = packed.depths(target, dirs, cone, float(far))
    ladder = np.linspace(near, far, levels)
    occluded = np.flatnonzero(depth < ladder[-1])
    first = np.searchsorted(ladder, depth[occluded], side="right")  # depth < ladder[first]
    order = np.argsort(first, kind="stable")
    clearance = _clearance(dirs, np.ascontiguousarray(dirs[occluded[order]]), first[order],
                           levels)
    return ClearanceMap(ladder, clearance, depth, directions, target, packed, cone)


@lru_cache(maxsize=4)
def _sphere_tree(directions: int) -> cKDTree:
    """A search tree over the ``sphere(directions)`` directions."""
    return cKDTree(sphere(directions)[0])


@nb.njit(cache=True)
def _clearance_at(offsets: np.ndarray, levels: np.ndarray, table: np.ndarray,
                  dirs: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Clearance / pi of each offset as :func:`_lookup` reads it from the table
    :func:`_clearance` builds, computed for its own level and direction only."""
    out = np.empty(len(offsets))
    for i in range(len(offsets)):
        k, a, p = _cell(offsets[i], levels, table.shape[0], table.shape[1])
        j = table[a, p]
        best = -1.0  # cosine of the nearest direction occluded closer than level k
        for m in range(len(dirs)):
            if depth[m] < levels[k]:
                c = dirs[j, 0] * dirs[m, 0] + dirs[j, 1] * dirs[m, 1] + dirs[j, 2] * dirs[m, 2]
                if c > best:
                    best = c
        out[i] = (0.0 if best > 1.0 - 1e-12 else np.arccos(max(best, -1.0))) / np.pi
    return out


def distance_level(distance: float, near: float, far: float, levels: int = 48) -> float:
    """The distance (m) a camera ``distance`` from the target is rated at: the first of
    the ``levels`` from ``near`` to ``far`` at or beyond it (the last, beyond ``far``),
    as ``ClearanceMap.tfv`` and :func:`tfv_at` take it."""
    ladder = np.linspace(near, far, levels)
    return float(ladder[min(int(np.searchsorted(ladder, distance)), levels - 1)])


def tfv_at(target: np.ndarray, depth: np.ndarray, offsets: np.ndarray, near: float,
           far: float, hulls: PackedHulls | Callable[[], PackedHulls], levels: int = 48,
           directions: int = 16384, cone: bool = True) -> np.ndarray:
    """TFV in [0, 1] of cameras at ``offsets`` (n, 3) from ``target``, given the depth
    (m) from which each sphere direction is occluded (``hull_depths`` over ``directions``
    with ``limit=far``): what ``clearance_map(...).tfv(offsets)`` gives, without the
    table of every direction's clearance, so cheap for a few cameras (each scans the
    sphere once). ``depth`` is only compared with the distance level of each camera
    (the first of ``levels`` from ``near`` to ``far`` at or beyond it): for cameras at
    one level, 0 for the directions occluded from it and inf for the others will do.
    ``hulls`` (or a function making them, called only if needed) are the hulls
    ``depth`` came from, for the exact check near the occlusion boundary."""
    dirs, table = sphere(directions)
    offsets = np.ascontiguousarray(offsets, dtype=np.float64).reshape(-1, 3)
    ladder = np.linspace(near, far, levels)
    tfv = _clearance_at(offsets, ladder, table, dirs, np.ascontiguousarray(depth, np.float64))
    margin = 2.0 * np.sqrt(4 * np.pi / directions) / np.pi  # as ClearanceMap.tfv
    close = np.flatnonzero((tfv > 0) & (tfv < margin))
    if len(close):
        packed = hulls if isinstance(hulls, PackedHulls) else hulls()
        tfv[close[packed.occluded(np.asarray(target, float), offsets[close], cone)]] = 0.0
    return tfv
