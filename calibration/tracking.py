"""Natural fiducials tracked through a move, and the camera's path from them (sec. 2.4).

A move is seen as a sequence of stereo frames. In each, SIFT keypoints of the left
image (blobs and corners of the surface texture and of object edges: natural fiducials)
are matched to the right image along their row (the head's pair is rectified), which
gives each a disparity: a measurement z = (u, v, d) (calibration/stereo_features.py).

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
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .bundle import BundleResult, Keyframe, refine, triangulate
from .ekf import StereoCamera
from .pose import DegenerateGeometryError, invert, rotation_deg, sqpnp
from .stereo_features import DESCRIPTOR_MAX, StereoFeatures, descriptor_distances
from .tracker_settings import TrackerSettings


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
