"""Where a box model's edges are in an image: the colour step nearest each predicted
edge point along its normal (sub-pixel), and, for a start too uncertain for that, the
image shift that puts the whole model on the image's edges, or its silhouette on the
object's colour region (calibration/edge_fit.py uses both)."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from scipy.special import ndtr

from .edge_model import NEARER_PX, Boxes, Samples, Seen, StereoRig

MIN_STEP = 12.0  # a colour step weaker than this (RGB 0-255 per pixel of profile) is no edge
MAX_REACH_PX = 20  # edges are aligned at most this far: beyond, texture outnumbers them
DEPTH_HYPOTHESES = 9  # distances tried by the region alignment, across +-3 sd
MAX_REGION_REACH_PX = 80  # a region at most this far (its object's colour does not alias)
HYPOTHESES = 4  # starts fitted from the alignment's best shifts
HYPOTHESIS_SHARE = 0.7  # ... those scoring at least this share of the best


def search_edges(image: np.ndarray, pixels: np.ndarray, normals: np.ndarray,
                 reach_px: int, limit: np.ndarray | None = None) -> np.ndarray:
    """Signed offset (px, along each normal) of the strongest colour step within
    ``reach_px`` of each pixel (and within its ``limit``, px, if given) that is a local
    maximum nearest it, interpolated between pixels; NaN where there is none. ``image``
    is float (h, w, channels)."""
    offsets = np.arange(-reach_px - 2, reach_px + 3, dtype=np.float32)  # two more each end
    xs = (pixels[:, None, 0] + offsets[None, :] * normals[:, None, 0]).astype(np.float32)
    ys = (pixels[:, None, 1] + offsets[None, :] * normals[:, None, 1]).astype(np.float32)
    profile = cv2.remap(image, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    profile = profile.reshape(len(pixels), len(offsets), -1)
    step = np.linalg.norm(profile[:, 2:] - profile[:, :-2], axis=2) / 2  # -reach-1 .. reach+1
    inner = step[:, 1:-1]  # -reach .. reach
    left, right = step[:, :-2], step[:, 2:]
    peak = (inner >= left) & (inner > right) & (inner >= MIN_STEP)
    at = np.arange(-reach_px, reach_px + 1)
    if limit is not None:
        peak &= np.abs(at)[None, :] <= limit[:, None]
    distance = np.where(peak, np.abs(at)[None, :], np.inf)
    # the nearest peak among those at least half as strong as the strongest in reach
    strong = inner >= 0.5 * np.max(np.where(peak, inner, 0.0), axis=1, keepdims=True)
    distance = np.where(strong, distance, np.inf)
    best = np.argmin(distance, axis=1)
    found = np.isfinite(distance[np.arange(len(best)), best])
    k = np.arange(len(best))
    y0, y1, y2 = left[k, best], inner[k, best], right[k, best]
    curvature = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(curvature < 0, 0.5 * (y0 - y2) / curvature, 0.0)
    result = at[best] + np.clip(shift, -0.5, 0.5)
    return np.where(found, result, np.nan)


# The synthetic profiles :func:`merge_bias_px` measures the search on: neighbour
# distances (px) and the lens's blur (Gaussian sd, px) tabulated, and the neighbour's
# colour step relative to the edge's own (either sign) and the edge's sub-pixel phases
# over which the bias is averaged
MERGE_DISTANCES_PX = np.arange(0.0, 8.01, 0.25)
MERGE_BLURS_PX = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0])
MERGE_CONTRASTS = np.array([-1.0, -0.75, -0.5, -0.25, 0.25, 0.5, 0.75, 1.0])
MERGE_PHASES = np.array([0.0, 0.25, 0.5, 0.75])


def pixel_steps(edges: np.ndarray, n: int, blur_px: float) -> np.ndarray:
    """Unit colour steps at ``edges`` (m, px) blurred by a Gaussian of sd ``blur_px``,
    each pixel's mean over its area [j, j + 1) (m, n): the area under the blurred step,
    integrated in closed form (the integral of the normal CDF is z CDF(z) + pdf(z))."""
    z = np.arange(n + 1.0)[None, :] - np.asarray(edges, float)[:, None]
    if blur_px == 0:
        area = np.clip(z, 0.0, None)
    else:
        u = z / blur_px
        area = blur_px * (u * ndtr(u) + np.exp(-0.5 * u * u) / math.sqrt(2 * math.pi))
    return np.diff(area, axis=1)


@functools.cache
def _merge_table() -> np.ndarray:
    """RMS offset (px) of the step :func:`search_edges` finds from the true one, when
    another step lies a given distance away (searched at most halfway to it), per
    (blur, distance) of the tabulated ones."""
    n, own = 48, 24.0  # profile length (px), the edge (px)
    table = np.zeros((len(MERGE_BLURS_PX), len(MERGE_DISTANCES_PX)))
    d, c, phase = (a.ravel() for a in np.meshgrid(MERGE_DISTANCES_PX, MERGE_CONTRASTS,
                                                  MERGE_PHASES, indexing="ij"))
    edge = own + phase
    contrast = np.where(d > 0, c, 0.0)[:, None]
    limits = np.where(d > 0, d / 2, np.inf)
    for i, blur in enumerate(MERGE_BLURS_PX):
        rows = 100.0 * (pixel_steps(edge, n, blur) + contrast * pixel_steps(edge + d, n, blur))
        image = np.repeat(rows.astype(np.float32)[:, :, None], 3, axis=2)
        pixels = np.column_stack([edge - 0.5, np.arange(len(d))])
        found = search_edges(image, pixels, np.tile([1.0, 0.0], (len(d), 1)), 3, limits)
        shift = np.where(np.isfinite(found), found, np.minimum(limits, 3.0))
        per_distance = shift.reshape(len(MERGE_DISTANCES_PX), -1)
        table[i] = np.sqrt(np.mean(per_distance ** 2, axis=1))
    return table


def merge_bias_px(distance_px: np.ndarray, blur_sd_px: float) -> np.ndarray:
    """How far (px, RMS) an edge's found step may lie from its true place because
    another step lies ``distance_px`` away across it: blurred (the lens's ``blur_sd_px``,
    the pixels' area, the search's central difference), two steps closer than a few
    blur widths merge into one, found between or beyond them. Measured on
    :func:`search_edges` itself with synthetic steps; 0 for isolated edges."""
    excess = _merge_excess(float(np.clip(blur_sd_px, MERGE_BLURS_PX[0], MERGE_BLURS_PX[-1])))
    d = np.asarray(distance_px, float)
    return np.where(np.isfinite(d), np.interp(d, MERGE_DISTANCES_PX, excess, right=0.0), 0.0)


@functools.lru_cache(maxsize=64)
def _merge_excess(blur: float) -> np.ndarray:
    """:func:`merge_bias_px`'s bias per tabulated distance at one blur (px), less what
    the search errs by on an isolated step: that is each point's own noise."""
    table = _merge_table()
    row = np.array([np.interp(blur, MERGE_BLURS_PX, table[:, j])
                    for j in range(len(MERGE_DISTANCES_PX))])
    excess = np.sqrt(np.maximum(row ** 2 - row[-1] ** 2, 0.0))
    excess.flags.writeable = False  # shared by every call at this blur
    return excess


