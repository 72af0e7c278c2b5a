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
triangulated from the frame, if it was located from ``min_seeding`` fiducials or more
(a poorly located frame would seed a displaced copy of the scene). A frame where fewer
than ``min_inliers`` agree is not located (the prediction stands in for it) and adds
nothing. At the end a bundle
adjustment (calibration/bundle.py) over the located frames refines every pose and every
fiducial seen twice or more, the first pose held fixed: each fiducial is then
triangulated over the camera's whole path, not just the head's baseline.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .bundle import BundleResult, Keyframe, refine, triangulate
from .ekf import StereoCamera
from .pose import DegenerateGeometryError, rotation_deg, sqpnp

DESCRIPTOR_MAX = 300.0  # SIFT descriptor distance beyond which nothing matches


@dataclass(frozen=True)
class TrackerSettings:
    """How fiducials are found and followed (pixels unless stated)."""

    features: int = 800  # SIFT keypoints per image at most
    contrast: float = 0.01  # SIFT contrast threshold (of intensities in [0, 1])
    ratio: float = 0.8  # a match's descriptor distance over the runner-up's, at most
    row_px: float = 1.0  # a stereo match's rows differ by at most this
    search_px: float = 30.0  # around the predicted projection
    inlier_px: float = 2.0
    min_inliers: int = 8
    min_seeding: int = 20  # a frame located from fewer starts no new fiducials
    max_jump_m: float = 0.03  # a located pose this far from the prediction is refused
    max_jump_deg: float = 2.0
    pixel_sigma: float = 0.3  # of a keypoint's position


@dataclass(frozen=True)
class StereoFeatures:
    """Keypoints of a left image with a stereo match: z (n, 3) as (u, v, disparity) and
    SIFT descriptors (n, 128)."""

    z: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.z)


def _gray(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb


def _usable(mask: np.ndarray | None, shape: tuple[int, ...], margin: int = 4) -> np.ndarray:
    """8-bit detection mask: not in ``mask`` (pixels to ignore), nor within ``margin``."""
    keep = np.full(shape[:2], 255, np.uint8)
    if mask is not None:
        keep[mask] = 0
    return cv2.erode(keep, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))


class FeatureFinder:
    """SIFT keypoints matched across a rectified stereo pair."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.settings = settings
        self.sift = cv2.SIFT_create(nfeatures=settings.features,  # type: ignore[attr-defined]
                                    contrastThreshold=settings.contrast)
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)

    def stereo(self, left: np.ndarray, right: np.ndarray, ignore_left: np.ndarray | None = None,
               ignore_right: np.ndarray | None = None) -> StereoFeatures:
        """Keypoints of the left image (RGB or gray) found again in the right one, on the
        same row and at a positive disparity; ``ignore_*`` are boolean masks of pixels
        not to use (the robots' own bodies)."""
        s = self.settings
        kl, dl = self.sift.detectAndCompute(_gray(left), _usable(ignore_left, left.shape))
        kr, dr = self.sift.detectAndCompute(_gray(right), _usable(ignore_right, right.shape))
        empty = StereoFeatures(np.zeros((0, 3)), np.zeros((0, 128), np.float32))
        if dl is None or dr is None or len(kr) < 2:
            return empty
        pl = np.array([k.pt for k in kl])
        pr = np.array([k.pt for k in kr])
        z, desc = [], []
        for m in self.matcher.knnMatch(dl, dr, k=2):
            if len(m) < 2 or m[0].distance > s.ratio * m[1].distance:
                continue
            a, b = pl[m[0].queryIdx], pr[m[0].trainIdx]
            d = a[0] - b[0]
            if abs(a[1] - b[1]) <= s.row_px and d > 0.5:
                z.append((a[0], a[1], d))
                desc.append(dl[m[0].queryIdx])
        if not z:
            return empty
        return StereoFeatures(np.array(z), np.array(desc, np.float32))


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


def guided_matches(camera: StereoCamera, g01: np.ndarray, points: np.ndarray,
                   descriptors: np.ndarray, found: StereoFeatures, radius_px: float,
                   ratio: float) -> np.ndarray:
    """Pairs (feature, fiducial) (m, 2): the fiducial projecting within ``radius_px`` of
    the feature whose descriptor is closest, and clearly closer than the runner-up;
    one feature per fiducial (the closest in descriptor)."""
    if len(points) == 0 or len(found) == 0:
        return np.zeros((0, 2), int)
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
        dist = np.linalg.norm(descriptors[near] - found.descriptors[j], axis=1)
        order = np.argsort(dist)
        if dist[order[0]] > DESCRIPTOR_MAX:
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
        if len(pairs) >= s.min_seeding:  # a well-located frame: its new fiducials are sound
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

