"""Expected information of camera views over an occupancy grid, and cooperative choice.

A view is a camera pose; its rays (every ``stride``-th pixel) are cast through the grid
up to ``max_range``. Gains, per ray, summed over the view:

- ``entropy`` (occlusion-aware, the paper's reference [16]): the sum over the voxels
  the rays cross of their entropy H(v) times the probability that v is visible, the
  product of (1 - P) of the voxels before it on the ray (the best ray's, as each voxel
  counts once per view however many rays cross it). On the way, a never-observed voxel
  may count with a prior ``unknown_occupancy`` instead of 0.5 (most space is empty), and
  a voxel below ``free_below`` (the paper's P < 0.05: known empty) as empty;
- ``unobserved``: the number of never-observed voxels crossed before a ray's first
  occupied voxel (P > 0.5);
- ``rear_side``: the number of never-observed voxels right behind a ray's first
  occupied voxel (the rear side of known surfaces).

Only voxels of interest (the target region) count; every voxel attenuates. A view
chosen for this round is expected to observe each voxel with its visibility: later
views count a voxel only by the probability that no chosen view sees it (the product
of 1 - visibility over the chosen views), so robots choosing in turn do not duplicate
each other's views.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba as nb
import numpy as np

from .camera import Pinhole
from .grid import OccupancyGrid
from .raycast import max_ray_voxels, walk_segment

GAINS = ("entropy", "unobserved", "rear_side")
Gain = Literal["entropy", "unobserved", "rear_side"]
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


@nb.njit(cache=True)
def _footprint(origin: np.ndarray, dirs: np.ndarray, length: float,
               shape: tuple[int, int, int], opacity: np.ndarray, state: np.ndarray, mode: int,
               out: np.ndarray, max_steps: int) -> None:
    """Per voxel, the most any ray of a view gives it (each voxel counts once per view):
    mode 0, the probability it is visible (the product of 1 - ``opacity`` before it);
    1, whether it is a never-observed voxel (``state`` 0) before the first occupied one
    (``state`` 1); 2, whether it is the never-observed voxel right behind the first
    occupied one. Serial, so the result is the same on every run."""
    buf = np.empty(max_steps, dtype=np.int64)
    no_stop = np.zeros(0, dtype=np.bool_)
    for r in range(len(dirs)):
        c = walk_segment(origin, dirs[r], length, shape, buf, no_stop, 0.0)
        visible = 1.0
        for s in range(c):
            v = buf[s]
            if mode == 0:
                out[v] = max(out[v], visible)
                visible *= 1.0 - opacity[v]
                if visible < NEGLIGIBLE:
                    break
            elif state[v] == 1:
                if mode == 2 and s + 1 < c and state[buf[s + 1]] == 0:
                    out[buf[s + 1]] = 1.0
                break
            elif mode == 1 and state[v] == 0:
                out[v] = 1.0


@dataclass
class GainModel:
    """Evaluates views against one state of the grid."""

    grid: OccupancyGrid
    camera: Pinhole
    interest: np.ndarray  # bool per voxel: the target region
    max_range: float = 3.0
    stride: int = 16
    unknown_occupancy: float = 0.5  # P used for never-observed voxels on the way
    free_below: float = 0.0  # voxels with P below this are empty on the way

    def __post_init__(self) -> None:
        prob = self.grid.probability().reshape(-1).astype(np.float64)
        self.state = self.grid.states().reshape(-1)
        # P(occupied) of the voxels a ray passes: the map's, except never-observed voxels
        # (a prior instead of 0.5) and voxels known to be empty (0)
        self.opacity = np.where(self.state == 0, self.unknown_occupancy,
                                np.where(prob < self.free_below, 0.0, prob))
        # probability that no view chosen so far observes each voxel
        self.unseen = np.ones(self.grid.size)
        self._entropy = self.grid.entropy().reshape(-1).astype(np.float64)

    def _weight(self, gain: Gain) -> np.ndarray:
        base = self._entropy if gain == "entropy" else np.ones(self.grid.size)
        return np.where(self.interest.reshape(-1), base * self.unseen, 0.0)

    def _cast(self, view: View) -> tuple[np.ndarray, np.ndarray, float]:
        origin = (view.position - self.grid.origin) / self.grid.resolution
        length = self.max_range / self.grid.resolution
        return origin, view_rays(view, self.camera, self.stride), length

    def footprint(self, view: View, gain: Gain = "entropy") -> np.ndarray:
        """Flat, per voxel: what ``view`` gives it (see ``_footprint``); for ``entropy``,
        the probability that the view sees it."""
        out = np.zeros(self.grid.size)
        origin, dirs, length = self._cast(view)
        _footprint(origin, dirs, length, self.grid.shape, self.opacity, self.state,
                   GAINS.index(gain), out, max_ray_voxels(self.grid.shape))
        return out

    def gains(self, views: list[View], gain: Gain = "entropy") -> np.ndarray:
        """The gain of each view: the sum over the voxels of interest it reaches, each
        once, of their weight (entropy in bits, or 1) times what the view gives them."""
        weight = self._weight(gain)
        return np.array([float(weight @ self.footprint(view, gain)) for view in views])

    def expect(self, view: View) -> None:
        """Take ``view`` as chosen: the views rated after it count what it may miss."""
        self.unseen *= 1.0 - self.footprint(view)
