"""Probabilistic voxel occupancy grid in log-odds (0.5 = unknown), OctoMap's sensor model.

Storage is 3 bytes per voxel: log-odds as int16 in thousandths (``LOG_ODDS_SCALE``) and a
uint8 stamp that marks the voxels a scan has already updated.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from .errors import MappingError

LOG_ODDS_SCALE = 1000.0  # stored log-odds units per nat


def logit(p: float | np.ndarray) -> np.ndarray:
    return np.log(np.asarray(p) / (1 - np.asarray(p)))


def stored_log_odds(p: float | np.ndarray) -> np.ndarray:
    """P(occupied) as stored: log-odds in thousandths of a nat, rounded."""
    return np.round(logit(p) * LOG_ODDS_SCALE).astype(np.int16)


@dataclass(frozen=True)
class SensorModel:
    """P(occupied) after a hit / after a miss, and the clamping bounds (OctoMap's defaults)."""

    hit: float = 0.7
    miss: float = 0.4
    clamp_min: float = 0.12
    clamp_max: float = 0.97

    def __post_init__(self) -> None:
        if not 0 < self.clamp_min < self.miss < 0.5 < self.hit < self.clamp_max < 1:
            raise MappingError(
                f"sensor model needs 0 < clamp_min < miss < 0.5 < hit < clamp_max < 1, got {self}"
            )

    def stored(self) -> tuple[int, int, int, int]:
        """(hit, miss, min, max) in stored log-odds units."""
        hit, miss, lo, hi = (int(stored_log_odds(p))
                             for p in (self.hit, self.miss, self.clamp_min, self.clamp_max))
        return hit, miss, lo, hi


@nb.njit(cache=True, parallel=True)
def _apply(stamp: np.ndarray, log_odds: np.ndarray, occupied_code: int, free_code: int,
           hit: int, miss: int, lo: int, hi: int) -> tuple[int, int]:
    """Add ``hit`` to voxels stamped occupied and ``miss`` to those stamped free, clamped."""
    n_free = 0
    n_occupied = 0
    for v in nb.prange(len(stamp)):
        s = stamp[v]
        if s == occupied_code:
            log_odds[v] = min(max(log_odds[v] + hit, lo), hi)
            n_occupied += 1
        elif s == free_code:
            log_odds[v] = min(max(log_odds[v] + miss, lo), hi)
            n_free += 1
    return n_free, n_occupied


@dataclass
class OccupancyGrid:
    """A box of cubic voxels; ``origin`` is the min corner (m), ``shape`` counts voxels."""

    origin: np.ndarray
    resolution: float
    shape: tuple[int, int, int]
    model: SensorModel = field(default_factory=SensorModel)
    log_odds: np.ndarray = field(init=False, repr=False)  # int16, thousandths of a nat
    stamp: np.ndarray = field(init=False, repr=False)  # uint8, see begin_scan
    _scan: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=float)
        self.log_odds = np.zeros(self.shape, dtype=np.int16)
        self.stamp = np.zeros(self.shape, dtype=np.uint8)

    @classmethod
    def from_bounds(cls, lo: np.ndarray, hi: np.ndarray, resolution: float,
                    model: SensorModel | None = None) -> OccupancyGrid:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        n = np.ceil((hi - lo) / resolution - 1e-9).astype(int)
        return cls(lo, resolution, (int(n[0]), int(n[1]), int(n[2])), model or SensorModel())

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def nbytes(self) -> int:
        """Memory held per grid (bytes)."""
        return int(self.log_odds.nbytes + self.stamp.nbytes)

    def index(self, points: np.ndarray) -> np.ndarray:
        """Integer voxel indices (n, 3) of points (n, 3); may lie outside the grid."""
        return np.floor((np.asarray(points) - self.origin) / self.resolution).astype(np.int64)

    def inside(self, idx: np.ndarray) -> np.ndarray:
        return np.all((idx >= 0) & (idx < np.array(self.shape)), axis=-1)

    def centers(self, idx: np.ndarray | None = None) -> np.ndarray:
        """Voxel centres (m) of indices (n, 3), or of every voxel (shape + (3,))."""
        if idx is None:
            idx = np.stack(np.meshgrid(*[np.arange(n) for n in self.shape], indexing="ij"), -1)
        return self.origin + (np.asarray(idx) + 0.5) * self.resolution

    def probability(self) -> np.ndarray:
        """P(occupied) per voxel, float32."""
        scaled = self.log_odds.astype(np.float32) * np.float32(-1.0 / LOG_ODDS_SCALE)
        return 1.0 / (1.0 + np.exp(scaled))

    def probability_at(self, points: np.ndarray, outside: float = 0.5) -> np.ndarray:
        """P(occupied) at points (n, 3); ``outside`` for points beyond the grid."""
        idx = self.index(points)
        ok = self.inside(idx)
        p = np.full(len(idx), outside, dtype=float)
        values = self.log_odds[tuple(idx[ok].T)].astype(float) / LOG_ODDS_SCALE
        p[ok] = 1.0 / (1.0 + np.exp(-values))
        return p

    def set_probability(self, p: float | np.ndarray, where: np.ndarray | None = None) -> None:
        """Overwrite P(occupied) (everywhere, or where the boolean mask is True)."""
        value = stored_log_odds(p)
        if where is None:
            self.log_odds[...] = value
        else:
            self.log_odds[where] = value

    def entropy(self) -> np.ndarray:
        """Binary entropy per voxel (bits)."""
        p = np.clip(self.probability(), 1e-7, 1 - 1e-7)
        return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))

    def states(self) -> np.ndarray:
        """Per voxel: -1 free (P < 0.5), 0 unknown (never observed or exactly 0.5), 1 occupied."""
        return np.sign(self.log_odds).astype(np.int8)

    def begin_scan(self) -> tuple[int, int]:
        """Stamp codes (occupied, free) for a new scan; no voxel carries them yet."""
        self._scan = self._scan % 127 + 1
        if self._scan == 1:
            self.stamp[...] = 0  # codes are reused after 127 scans
        return 2 * self._scan, 2 * self._scan + 1

    def end_scan(self, occupied_code: int, free_code: int) -> tuple[int, int]:
        """Apply one hit to voxels stamped occupied and one miss to those stamped free in this
        scan; each voxel at most once. Returns (free, occupied) counts."""
        hit, miss, lo, hi = self.model.stored()
        n_free, n_occ = _apply(self.stamp.reshape(-1), self.log_odds.reshape(-1),
                               occupied_code, free_code, hit, miss, lo, hi)
        return int(n_free), int(n_occ)

    def update(self, free: np.ndarray, occupied: np.ndarray) -> None:
        """One scan's evidence as flat voxel indices; occupied wins over free."""
        occupied_code, free_code = self.begin_scan()
        stamp = self.stamp.reshape(-1)
        stamp[free] = free_code
        stamp[occupied] = occupied_code
        self.end_scan(occupied_code, free_code)
