"""Natural fiducials (sec. 2.4): found in the image, rated with the environment model,
measured in stereo, tracked by template matching.

Candidates are corners of the left image (Shi-Tomasi, refined to sub-pixel): edges and
corners of objects, texture. Each is measured in the right image along its row (the
head's cameras are parallel, so the pair is rectified): the disparity d gives k_i of
eq. 5, the point at depth f b / d. Each is rated by the fiducial evaluation function
(eq. 8), every term scaled to [0, 1] over the candidates:

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

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from mapping import OccupancyGrid

from .targets import to_gray

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


def corners(gray: np.ndarray, count: int, min_distance: float = 8.0,
            border: int = 20) -> np.ndarray:
    """Up to ``count`` sub-pixel corners (n, 2) away from the image border."""
    found = cv2.goodFeaturesToTrack(gray, count, 0.01, min_distance)
    if found is None:
        return np.zeros((0, 2))
    found = cv2.cornerSubPix(gray, found.astype(np.float32), (5, 5), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.01))
    pts = found.reshape(-1, 2).astype(float)
    h, w = gray.shape
    keep = ((pts[:, 0] >= border) & (pts[:, 0] < w - border) & (pts[:, 1] >= border)
            & (pts[:, 1] < h - border))
    return pts[keep]


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


def _peak(scores: np.ndarray) -> tuple[int, int, float]:
    """Location (row, col) of the best match and its sub-pixel column offset."""
    _, _, _, (c, r) = cv2.minMaxLoc(scores)
    offset = 0.0
    if 0 < c < scores.shape[1] - 1:
        a, b, d = scores[r, c - 1], scores[r, c], scores[r, c + 1]
        denom = a - 2 * b + d
        offset = 0.0 if denom == 0 else 0.5 * (a - d) / denom
    return r, c, offset


def _match_row(left: np.ndarray, right: np.ndarray, uv: np.ndarray, half: int,
               max_disparity: int) -> tuple[float, float] | None:
    """Disparity (pixels) of the patch centred at the pixel nearest ``uv`` along its row
    of the other image (searching to the left), and the match score."""
    tpl = patch(left, uv, half)
    if tpl is None or float(tpl.std()) < 1e-3:
        return None
    u, v = nearest(uv)
    lo = max(u - max_disparity - half, 0)
    strip = right[v - half:v + half + 1, lo:u + half + 1]
    if strip.shape[1] < tpl.shape[1] + 2:
        return None
    scores = cv2.matchTemplate(strip, tpl, cv2.TM_CCOEFF_NORMED)
    _, c, offset = _peak(scores)
    return u - (lo + c + half + offset), float(scores[0, c])


def disparity(left: np.ndarray, right: np.ndarray, uv: np.ndarray, half: int = 7,
              max_disparity: int = 160, min_score: float = 0.9,
              agree_px: float = 0.5) -> float | None:
    """Disparity (pixels) of a left-image point in the rectified right image, by
    normalised cross-correlation along its row; None if unsure. Unsure: a weak match, or
    a patch half as wide that disagrees by more than ``agree_px`` (the point sits on a
    depth edge: a corner of an outline, not of a surface, which moves as the camera does),
    or a match back from the right image that does not land where it started, or points
    5 pixels around it at other depths."""
    big = _match_row(left, right, uv, half, max_disparity)
    small = _match_row(left, right, uv, half // 2 + 1, max_disparity)
    if big is None or small is None or big[1] < min_score or big[0] <= 0.5:
        return None
    if abs(big[0] - small[0]) > agree_px:
        return None
    u, v = nearest(uv)
    back = _match_row(right[:, ::-1], left[:, ::-1],
                      np.array([right.shape[1] - 1 - (u - big[0]), v]), half, max_disparity)
    if back is None or abs(back[0] - big[0]) > 1.0:
        return None
    for du, dv in ((-5, 0), (5, 0), (0, -5), (0, 5)):  # a surface all round, not an outline
        around = _match_row(left, right, np.array([u + du, v + dv]), half // 2 + 1,
                            max_disparity)
        if around is None or around[1] < min_score or abs(around[0] - big[0]) > 2 * agree_px:
            return None
    return big[0]


def locate(gray: np.ndarray, template: np.ndarray, predicted: np.ndarray, search_px: int,
           min_score: float = 0.85) -> tuple[np.ndarray, float] | None:
    """Where ``template`` matches best within ``search_px`` of ``predicted`` (sub-pixel),
    and its score; None if nowhere well enough."""
    half = template.shape[0] // 2
    u, v = nearest(predicted)
    h, w = gray.shape
    u0, v0 = max(u - search_px - half, 0), max(v - search_px - half, 0)
    u1, v1 = min(u + search_px + half + 1, w), min(v + search_px + half + 1, h)
    region = gray[v0:v1, u0:u1]
    if region.shape[0] < template.shape[0] or region.shape[1] < template.shape[1]:
        return None
    scores = cv2.matchTemplate(region, template, cv2.TM_CCOEFF_NORMED)
    r, c, du = _peak(scores)
    if scores[r, c] < min_score:
        return None
    dv = 0.0
    if 0 < r < scores.shape[0] - 1:
        a, b, d = scores[r - 1, c], scores[r, c], scores[r + 1, c]
        denom = a - 2 * b + d
        dv = 0.0 if denom == 0 else 0.5 * (a - d) / denom
    return np.array([u0 + c + half + du, v0 + r + half + dv]), float(scores[r, c])


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
        f = np.sqrt(sum(g ** 2 for g in np.meshgrid(*[np.fft.fftfreq(w)] * 3,
                                                     indexing="ij")))
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


def find_candidates(left_rgb: np.ndarray, right_rgb: np.ndarray, grid: OccupancyGrid,
                    to_world: Callable[[np.ndarray], np.ndarray], count: int = 200,
                    avoid: np.ndarray | None = None, avoid_px: float = 15.0
                    ) -> list[Candidate]:
    """Corners of the left image with a stereo match, rated by eq. 8. ``to_world`` maps
    (u, v, d) to a world point; ``avoid`` (m, 2) are pixels of fiducials already held."""
    left, right = to_gray(left_rgb), to_gray(right_rgb)
    p = grid.probability()
    out = []
    for uv in corners(left, count):
        if avoid is not None and len(avoid) and np.min(
                np.linalg.norm(avoid - uv, axis=1)) < avoid_px:
            continue
        d = disparity(left, right, uv)
        if d is None:
            continue
        world = to_world(np.array([uv[0], uv[1], d]))
        out.append(Candidate(uv, d, certainty(grid, p, world), visual_contrast(left, uv),
                             depth_contrast(grid, p, world)))
    rate(out)
    return out