def search_reach_px(pose: np.ndarray, boxes: Boxes, rig: StereoRig, sd_m: float,
                    sd_rad: float) -> int:
    """How far (px) to search at first: three standard deviations of where an edge of the
    model at ``pose`` may project, for a pose uncertain by ``sd_m`` and ``sd_rad``."""
    corners = boxes.centres + boxes.halves  # any point of the model: a lever arm
    X = corners @ pose[:3, :3].T + pose[:3, 3]
    lever = float(np.max(np.linalg.norm(X - X.mean(axis=0), axis=1))) + float(
        np.max(np.linalg.norm(boxes.halves, axis=1)))
    z = float(np.min(X[:, 2]))
    return int(np.ceil(3 * (sd_m + sd_rad * lever) * rig.fx / max(z, 1e-3)))


def align(frames: list[np.ndarray], samples: list[Samples], reach_px: int
          ) -> list[np.ndarray]:
    """Image shifts (du, dv, px, within ``reach_px``) that put the model's projected edges
    on colour steps across them, in both images at once: the local maxima of that score
    over an exhaustive search, best first, down to HYPOTHESIS_SHARE of the best. A model
    of parallel edges (rails, a thin panel's faces) scores nearly as well one edge over:
    each of these is then fitted, and the fit that explains the most edges is kept."""
    shifts = np.arange(-reach_px, reach_px + 1, dtype=np.float32)
    du, dv = np.meshgrid(shifts, shifts)
    score = np.zeros(du.shape, np.float32)
    for frame, sample in zip(frames, samples, strict=True):
        if len(sample.points) == 0:
            continue
        gx, gy = _gradients(frame)
        xs = (sample.pixels[:, 0, None] + du.ravel()[None, :]).astype(np.float32)
        ys = (sample.pixels[:, 1, None] + dv.ravel()[None, :]).astype(np.float32)
        sx = cv2.remap(gx, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        sy = cv2.remap(gy, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        n = sample.normals
        across = np.linalg.norm(sx * n[:, None, 0:1] + sy * n[:, None, 1:2], axis=-1)
        # a sample counts once, however strong its step: texture must not outvote edges
        score += np.minimum(across / (2 * MIN_STEP), 1.0).sum(axis=0).reshape(du.shape)
    peaks = (score == cv2.dilate(score, np.ones((3, 3), np.uint8))) & (
        score >= HYPOTHESIS_SHARE * score.max()) & (score > 0)
    order = np.argsort(-score[peaks])[:HYPOTHESES]
    return [np.array([du[peaks][i], dv[peaks][i]]) for i in order]


# a box's eight corners, in half extents
CORNERS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)


def silhouette(pose: np.ndarray, boxes: Boxes, rig: StereoRig, shape: tuple[int, int],
               camera: int = 0) -> np.ndarray:
    """The model's silhouette in camera ``camera``'s image (bool, ``shape``): its boxes'
    projected hulls."""
    out = np.zeros(shape, np.uint8)
    for c, h in zip(boxes.centres, boxes.halves, strict=True):
        X = (c + CORNERS * h) @ pose[:3, :3].T + pose[:3, 3]
        if (X[:, 2] <= 0).any():
            continue
        hull = cv2.convexHull(np.round(rig.project(X, camera)).astype(np.int32))
        cv2.fillConvexPoly(out, hull, 1)
    return out.astype(bool)


def _region_scores(mask: np.ndarray, pose: np.ndarray, boxes: Boxes, rig: StereoRig,
                   camera: int, reach_px: int, unseen: np.ndarray | None = None
                   ) -> np.ndarray | None:
    """For every image shift within ``reach_px`` ((2 reach + 1)^2, rows then columns):
    silhouette pixels on ``mask`` minus those off it, but for the ``unseen`` ones
    (something nearer covers them: they count nothing)."""
    shape = silhouette(pose, boxes, rig, mask.shape, camera)
    ys, xs = np.nonzero(shape)
    if len(ys) == 0:
        return None
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    signed = 2 * mask.astype(np.float32) - 1
    if unseen is not None:
        signed[unseen & ~mask] = 0.0
    signed = np.pad(signed, reach_px, constant_values=-1)
    area = signed[y0:y1 + 2 * reach_px, x0:x1 + 2 * reach_px]
    template = shape[y0:y1, x0:x1].astype(np.float32)
    if area.shape[0] < template.shape[0] or area.shape[1] < template.shape[1]:
        return None
    return cv2.matchTemplate(area, template, cv2.TM_CCORR)


def in_front(seen: Seen, pose: np.ndarray, boxes: Boxes, rig: StereoRig, depth_sd_m: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """The pixels of the left and right images where the pair saw something nearer than
    any point of the model at ``pose`` (its depth uncertain by ``depth_sd_m``), by more
    than ``Seen.hides`` allows: whether the model is behind them, no image can say."""
    corners = (boxes.centres[:, None] + CORNERS[None] * boxes.halves[:, None]).reshape(-1, 3)
    nearest = float(np.max((corners @ pose[:3, :3].T + pose[:3, 3])[:, 2].clip(1e-6) ** -1))
    own = rig.fx * rig.baseline_m * nearest
    limit = own + NEARER_PX + 3 * depth_sd_m * own * nearest
    with np.errstate(invalid="ignore"):
        left = np.isfinite(seen.disparity) & (seen.disparity > limit)
    v, u = np.nonzero(left)
    ur = np.rint(u - seen.disparity[v, u]).astype(int)
    right = np.zeros_like(left)
    keep = (ur >= 0) & (ur < left.shape[1])
    right[v[keep], ur[keep]] = True
    return left, right


def align_region(masks: tuple[np.ndarray, np.ndarray], pose: np.ndarray, boxes: Boxes,
                 rig: StereoRig, reach_px: int, depth_sd_m: float,
                 seen: Seen | None = None) -> np.ndarray:
    """The pose, moved from ``pose`` across the image (within ``reach_px``) and along the
    line of sight (within three ``depth_sd_m``), whose silhouettes best lay over
    ``masks``, the object's pixels in the left and right images (found by its colour):
    each silhouette pixel on a mask counts one, off it minus one, and nothing where the
    pair saw something in front of the object (``seen``: ``in_front``). Regions do not
    alias as parallel edges and texture do, and the two images together tell the
    distance (by the disparity, where the region's size cannot: a thin panel seen
    end-on)."""
    centre = pose[:3, :3] @ boxes.centres.mean(axis=0) + pose[:3, 3]
    ray = centre / np.linalg.norm(centre)
    unseen = (None, None) if seen is None else in_front(seen, pose, boxes, rig, depth_sd_m)
    best, best_pose = -np.inf, pose
    for along in np.linspace(-3 * depth_sd_m, 3 * depth_sd_m, DEPTH_HYPOTHESES):
        moved = pose.copy()
        moved[:3, 3] += along * ray
        z = float((moved[:3, :3] @ boxes.centres.mean(axis=0) + moved[:3, 3])[2])
        if z <= 0.05:
            continue
        maps = [_region_scores(m, moved, boxes, rig, c, reach_px, unseen[c])
                for c, m in enumerate(masks)]
        if any(m is None for m in maps):
            continue
        score = sum(m for m in maps if m is not None)
        assert isinstance(score, np.ndarray)
        if float(score.max()) > best:
            dv, du = np.unravel_index(int(np.argmax(score)), score.shape)
            moved[:3, 3] += [(du - reach_px) * z / rig.fx, (dv - reach_px) * z / rig.fy, 0.0]
            best, best_pose = float(score.max()), moved
    return best_pose


def _gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An image's colour gradients along x and y (per channel, per pixel)."""
    return (cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3) / 8,
            cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3) / 8)
