"""Rating natural fiducials (sec. 2.4) with the image and the environment model.

Fiducials are found in the images by calibration/stereo_features.py and followed by
calibration/tracking.py; here each is rated by the fiducial evaluation function (eq. 8),
every term scaled to [0, 1] over the candidates:

- certainty f = P / r: P the grid's occupancy at the point (the surface voxel: the
  largest P within one voxel), r the radius (voxels, at least 1) out to which the
  certainty |2 P - 1| of the surrounding shells keeps falling;
- visual contrast g = |C| w (eq. 9): C = (I - Ī_w) / Ī_w over square windows of side w,
  w the largest before |C| starts to fall;
- depth contrast h = H w: H the highest spatial frequency holding 10 % of the peak power
  of the 3-D Fourier transform of the grid's occupancy in a cube of side w voxels around
  the point, w the largest before the spectrum's centroid moves to higher frequencies.

Fiducials are then picked greedily, best first, each pick lowering the rating of those
within ``spacing_px`` of it (the penalty for fiducials close to each other).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from taskcam.mapping import OccupancyGrid

VISUAL_WINDOWS = (3, 5, 7, 9, 11, 15, 19, 23, 31)  # pixels
DEPTH_WINDOWS = (4, 6, 8, 10)  # voxels
SHELLS = 6  # voxels: the certainty profile's reach


@dataclass
class Candidate:
    pixel: np.ndarray  # (u, v) in the left image
    disparity: float  # pixels
    certainty: float
    contrast: float
    depth_contrast: float
    rating: float = 0.0


def nearest(uv: np.ndarray) -> tuple[int, int]:
    """The pixel (column, row) nearest a sub-pixel position."""
    return int(np.rint(uv[0])), int(np.rint(uv[1]))


def patch(gray: np.ndarray, uv: np.ndarray, half: int) -> np.ndarray | None:
    """The (2 half + 1)^2 patch centred on the pixel nearest ``uv``; None at the border."""
    u, v = nearest(uv)
    h, w = gray.shape
    if u - half < 0 or v - half < 0 or u + half >= w or v + half >= h:
        return None
    return gray[v - half:v + half + 1, u - half:u + half + 1]


def certainty(grid: OccupancyGrid, p: np.ndarray, point: np.ndarray) -> float:
    """f = P / r (see the module docstring); ``p`` the grid's probabilities."""
    i = grid.index(point[None])[0]
    if not grid.inside(i[None])[0]:
        return 0.0
    lo, hi = np.maximum(i - SHELLS, 0), np.minimum(i + SHELLS + 1, grid.shape)
    block = p[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    centre = i - lo
    near = block[tuple(slice(max(c - 1, 0), c + 2) for c in centre)]
    P = float(near.max())
    idx = np.indices(block.shape).reshape(3, -1).T
    radius = np.rint(np.linalg.norm(idx - centre, axis=1)).astype(int)
    sure = np.abs(2 * block.ravel() - 1)
    profile = [sure[radius == k].mean() for k in range(1, SHELLS + 1) if np.any(radius == k)]
    r = 1  # shells over which the certainty keeps falling, from the nearest one
    while r < len(profile) and profile[r] < profile[r - 1] - 1e-6:
        r += 1
    return P / r


def visual_contrast(gray: np.ndarray, uv: np.ndarray) -> float:
    """g = |C| w (eq. 9), w the largest window before |C| falls."""
    u, v = nearest(uv)
    value = float(gray[v, u])
    best_c, best_w = 0.0, VISUAL_WINDOWS[0]
    for w in VISUAL_WINDOWS:
        win = patch(gray, uv, w // 2)
        if win is None:
            break
        mean = float(win.mean())
        c = abs(value - mean) / max(mean, 1e-3)
        if c < best_c:
            break
        best_c, best_w = c, w
    return best_c * best_w


@cache
def _frequency(w: int) -> np.ndarray:
    """The spatial frequency (cycles a voxel) of each bin of a w^3 cube's transform
    (kept for every call: read-only)."""
    f = np.sqrt(sum(g ** 2 for g in np.meshgrid(*[np.fft.fftfreq(w)] * 3, indexing="ij")))
    f.flags.writeable = False
    return f


def depth_contrast(grid: OccupancyGrid, p: np.ndarray, point: np.ndarray) -> float:
    """h = H w from the 3-D Fourier transform of the occupancy ``p`` around the point."""
    i = grid.index(point[None])[0]
    best, last_centroid = 0.0, -1.0
    for w in DEPTH_WINDOWS:
        lo = i - w // 2
        if np.any(lo < 0) or np.any(lo + w > grid.shape):
            break
        cube = p[lo[0]:lo[0] + w, lo[1]:lo[1] + w, lo[2]:lo[2] + w]
        power = np.abs(np.fft.fftn(cube - cube.mean())) ** 2
        f = _frequency(w)
        total = power.sum()
        if total <= 1e-12:
            continue
        centroid = float((power * f).sum() / total)
        if last_centroid >= 0 and centroid > last_centroid:
            break
        strong = power >= 0.1 * power.max()
        best, last_centroid = float(f[strong].max()) * w, centroid
    return best


def rate(candidates: list[Candidate]) -> None:
    """Eq. 8: each term scaled to [0, 1] over the candidates, summed."""
    if not candidates:
        return
    terms = np.array([[c.certainty, c.contrast, c.depth_contrast] for c in candidates])
    scale = np.where(terms.max(axis=0) > 0, terms.max(axis=0), 1.0)
    for c, t in zip(candidates, terms / scale, strict=True):
        c.rating = float(t.sum())


def pick(candidates: list[Candidate], count: int, spacing_px: float = 25.0,
         penalty: float = 1.5) -> list[Candidate]:
    """The ``count`` best by rating, each pick lowering the rating of its neighbours."""
    left = list(candidates)
    score = np.array([c.rating for c in left])
    chosen: list[Candidate] = []
    while left and len(chosen) < count:
        k = int(np.argmax(score))
        best = left.pop(k)
        score = np.delete(score, k)
        chosen.append(best)
        if left:
            d = np.linalg.norm(np.array([c.pixel for c in left]) - best.pixel, axis=1)
            score = score - penalty * np.exp(-((d / spacing_px) ** 2))
    return chosen

