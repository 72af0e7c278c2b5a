"""A floor plan from the bases' planar laser scanners: square cells of the floor, each
free, occupied or never scanned, integrated from scans (rays in one horizontal plane).

What stands in the scan plane is seen; what is wholly below or above it is not. Cells
are free where a ray passed, occupied where one ended on something, and stay never
scanned beyond; a cell once seen occupied stays occupied (a static world).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from .obstacle_field import ObstacleField

FREE, UNSCANNED, OCCUPIED = -1, 0, 1


@dataclass
class FloorMap:
    """Square cells ``resolution`` (m) wide from ``origin`` (the min corner, x, y; m)."""

    origin: np.ndarray
    resolution: float
    shape: tuple[int, int]
    state: np.ndarray = field(init=False, repr=False)  # int8 per cell: FREE, UNSCANNED, OCCUPIED

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, float)
        self.state = np.full(self.shape, UNSCANNED, np.int8)

    @classmethod
    def from_bounds(cls, lo: np.ndarray, hi: np.ndarray, resolution: float) -> FloorMap:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        n = np.ceil((hi - lo) / resolution - 1e-9).astype(int)
        return cls(lo, resolution, (int(n[0]), int(n[1])))

    def index(self, points: np.ndarray) -> np.ndarray:
        """Cell indices (n, 2) of points (n, 2; m); may lie outside the map."""
        return np.floor((np.asarray(points) - self.origin) / self.resolution).astype(np.int64)

    def integrate(self, origin: np.ndarray, directions: np.ndarray, ranges: np.ndarray,
                  hit: np.ndarray) -> None:
        """One scan from ``origin`` (x, y; m): rays along ``directions`` (n, 2; unit)
        passed ``ranges`` (n,; m) of free floor and ended on something where ``hit``."""
        step = self.resolution / 2  # samples along each ray, half a cell apart
        # as far as the ray is free, and no farther than where it leaves the map
        top = self.origin + np.array(self.shape) * self.resolution
        with np.errstate(divide="ignore", invalid="ignore"):
            exits = np.where(directions > 0, (top - origin) / directions,
                             np.where(directions < 0, (self.origin - origin) / directions, np.inf))
        free = np.minimum(ranges - step, exits.min(axis=1))
        counts = np.ceil(np.maximum(free, 0.0) / step).astype(np.int64)
        ray = np.repeat(np.arange(len(ranges)), counts)
        along = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)) * step
        self._set(origin + along[:, None] * directions[ray], FREE)
        ends = origin + (ranges[hit] + 1e-6)[:, None] * directions[hit]
        self._set(ends, OCCUPIED)

    def _set(self, points: np.ndarray, value: int) -> None:
        idx = self.index(points)
        idx = idx[np.all((idx >= 0) & (idx < self.shape), axis=1)]
        cells = self.state[tuple(idx.T)]
        if value == FREE:  # occupied stays occupied
            self.state[tuple(idx[cells != OCCUPIED].T)] = FREE
        else:
            self.state[tuple(idx.T)] = OCCUPIED

    def field(self, known: np.ndarray | None = None, unscanned: bool = True) -> ObstacleField:
        """The field of occupied and (``unscanned``) never-scanned cells, those
        ``known`` (bool, the map's shape: explained otherwise) left out (beyond the map
        the field says nothing: it is to cover where the bases may go)."""
        obstacle = self.state != FREE if unscanned else self.state == OCCUPIED
        if known is not None:
            obstacle &= ~known
        return ObstacleField.from_mask(obstacle, self.origin, self.resolution)

    def centers(self) -> np.ndarray:
        """Cell centres (shape + (2,); m)."""
        i, j = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        return self.origin + (np.stack([i, j], -1) + 0.5) * self.resolution


def ray_directions(count: int) -> np.ndarray:
    """``count`` unit directions (count, 2) evenly round the circle, from +x."""
    a = np.arange(count) * (2 * math.pi / count)
    return np.column_stack([np.cos(a), np.sin(a)])


def drive_lengths(clear: np.ndarray, start: tuple[int, int], cell_m: float,
                  limit_m: float) -> np.ndarray:
    """The shortest drive (m) from cell ``start`` to every cell of the raster ``clear``
    (bool, (nx, ny)), through clear cells side by side or corner to corner (a diagonal
    step only where both cells beside it are clear: the base does not cut a corner);
    inf where none is at most ``limit_m`` long (Dijkstra's, as scipy has it)."""
    out = np.full(clear.shape, np.inf)
    if not clear[start]:
        return out
    index = np.full(clear.shape, -1, np.int64)
    index[clear] = np.arange(int(clear.sum()))
    i, j = np.nonzero(clear)
    rows, cols, lengths = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        k, m = i + di, j + dj
        inside = (k < clear.shape[0]) & (m >= 0) & (m < clear.shape[1])
        a, b, k, m = i[inside], j[inside], k[inside], m[inside]
        step = clear[k, m]
        if di and dj:  # the two cells a diagonal passes between
            step &= clear[a + di, b] & clear[a, b + dj]
        rows.append(index[a[step], b[step]])
        cols.append(index[k[step], m[step]])
        lengths.append(np.full(int(step.sum()), cell_m * math.hypot(di, dj)))
    n = int(clear.sum())
    graph = coo_matrix((np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(n, n)).tocsr()
    found = dijkstra(graph, directed=False, indices=int(index[start]), limit=limit_m)
    out[clear] = found
    return out
