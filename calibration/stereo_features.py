"""Keypoints of a stereo pair, the natural fiducials' measurements: found in the left image
(SIFT, spread over the image, or ORB), each with its disparity in the right image (by
descriptor match, optical flow or correlation along the row), and the distances between
their descriptors.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar

import cv2
import numpy as np

from .flow import flow_disparities, nearest_disparity
from .tracker_settings import TrackerSettings

T = TypeVar("T")
# A descriptor further than this from a fiducial's matches nothing: SIFT's are
# L2-normalised to 512, ORB's are 256 bits (Hamming distance; 64 is a quarter of them).
DESCRIPTOR_MAX = {"sift": 300.0, "orb": 64.0}


@dataclass(frozen=True)
class StereoFeatures:
    """Keypoints of a left image with a stereo match: z (n, 3) as (u, v, disparity) and
    their descriptors (n, k): SIFT's float32, ORB's uint8 bytes."""

    z: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.z)


def descriptor_distances(many: np.ndarray, one: np.ndarray) -> np.ndarray:
    """Distances (n) of descriptors ``many`` (n, k) to ``one`` (k): Hamming for bytes,
    Euclidean otherwise."""
    if many.dtype == np.uint8:
        return np.unpackbits(np.bitwise_xor(many, one), axis=1).sum(axis=1).astype(float)
    return np.asarray(np.linalg.norm(many - one, axis=1))


def _gray(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb


def _usable(mask: np.ndarray | None, shape: tuple[int, ...], margin: int = 4) -> np.ndarray:
    """8-bit detection mask: not in ``mask`` (pixels to ignore), nor within ``margin``."""
    keep = np.full(shape[:2], 255, np.uint8)
    if mask is not None:
        keep[mask] = 0
    return cv2.erode(keep, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))


SUBPIXEL = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.01)  # corner refinement
# SIFT's keypoints are kept spread over a grid of cells this size (columns, rows): a cap
# on the strongest alone gives them all to the most contrasted surface in view, and a
# known fiducial on a duller one goes undetected however well it is predicted (a wrist
# turning a textured table into view found 6 % of the last frame's fiducials again, where
# 49 % were predicted in view: the Menagerie scenario, seed 0).
SPREAD_GRID = (8, 6)


def spread(responses: np.ndarray, pixels: np.ndarray, size: tuple[int, int], n: int,
           expected: np.ndarray | None = None, grid: tuple[int, int] = SPREAD_GRID
           ) -> np.ndarray:
    """Indices of at most ``n`` keypoints (``responses`` (k), larger is stronger;
    ``pixels`` (k, 2) in an image of ``size``: width, height) spread over the image: half
    of ``n`` is shared by the cells of ``grid``, each keeping up to its share of its own
    strongest, the other half and what cells without texture leave go to the strongest
    remaining anywhere (the most repeatable). The shares are equal (8 in 800 over 48
    cells: as many as locate a frame), or, given the pixels where known fiducials are
    ``expected`` (m, 2), one cell's share for each cell and the rest in proportion to the
    fiducials expected in it: keypoints are extracted where the track needs them.
    Measured on `bench/studies/pose_correction.py`'s 24 moves, the final SQPnP estimate's error:
    the strongest alone, median 1.34 mm, worst 2.87; all of ``n`` shared equally 1.17
    and 3.94 (fiducials of dull cells, poorly placed, picked for the estimate); half of
    it 1.04 and 3.04; half, by the fiducials expected, 1.01 and 2.19."""
    if len(responses) <= n:
        return np.arange(len(responses))
    cells = grid[0] * grid[1]

    def cell_of(p: np.ndarray) -> np.ndarray:
        cols = np.clip((p[:, 0] * grid[0] / size[0]).astype(int), 0, grid[0] - 1)
        rows = np.clip((p[:, 1] * grid[1] / size[1]).astype(int), 0, grid[1] - 1)
        return rows * grid[0] + cols

    cell = cell_of(pixels)
    shares = np.full(cells, n // (2 * cells))  # half of n, shared by the cells
    if expected is not None and len(expected):
        wanted = np.bincount(cell_of(expected), minlength=cells)
        shares = n // (4 * cells) + np.floor(n / 4 * wanted / wanted.sum()).astype(int)
    order = np.lexsort((-responses, cell))  # by cell, strongest first within each
    first = np.searchsorted(cell[order], np.arange(cells))
    rank = np.arange(len(order)) - first[cell[order]]  # place within its cell
    inside = rank < shares[cell[order]]
    kept, rest = order[inside], order[~inside]
    rest = rest[np.argsort(-responses[rest], kind="stable")][: n - len(kept)]
    return np.sort(np.concatenate([kept, rest]))


class FeatureFinder:
    """Keypoints of the left image (SIFT or ORB) and their disparities in the right."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.settings = settings
        self._pool: ThreadPoolExecutor | None = None  # for the right image's keypoints
        if settings.detector == "sift":
            # every keypoint (then :func:`spread`), each where it is: OpenCV
            # otherwise places them a quarter pixel off in u and v (its doubled first
            # octave), as if the camera were turned 0.03 deg, which the track accumulates
            self.detector = cv2.SIFT_create(  # type: ignore[attr-defined]
                nfeatures=0, contrastThreshold=settings.contrast, enable_precise_upscale=True)
            self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        elif settings.detector == "orb":
            self.detector = cv2.ORB_create(  # type: ignore[attr-defined]
                nfeatures=settings.features, fastThreshold=round(255 * settings.contrast))
            self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        else:
            raise ValueError(f"detector {settings.detector!r}: 'sift' or 'orb'")

    def keypoints(self, gray: np.ndarray, mask: np.ndarray, expected: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
        """Keypoint positions (n, 2) and descriptors of an 8-bit image; SIFT's
        :func:`spread`, more of them near the pixels (m, 2) where known fiducials are
        ``expected``. ORB's FAST corners lie on whole pixels of their pyramid level: they
        are refined to sub-pixel on the image (a corner's gradient is orthogonal to its
        offset)."""
        if self.settings.detector == "sift":
            # every keypoint found, the spread ones described: describing is most of
            # SIFT's cost (about 4000 keypoints an image, 800 kept), more than building
            # its pyramid a second time for them (the same descriptors to the bit while a
            # kept keypoint lies in the doubled first octave, as every frame of the bench
            # has; 117 against 181 ms an image on one thread, 25 default-scenario frames)
            every = self.detector.detect(gray, mask)
            if not every:
                return np.zeros((0, 2)), None
            keep = spread(np.array([k.response for k in every]),
                          np.array([k.pt for k in every]), gray.shape[::-1],
                          self.settings.features, expected)
            found, descriptors = self.detector.compute(gray, [every[i] for i in keep])
        else:
            found, descriptors = self.detector.detectAndCompute(gray, mask)
        if descriptors is None or not found:
            return np.zeros((0, 2)), None
        pts: np.ndarray = np.array([k.pt for k in found], np.float32).reshape(-1, 1, 2)
        if self.settings.detector == "orb":
            pts = cv2.cornerSubPix(gray, pts, (3, 3), (-1, -1), SUBPIXEL)
        return np.asarray(pts, float).reshape(-1, 2), descriptors

    def stereo(self, left: np.ndarray, right: np.ndarray, ignore_left: np.ndarray | None = None,
               expected: np.ndarray | None = None) -> StereoFeatures:
        """Keypoints of the left image (RGB or gray) found again in the right one on the
        same row, at a positive disparity: as the keypoint of the right image whose
        descriptor matches (found on a second thread meanwhile: :meth:`_meanwhile`), with
        ``stereo = "flow"`` by optical flow (calibration/flow.py), or with
        ``"correlation"`` by correlation along the row (:func:`row_disparities`).
        ``ignore_left`` is a boolean mask of pixels not to use (the robots' own bodies: a
        right pixel on a robot can only pair with a left one there). ``expected`` (m, 3):
        (u, v, disparity) where known fiducials are predicted, so that keypoints are
        extracted there (:func:`spread`); in the right image at u - disparity."""
        gl = _gray(left)
        uv = None if expected is None else expected[:, :2]
        if self.settings.stereo == "descriptors":  # the right image's keypoints meanwhile
            in_right = None if expected is None else expected[:, :2] - expected[:, 2:3] * [1, 0]
            gr = _gray(right)
            right_keys = self._meanwhile(self.keypoints, gr, _usable(None, gr.shape), in_right)
        pts, desc = self.keypoints(gl, _usable(ignore_left, left.shape), uv)
        if desc is None:
            return StereoFeatures(np.zeros((0, 3)), np.zeros((0, 0), np.float32))
        if self.settings.stereo == "descriptors":
            d = self._descriptor_disparities(pts, desc, *right_keys.result())
        elif self.settings.stereo == "flow":
            most = self.settings.max_disparity_px
            guess = nearest_disparity(pts, expected, 0.25 * most)  # a quarter: about 1.2 m
            d = flow_disparities(gl, _gray(right), pts, guess, self.settings.row_px, most)
        else:
            d = row_disparities(gl, _gray(right), pts, self.settings)
        keep = np.isfinite(d) & (d > 0.5)
        return StereoFeatures(np.column_stack([pts[keep], d[keep]]), desc[keep])

    def _meanwhile(self, work: Callable[..., T], *args: Any) -> Future[T]:
        """``work(*args)`` on a second thread while the caller goes on, when OpenCV may
        use more than one (a sweep's workers are pinned to one: sim/experiments/
        runner.py); otherwise done now. SIFT gives the same keypoints either way."""
        if cv2.getNumThreads() > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1)
            return self._pool.submit(work, *args)
        done: Future[T] = Future()
        done.set_result(work(*args))
        return done

    def _descriptor_disparities(self, pts: np.ndarray, desc: np.ndarray, pr: np.ndarray,
                                dr: np.ndarray | None) -> np.ndarray:
        """Disparity of each left keypoint (``pts``, ``desc``) to the right keypoint
        (``pr``, ``dr``) its descriptor matches (clearly closer than the runner-up, its
        row within ``row_px``); NaN where none."""
        s = self.settings
        out = np.full(len(pts), np.nan)
        if dr is None or len(pr) < 2:
            return out
        for m in self.matcher.knnMatch(desc, dr, k=2):
            if len(m) < 2 or m[0].distance > s.ratio * m[1].distance:
                continue
            a, b = pts[m[0].queryIdx], pr[m[0].trainIdx]
            if abs(a[1] - b[1]) <= s.row_px:
                out[m[0].queryIdx] = a[0] - b[0]
        return out


