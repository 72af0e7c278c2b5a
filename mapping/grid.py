"""Probabilistic voxel occupancy grid in log-odds (0.5 = unknown), OctoMap's sensor model."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def logit(p: float | np.ndarray) -> np.ndarray:
    return np.log(np.asarray(p) / (1 - np.asarray(p)))


@dataclass(frozen=True)
class SensorModel:
    """Probability a voxel is occupied given a hit / a miss, and the clamping bounds."""

    hit: float = 0.7
    miss: float = 0.4
    clamp_min: float = 0.12
    clamp_max: float = 0.97

    def __post_init__(self) -> None:
        if not 0 < self.clamp_min < self.miss < 0.5 < self.hit < self.clamp_max < 1:
            raise ValueError(
                f"sensor model needs 0 < clamp_min < miss < 0.5 < hit < clamp_max < 1, got {self}"
            )


@dataclass
class OccupancyGrid:
    """A box of cubic voxels; ``origin`` is the min corner (m), ``shape`` counts voxels."""

    origin: np.ndarray
    resolution: float
    shape: tuple[int, int, int]
    model: SensorModel = field(default_factory=SensorModel)
    log_odds: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=float)
        self.log_odds = np.zeros(self.shape, dtype=np.float32)

    @classmethod
    def from_bounds(cls, lo: np.ndarray, hi: np.ndarray, resolution: float,
                    model: SensorModel | None = None) -> OccupancyGrid:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        shape = tuple(int(n) for n in np.ceil((hi - lo) / resolution - 1e-9).astype(int))
        return cls(lo, resolution, (shape[0], shape[1], shape[2]), model or SensorModel())

    @property
    def upper(self) -> np.ndarray:
        return self.origin + self.resolution * np.array(self.shape)

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
        """P(occupied) per voxel."""
        return 1.0 / (1.0 + np.exp(-self.log_odds))

    def probability_at(self, points: np.ndarray, outside: float = 0.5) -> np.ndarray:
        """P(occupied) at points (n, 3); ``outside`` for points beyond the grid."""
        idx = self.index(points)
        ok = self.inside(idx)
        p = np.full(len(idx), outside, dtype=float)
        i = idx[ok]
        p[ok] = 1.0 / (1.0 + np.exp(-self.log_odds[i[:, 0], i[:, 1], i[:, 2]]))
        return p

    def entropy(self) -> np.ndarray:
        """Binary entropy per voxel (bits)."""
        p = np.clip(self.probability(), 1e-12, 1 - 1e-12)
        return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))

    def update(self, free: np.ndarray, occupied: np.ndarray) -> None:
        """One scan's evidence: flat voxel indices observed free / occupied, each once."""
        flat = self.log_odds.reshape(-1)
        lo, hi = logit(self.model.clamp_min), logit(self.model.clamp_max)
        flat[free] = np.clip(flat[free] + logit(self.model.miss), lo, hi)
        flat[occupied] = np.clip(flat[occupied] + logit(self.model.hit), lo, hi)
