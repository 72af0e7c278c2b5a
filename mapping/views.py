"""Expected information of camera views over an occupancy grid, and cooperative choice.

A view is a camera pose; its rays (every ``stride``-th pixel) are cast through the grid
up to ``max_range``. Gains, per ray, summed over the view:

- ``entropy`` (occlusion-aware, the paper's reference [16]): the sum over the voxels a
  ray crosses of their entropy H(v) times the probability that v is visible, the
  product of (1 - P) of the voxels before it;
- ``unobserved``: the number of never-observed voxels a ray crosses before the first
  occupied voxel (P > 0.5);
- ``rear_side``: the number of rays whose first occupied voxel is followed by a
  never-observed one (the rear side of known surfaces).

Only voxels of interest (``weight`` > 0: the target region) count; every voxel
attenuates. Voxels already expected to be seen by views chosen for this round carry no
gain (``expected``), so robots choosing in turn do not duplicate each other's views.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba as nb
import numpy as np

from .camera import Pinhole
from .grid import OccupancyGrid
from .raycast import _max_steps, _walk

GAINS = ("entropy", "unobserved", "rear_side")
Gain = Literal["entropy", "unobserved", "rear_side"]
VISIBLE = 0.5  # a voxel counts as seen by a view where its visibility exceeds this
NEGLIGIBLE = 1e-3  # rays stop once their visibility falls below this


@dataclass(frozen=True)
class View:
    """A camera pose, ``T_world_cam`` in OpenCV convention (4x4, m)."""

    T_world_cam: np.ndarray

    @property
    def position(self) -> np.ndarray:
        return self.T_world_cam[:3, 3]


def region_mask(grid: OccupancyGrid, centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Voxels whose centres lie in the box ``centre`` +- ``half`` (m)."""
    c = grid.centers()
    return np.all(np.abs(c - np.asarray(centre)) <= np.asarray(half), axis=-1)


def mean_entropy(grid: OccupancyGrid, mask: np.ndarray) -> float:
    """Mean binary entropy (bits) of the voxels in ``mask``."""
    return float(grid.entropy()[mask].mean())


def view_rays(view: View, camera: Pinhole, stride: int) -> np.ndarray:
    """Unit world directions (n, 3) of every ``stride``-th pixel of the view."""
    _, _, rays = camera.rays(stride)
    rays = rays.reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return rays @ view.T_world_cam[:3, :3].T


@nb.njit(cache=True, parallel=True)
def _gains(origin: np.ndarray, dirs: np.ndarray, length: float, shape: tuple[int, int, int],
           prob: np.ndarray, weight: np.ndarray, mode: int, max_steps: int) -> np.ndarray:
    n = len(dirs)
    out = np.zeros(n)
    no_stop = np.zeros(0, dtype=np.bool_)
    for r in nb.prange(n):
        buf = np.empty(max_steps, dtype=np.int64)
        c = _walk(origin, dirs[r], length, shape, buf, no_stop, 0.0)
        visible = 1.0
        gain = 0.0
        for s in range(c):
            v = buf[s]
            p = prob[v]
            if mode == 0:
                gain += weight[v] * visible
                visible *= 1.0 - p
                if visible < NEGLIGIBLE:
                    break
            elif mode == 1:
                if p > 0.5:
                    break
                if p == 0.5:
                    gain += weight[v]
            else:
                if p > 0.5:
                    if s + 1 < c and prob[buf[s + 1]] == 0.5:
                        gain += weight[buf[s + 1]]
                    break
        out[r] = gain
    return out


@nb.njit(cache=True, parallel=True)
def _visible(origin: np.ndarray, dirs: np.ndarray, length: float, shape: tuple[int, int, int],
             prob: np.ndarray, seen: np.ndarray, max_steps: int) -> None:
    no_stop = np.zeros(0, dtype=np.bool_)
    for r in nb.prange(len(dirs)):
        buf = np.empty(max_steps, dtype=np.int64)
        c = _walk(origin, dirs[r], length, shape, buf, no_stop, 0.0)
        visible = 1.0
        for s in range(c):
            if visible <= VISIBLE:
                break
            seen[buf[s]] = True
            visible *= 1.0 - prob[buf[s]]


@dataclass
class GainModel:
    """Evaluates views against one state of the grid."""

    grid: OccupancyGrid
    camera: Pinhole
    interest: np.ndarray  # bool per voxel: the target region
    max_range: float = 3.0
    stride: int = 16

    def __post_init__(self) -> None:
        self.prob = self.grid.probability().reshape(-1).astype(np.float64)
        self.expected = np.zeros(self.grid.size, dtype=bool)
        self._entropy = self.grid.entropy().reshape(-1).astype(np.float64)

    def _weight(self, gain: Gain) -> np.ndarray:
        base = self._entropy if gain == "entropy" else np.ones(self.grid.size)
        return np.where(self.interest.reshape(-1) & ~self.expected, base, 0.0)

    def _cast(self, view: View) -> tuple[np.ndarray, np.ndarray, float]:
        origin = (view.position - self.grid.origin) / self.grid.resolution
        return origin, view_rays(view, self.camera, self.stride), self.max_range / \
            self.grid.resolution

    def gains(self, views: list[View], gain: Gain = "entropy") -> np.ndarray:
        """The gain of each view (bits for ``entropy``, voxel or ray counts otherwise)."""
        weight = self._weight(gain)
        out = np.empty(len(views))
        shape = self.grid.shape
        for i, view in enumerate(views):
            origin, dirs, length = self._cast(view)
            out[i] = _gains(origin, dirs, length, shape, self.prob, weight, GAINS.index(gain),
                            _max_steps(shape)).sum()
        return out

    def expect(self, view: View) -> None:
        """Count the voxels ``view`` will see as observed for the views chosen after it."""
        self.expected |= self.seen_by(view)

    def seen_by(self, view: View) -> np.ndarray:
        """Flat bool per voxel: would ``view`` see it (visibility above 0.5)?"""
        seen = np.zeros(self.grid.size, dtype=bool)
        origin, dirs, length = self._cast(view)
        _visible(origin, dirs, length, self.grid.shape, self.prob, seen,
                 _max_steps(self.grid.shape))
        return seen
