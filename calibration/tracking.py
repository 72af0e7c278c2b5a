"""Natural fiducials tracked through a move, and the camera's path from them (sec. 2.4).

A move is seen as a sequence of stereo frames. In each, SIFT keypoints of the left
image (blobs and corners of the surface texture and of object edges: natural fiducials)
are matched to the right image along their row (the head's pair is rectified), which
gives each a disparity: a measurement z = (u, v, d).

The first frame's pose is known (the move has not erred yet). Every later frame is
located from the fiducials it finds again:

1. the predicted pose (the last located pose moved by the commanded motion since)
   projects every known fiducial into the image; a keypoint within ``search_px`` of a
   projection whose descriptor is clearly the closest of those around is a candidate;
2. RANSAC PnP keeps the candidates consistent with one pose;
3. projecting with that pose finds the rest, within ``inlier_px``, and SQPnP on all of
   them gives the frame's pose, unless it jumps implausibly far from the prediction.

Keypoints found again extend their fiducial's track; the others start new fiducials,
triangulated from the frame: every located frame seeds, however few fiducials located it,
since the bundle adjustment at the end re-estimates each new fiducial and the frame's pose
from all their views (a frame located from a few, as the camera comes out of a view
without texture, is what carries the track on into the next textured one). A frame where
fewer than ``min_inliers`` agree is not located (the prediction stands in for it) and
adds nothing. At the end a bundle
adjustment (calibration/bundle.py) over the located frames refines every pose and every
fiducial seen twice or more, the first pose held fixed: each fiducial is then
triangulated over the camera's whole path, not just the head's baseline.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .bundle import BundleResult, Keyframe, refine, triangulate
from .ekf import StereoCamera
from .flow import flow_disparities, nearest_disparity
from .pose import DegenerateGeometryError, invert, rotation_deg, sqpnp

T = TypeVar("T")
# A descriptor further than this from a fiducial's matches nothing: SIFT's are
# L2-normalised to 512, ORB's are 256 bits (Hamming distance; 64 is a quarter of them).
DESCRIPTOR_MAX = {"sift": 300.0, "orb": 64.0}


@dataclass(frozen=True)
class TrackerSettings:
    """How fiducials are found and followed (pixels unless stated)."""

    detector: str = "sift"  # "sift" or "orb" (FAST corners refined to sub-pixel)
    stereo: str = "descriptors"  # right pixels by "descriptors", "flow" (calibration/flow.py)
    # or "correlation" along the row
    row_px: float = 1.0  # with "descriptors": a stereo match's rows differ by at most this
    features: int = 800  # keypoints per image at most
    contrast: float = 0.01  # SIFT contrast threshold (of intensities in [0, 1])
    ratio: float = 0.8  # a fiducial match's descriptor distance over the runner-up's, at most
    patch_px: int = 11  # side of the patch a left keypoint is correlated along its row
    max_disparity_px: float = 160.0  # f b / 0.31 m for the default head (416 px, 0.12 m):
    # nearer than any placed camera's depth of field
    min_correlation: float = 0.8  # a stereo match's normalised correlation, at least
    peak_margin: float = 0.1  # ... and this above any other disparity's
    search_px: float = 30.0  # around the predicted projection
    inlier_px: float = 2.0
    min_inliers: int = 8
    max_jump_m: float = 0.03  # a located pose this far from the prediction is refused
    max_jump_deg: float = 2.0
    pixel_sigma: float = 0.3  # of a keypoint's position


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


@dataclass
class Frame:
    """One frame of the move: its pose (g01, world to camera; estimated, or predicted if
    not located) and the fiducials it saw {index: (u, v, d)}."""

    g01: np.ndarray
    observations: dict[int, np.ndarray]
    located: bool
    known: bool = False


@dataclass
class Fiducials:
    """Every fiducial met so far: position (world, m), latest descriptor, and track
    (left pixels, one per frame that saw it)."""

    points: list[np.ndarray] = field(default_factory=list)
    descriptors: list[np.ndarray] = field(default_factory=list)
    tracks: list[list[tuple[float, float]]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.points)

    def add(self, point: np.ndarray, descriptor: np.ndarray, pixel: np.ndarray) -> int:
        self.points.append(point)
        self.descriptors.append(descriptor)
        self.tracks.append([(float(pixel[0]), float(pixel[1]))])
        return len(self.points) - 1

    def seen(self, i: int, descriptor: np.ndarray, pixel: np.ndarray) -> None:
        self.descriptors[i] = descriptor
        self.tracks[i].append((float(pixel[0]), float(pixel[1])))


def project(camera: StereoCamera, g01: np.ndarray, points: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Left pixels (n, 2) of world points and their depths (n) in a camera at g01."""
    c = points @ g01[:3, :3].T + g01[:3, 3]
    z = np.where(np.abs(c[:, 2]) > 1e-9, c[:, 2], 1e-9)
    uv = np.column_stack([camera.fx * c[:, 0] / z + camera.cx, camera.fy * c[:, 1] / z + camera.cy])
    return uv, c[:, 2]