def row_disparities(left: np.ndarray, right: np.ndarray, pts: np.ndarray,
                    s: TrackerSettings) -> np.ndarray:
    """Disparity (px) of each left point (n, 2) in the rectified right image, NaN where
    none is sure: the left patch (``patch_px`` a side, sampled at the sub-pixel point)
    correlated (normalised) along the right image's row over disparities 0 to
    ``max_disparity_px`` (those that keep the right patch inside the image); the peak
    must reach ``min_correlation`` and stand ``peak_margin`` above every score outside
    its lobe, and is located to sub-pixel by a parabola through it and its neighbours."""
    half, most = s.patch_px // 2, int(np.ceil(s.max_disparity_px))
    width = s.patch_px + most
    out = np.full(len(pts), np.nan)
    left_f, right_f = left.astype(np.float32), right.astype(np.float32)
    rows, cols = left.shape[:2]
    for k, (u, v) in enumerate(pts):
        if not (half < v < rows - half - 1 and half < u < cols - half - 1):
            continue
        patch = cv2.getRectSubPix(left_f, (s.patch_px, s.patch_px), (float(u), float(v)))
        centre = u - most / 2  # the strip's centre: it holds disparities 0 to most
        strip = cv2.getRectSubPix(right_f, (width, s.patch_px), (float(centre), float(v)))
        score = cv2.matchTemplate(strip, patch, cv2.TM_CCOEFF_NORMED)[0]
        score = np.nan_to_num(score[::-1], nan=-1.0)  # index j: disparity j
        score[max(int(u) - half, 0):] = -1.0  # the right patch would leave the image
        j = int(np.argmax(score))
        if score[j] < s.min_correlation or j == 0 or j == len(score) - 1:
            continue
        lo, hi = j, j  # the peak's lobe: the scores falling away from it on either side
        while lo > 0 and score[lo - 1] < score[lo]:
            lo -= 1
        while hi < len(score) - 1 and score[hi + 1] < score[hi]:
            hi += 1
        others = np.concatenate([score[:lo], score[hi + 1:]])
        if len(others) and others.max() > score[j] - s.peak_margin:
            continue
        a, b, c = score[j - 1], score[j], score[j + 1]
        curvature = a - 2 * b + c
        out[k] = j + (0.5 * (a - c) / curvature if curvature < 0 else 0.0)
    return out
