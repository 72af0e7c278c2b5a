"""Where a map leaves no room for a robot: the distance from any point to the nearest
cell the map holds occupied or has never observed, for planning motions around what
the robots mapped rather than what the simulator knows.

The distances come from one Euclidean distance transform of the map's cells (a voxel
grid, or a floor plan's squares); a query is a bound, never an overestimate: from a
point the nearest obstacle cell is at least its own cell's distance away, less how far
the point lies from its cell's centre and half a cell's diagonal. That bound gives away
up to a cell's diagonal (8.7 cm in a 5 cm grid); where it falls below what a query asks
(``exact_below``), the distance to the obstacle cells near the point is measured
exactly: cube by cube (square by square), what the map holds, no more.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from scipy.ndimage import distance_transform_edt

from .grid import OccupancyGrid


@dataclass(frozen=True)
class ObstacleField:
    """Per cell of a grid (2-D or 3-D), the distance (m) from its centre to the nearest
    obstacle cell's centre (``inf`` when the map has none)."""

    origin: np.ndarray  # the grid's min corner (m)
    resolution: float  # m
    centre_distance: np.ndarray  # the grid's shape, m
    obstacles: int  # how many cells are obstacles
    # the distance less half a cell's diagonal, flat, with a border of inf round the
    # grid (what lies beyond says nothing): a query's lookup
    _bound: np.ndarray = field(init=False, repr=False, compare=False)

    _strides: np.ndarray = field(init=False, repr=False, compare=False)
    _top: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        half_diagonal = self.resolution * math.sqrt(len(self.origin)) / 2
        padded = np.pad(self.centre_distance - half_diagonal, 1, constant_values=np.inf)
        object.__setattr__(self, "_bound", padded.ravel())
        object.__setattr__(self, "_strides", np.array(padded.strides) // padded.itemsize)
        object.__setattr__(self, "_top", np.array(padded.shape) - 1)

    @classmethod
    def from_mask(cls, obstacle: np.ndarray, origin: np.ndarray, resolution: float
                  ) -> ObstacleField:
        """The field of the cells ``obstacle`` (bool) of a grid with min corner
        ``origin`` (m) and cells ``resolution`` (m) wide."""
        count = int(obstacle.sum())
        if count == 0:
            distance = np.full(obstacle.shape, np.inf)
        else:
            distance = distance_transform_edt(~obstacle, sampling=resolution)
        return cls(np.asarray(origin, float).copy(), resolution, np.asarray(distance, float),
                   count)

    @classmethod
    def from_grid(cls, grid: OccupancyGrid, known: np.ndarray | None = None,
                  unobserved: bool = True) -> ObstacleField:
        """The field of ``grid``'s occupied voxels and (``unobserved``) never-observed
        ones, those ``known`` (bool, the grid's shape: explained otherwise) left out."""
        states = grid.states()
        obstacle = states >= 0 if unobserved else states > 0
        if known is not None:
            obstacle &= ~known
        return cls.from_mask(obstacle, grid.origin, grid.resolution)

    def clearance(self, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """A lower bound of each sphere's (or disc's: centres (n, d), radii (n,); m)
        distance to the nearest obstacle cell (m; negative when it may overlap one);
        ``inf`` for a centre outside the grid, where the map says nothing."""
        flat, off = self.cells(centres)
        return self._bound[flat] - off - radii

    def cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's (n, d; m) cell as an index into :attr:`bounds`, and its
        distance from that cell's centre (m)."""
        scaled = (points - self.origin) / self.resolution
        cell = np.floor(scaled)
        frac = scaled - cell - 0.5  # from the cell's centre, in cells
        idx = np.clip(cell.astype(np.intp) + 1, 0, self._top)  # into the padded grid
        return idx @ self._strides, self.resolution * np.sqrt(np.einsum("ij,ij->i", frac, frac))

    def least(self, centres: np.ndarray, radii: np.ndarray, bounds: np.ndarray | None = None,
              first: int = 0, shift: int = 0, exact_below: float = -math.inf) -> float:
        """The least of :meth:`clearance` over the spheres (inf for none), at a
        fraction of its cost; ``bounds`` (default: this field's) may be several
        fields' bounds one after the other (on grids of this shape), the first
        ``first`` spheres looked up ``shift`` further on. A sphere whose bound is below
        ``exact_below`` (m) counts with its exact distance to the obstacle cells
        instead, or ``exact_below`` if none is that near: still never an overestimate,
        and exact wherever the answer is compared with ``exact_below``."""
        return float(_least(self._bound if bounds is None else bounds, self.origin,
                            self.resolution, self._strides, self._top,
                            np.ascontiguousarray(centres), radii, first, shift, exact_below))

    @property
    def bounds(self) -> np.ndarray:
        """Per cell, flat, with a border of inf round the grid: its distance less half a
        cell's diagonal (m); a cell's bound less a point's distance from its centre is
        the point's bound."""
        return self._bound


@nb.njit(cache=True)
def _least(bound: np.ndarray, origin: np.ndarray, resolution: float, strides: np.ndarray,
           top: np.ndarray, centres: np.ndarray, radii: np.ndarray, first: int,
           shift: int, exact_below: float) -> float:  # pragma: no cover - compiled
    best = np.inf
    for i in range(centres.shape[0]):
        base = shift if i < first else 0
        flat = base
        off2 = 0.0
        for k in range(centres.shape[1]):
            scaled = (centres[i, k] - origin[k]) / resolution
            cell = np.floor(scaled)
            frac = scaled - cell - 0.5
            off2 += frac * frac
            j = min(max(int(cell) + 1, 0), top[k])
            flat += j * strides[k]
        value = bound[flat] - resolution * np.sqrt(off2) - radii[i]
        if value < exact_below and radii[i] + exact_below > 0:
            nearest = _exact(bound, origin, resolution, strides, top, centres[i],
                             radii[i] + exact_below, base)
            value = exact_below if nearest == np.inf else nearest - radii[i]
        if value < best:
            best = value
    return best


@nb.njit(cache=True)
def _gap(p: float, low: float, resolution: float) -> float:  # pragma: no cover - compiled
    """How far ``p`` lies outside the interval [low, low + resolution] (m, squared)."""
    if p < low:
        return (low - p) * (low - p)
    if p > low + resolution:
        return (p - low - resolution) * (p - low - resolution)
    return 0.0


@nb.njit(cache=True)
def _exact(bound: np.ndarray, origin: np.ndarray, resolution: float, strides: np.ndarray,
           top: np.ndarray, point: np.ndarray, reach: float,
           base: int) -> float:  # pragma: no cover - compiled
    """The distance (m) from ``point`` to the nearest obstacle cell (its cube, or square)
    of the padded grid ``bound`` (read from ``base`` on; an obstacle cell's bound is
    negative, any other's not), or inf if none is nearer than ``reach`` (m)."""
    dims = point.shape[0]
    lo = np.zeros(3, np.int64)
    hi = np.zeros(3, np.int64)  # a 2-D grid's third axis: one layer
    for a in range(dims):  # the padded grid's indices of the cells within reach
        lo[a] = max(int(np.floor((point[a] - reach - origin[a]) / resolution)), 0) + 1
        hi[a] = min(int(np.floor((point[a] + reach - origin[a]) / resolution)), top[a] - 2) + 1
    third = strides[2] if dims == 3 else 0
    best = reach * reach
    found = False
    for i in range(lo[0], hi[0] + 1):
        gi = _gap(point[0], origin[0] + (i - 1) * resolution, resolution)
        if gi >= best:
            continue
        for j in range(lo[1], hi[1] + 1):
            gj = gi + _gap(point[1], origin[1] + (j - 1) * resolution, resolution)
            if gj >= best:
                continue
            for k in range(lo[2], hi[2] + 1):
                g = gj
                if dims == 3:
                    g += _gap(point[2], origin[2] + (k - 1) * resolution, resolution)
                if g < best and bound[base + i * strides[0] + j * strides[1] + k * third] < 0:
                    best = g
                    found = True
    return math.sqrt(best) if found else np.inf