# How much of a fiducial's chance to be found again is left once the direction it is
# seen from has turned (deg), or its distance changed (ratio), relative to an unchanged
# view. Measured with SIFT (800 keypoints) on the default scenario's painted surfaces,
# over every pair of located frames of seeds 0 and 1 (frames every 3 deg or 3 cm; 3.0
# million fiducial sightings): found again 62 % of the time within 1 deg, 47 % at 3-5,
# 32 % at 7-10, 15 % at 20-30; at a 1.35-1.6 times the distance 36 %. Beyond the
# measured range a fiducial counts as lost.
TURN_DEG = (0.0, 1.5, 2.5, 4.0, 6.0, 8.5, 12.5, 17.5, 25.0, 30.0, 30.01)
TURN_KEPT = (1.0, 0.95, 0.85, 0.76, 0.61, 0.52, 0.40, 0.29, 0.24, 0.24, 0.0)
SCALE = (1.0, 1.05, 1.15, 1.27, 1.47, 1.8, 2.0, 2.01)
SCALE_KEPT = (1.0, 1.0, 0.81, 0.78, 0.62, 0.59, 0.59, 0.0)


def predicted_overlap(camera: StereoCamera, size: tuple[int, int], seen_from: np.ndarray,
                      now: np.ndarray, points: np.ndarray, margin_px: float = 8.0) -> float:
    """The share of ``points`` (n, 3; world), seen from a camera at g01 ``seen_from``,
    that a camera at g01 ``now`` (image ``size``: width, height in px) is expected to find
    again, relative to a frame taken where it was seen: those in front of it and
    ``margin_px`` inside the image, each weighted by how much of its chance is left after
    its view turned and its distance changed (TURN_KEPT, SCALE_KEPT)."""
    if len(points) == 0:
        return 0.0
    uv, depth = project(camera, now, points)
    inside = ((depth > 0.05) & (uv[:, 0] >= margin_px) & (uv[:, 1] >= margin_px)
              & (uv[:, 0] <= size[0] - margin_px) & (uv[:, 1] <= size[1] - margin_px))
    then_ray = invert(seen_from)[:3, 3] - points
    now_ray = invert(now)[:3, 3] - points
    d_then, d_now = np.linalg.norm(then_ray, axis=1), np.linalg.norm(now_ray, axis=1)
    cos = np.einsum("ij,ij->i", then_ray, now_ray) / np.maximum(d_then * d_now, 1e-12)
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    ratio = d_now / np.maximum(d_then, 1e-12)
    ratio = np.maximum(ratio, 1 / np.maximum(ratio, 1e-12))
    kept = np.interp(turn, TURN_DEG, TURN_KEPT) * np.interp(ratio, SCALE, SCALE_KEPT)
    return float(np.mean(np.where(inside, kept, 0.0)))


def guided_matches(camera: StereoCamera, g01: np.ndarray, points: np.ndarray,
                   descriptors: np.ndarray, found: StereoFeatures, radius_px: float,
                   ratio: float) -> np.ndarray:
    """Pairs (feature, fiducial) (m, 2): the fiducial projecting within ``radius_px`` of
    the feature whose descriptor is closest, and clearly closer than the runner-up;
    one feature per fiducial (the closest in descriptor)."""
    if len(points) == 0 or len(found) == 0:
        return np.zeros((0, 2), int)
    limit = DESCRIPTOR_MAX["orb" if found.descriptors.dtype == np.uint8 else "sift"]
    uv, depth = project(camera, g01, points)
    ahead = np.flatnonzero(depth > 0.05)
    if len(ahead) == 0:
        return np.zeros((0, 2), int)
    tree = cKDTree(uv[ahead])
    best: dict[int, tuple[float, int]] = {}
    nearby = tree.query_ball_point(found.z[:, :2], radius_px, p=np.inf)
    for j, near_j in enumerate(nearby):
        if not near_j:
            continue
        near = ahead[near_j]
        dist = descriptor_distances(descriptors[near], found.descriptors[j])
        order = np.argsort(dist)
        if dist[order[0]] > limit:
            continue
        if len(order) > 1 and dist[order[0]] > ratio * dist[order[1]]:
            continue
        i = int(near[order[0]])
        if i not in best or dist[order[0]] < best[i][0]:
            best[i] = (float(dist[order[0]]), j)
    return np.array([(j, i) for i, (_, j) in best.items()], int).reshape(-1, 2)


class FiducialTracker:
    """Follows natural fiducials through the frames of one move (see the module doc)."""

    def __init__(self, camera: StereoCamera, settings: TrackerSettings) -> None:
        self.camera = camera
        self.settings = settings
        self.K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
        self.fiducials = Fiducials()
        self.frames: list[Frame] = []

    @property
    def last_located(self) -> Frame:
        """The latest frame that was located (the first always is)."""
        return next(f for f in reversed(self.frames) if f.located)

    def _last_seen(self) -> np.ndarray:
        """World positions (n, 3) of the last located frame's fiducials."""
        last = self.last_located
        return np.array([self.fiducials.points[i] for i in last.observations]).reshape(-1, 3)

    def expected(self, predicted: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(u, v, disparity) (m, 3) of the last located frame's fiducials in front of a
        camera at ``predicted`` (g01) and inside its image of ``size`` (width, height)."""
        uv, depth = project(self.camera, predicted, self._last_seen())
        inside = ((depth > 0.05) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0)
                  & (uv[:, 0] < size[0]) & (uv[:, 1] < size[1]))
        d = self.camera.fx * self.camera.baseline / depth[inside]
        return np.column_stack([uv[inside], d])

    def overlap(self, predicted: np.ndarray, size: tuple[int, int]) -> float:
        """The share of the last located frame's fiducials a frame at ``predicted``
        (g01) would find again (:func:`predicted_overlap`)."""
        return predicted_overlap(self.camera, size, self.last_located.g01, predicted,
                                 self._last_seen())

    def start(self, found: StereoFeatures, g01: np.ndarray) -> Frame:
        """The first frame, from a known pose."""
        frame = Frame(g01, {}, located=True, known=True)
        self._new_fiducials(frame, found, set())
        self.frames.append(frame)
        return frame

    def add(self, found: StereoFeatures, predicted: np.ndarray) -> Frame:
        """A later frame, its pose predicted (g01): locate it and extend the tracks."""
        return self._add(found, predicted, self.settings)

    def retry(self, found: StereoFeatures, predicted: np.ndarray, wider: float) -> Frame:
        """The last frame, which was not located, tracked again: its fiducials looked for
        ``wider`` times as far from their predicted pixels and its pose allowed as much
        further from the prediction."""
        assert self.frames and not self.frames[-1].located, "only a frame not located"
        self.frames.pop()
        s = self.settings
        return self._add(found, predicted, dataclasses.replace(
            s, search_px=wider * s.search_px, max_jump_m=wider * s.max_jump_m,
            max_jump_deg=wider * s.max_jump_deg))

    def _add(self, found: StereoFeatures, predicted: np.ndarray, s: TrackerSettings) -> Frame:
        points = np.array(self.fiducials.points)
        descriptors = np.array(self.fiducials.descriptors)
        g01 = self._locate(found, predicted, points, descriptors, s)
        if g01 is None:
            frame = Frame(predicted, {}, located=False)
            self.frames.append(frame)
            return frame
        pairs = guided_matches(self.camera, g01, points, descriptors, found, s.inlier_px,
                               s.ratio)
        frame = Frame(g01, {}, located=True)
        for j, i in pairs:
            frame.observations[int(i)] = found.z[j]
            self.fiducials.seen(int(i), found.descriptors[j], found.z[j])
        self._new_fiducials(frame, found, {int(j) for j in pairs[:, 0]})
        self.frames.append(frame)
        return frame

    def _locate(self, found: StereoFeatures, predicted: np.ndarray, points: np.ndarray,
                descriptors: np.ndarray, s: TrackerSettings) -> np.ndarray | None:
        pairs = guided_matches(self.camera, predicted, points, descriptors, found,
                               s.search_px, s.ratio)
        if len(pairs) < s.min_inliers:
            return None
        world = points[pairs[:, 1]]
        pixels = found.z[pairs[:, 0], :2]
        ok, _, _, inliers = cv2.solvePnPRansac(world, pixels.copy(), self.K, None,
                                               reprojectionError=s.inlier_px,
                                               iterationsCount=200, flags=cv2.SOLVEPNP_SQPNP)
        if not ok or inliers is None or len(inliers) < s.min_inliers:
            return None
        keep = inliers.ravel()
        try:
            first = sqpnp(world[keep], pixels[keep], self.K)
            refound = guided_matches(self.camera, first, points, descriptors, found,
                                     s.inlier_px, s.ratio)
            if len(refound) < s.min_inliers:
                return None
            g01 = sqpnp(points[refound[:, 1]], found.z[refound[:, 0], :2], self.K)
        except DegenerateGeometryError:
            return None
        jump = predicted @ np.linalg.inv(g01)  # camera motion from the located to the predicted
        if (np.linalg.norm(jump[:3, 3]) > s.max_jump_m
                or rotation_deg(predicted, g01) > s.max_jump_deg):
            return None  # an implausible jump: more likely a false match than the truth
        return g01

    def _new_fiducials(self, frame: Frame, found: StereoFeatures, used: set[int]) -> None:
        for j in range(len(found)):
            if j not in used:
                i = self.fiducials.add(triangulate(self.camera, found.z[j], frame.g01),
                                       found.descriptors[j], found.z[j])
                frame.observations[i] = found.z[j]

    def solve(self, min_views: int = 2) -> tuple[BundleResult, list[Frame], np.ndarray]:
        """Bundle-adjust the located frames and the fiducials seen in ``min_views`` of them
        or more; returns the result, its frames, and the fiducials' indices (its points'
        order)."""
        frames = [f for f in self.frames if f.located]
        views = np.zeros(len(self.fiducials), int)
        for f in frames:
            views[list(f.observations)] += 1
        kept = np.flatnonzero(views >= min_views)
        slot = {int(i): k for k, i in enumerate(kept)}
        keyframes = [Keyframe(f.g01, {slot[i]: z for i, z in f.observations.items() if i in slot},
                              known=f.known) for f in frames]
        points = np.array(self.fiducials.points)[kept].reshape(-1, 3)
        result = refine(self.camera, keyframes, points, self.settings.pixel_sigma)
        return result, frames, kept

