"""Model-based edge fitting in a stereo pair: a rigid set of boxes (a CAD model) located
to a fraction of a pixel by the edges it makes in both images.

The model's visible edges are projected with the current pose; at points along them the
image is searched along the edge's normal for the strongest colour step nearest the
prediction (its place interpolated between pixels); the pose then moves to put the
projected edges on the found points, in both images at once, with Tukey's weights so
that edges hidden by something the model does not know of, or matched to texture, count
for nothing. Searching and fitting alternate, the search range narrowing from what the
starting pose's uncertainty needs to a few pixels ("moving edges", as model-based
visual-servoing trackers do it).

An edge is used where at least one of its two faces is turned toward the camera (a
silhouette or a crease) and nothing in the scene that is modelled hides it: the boxes of
every fitted model, grown by a pixel and a half so that points next to another model's
outline are not used either. Edges along the image rows carry no disparity; the ends,
corners and the edges across the rows constrain depth, and every edge is used.

Frames: OpenCV camera (+z forward, +x right, +y down), the left camera's; the right one
sits ``baseline_m`` along its +x. Poses map object to left-camera coordinates; a pose's
uncertainty is a 6x6 covariance of a small motion (translation, then rotation vector)
applied in the left camera's frame: ``T <- exp(xi) T``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

SAMPLE_SPACING_PX = 2.0  # one search per this many pixels of projected edge
END_MARGIN = 0.12  # no searches in this share of an edge at each end: corners mislead
# An edge is searched at most halfway to its nearest neighbour in the image (the other
# model's edges included), so that it never takes its neighbour's step for its own;
# excluding close edges altogether measured worse (bench/measurement.py: 0.8 m, 30 deg,
# lateral p95 0.44 mm searched this way, 1.12 mm without edges closer than 2 px)
# A face is seen when turned toward the camera by more than this (the cosine of its normal
# to the line of sight: 6 deg from edge-on); a face seen edge-on shows its far edges on
# top of its near ones (a rail's foot under its top, seen from straight above)
MIN_FACING = 0.1
MIN_END_EDGE_PX = 4.0  # an edge's ends are searched where it projects at least this long
GROW_PX = 1.5  # modelled occluders are grown by this: no searches next to their outline
MIN_STEP = 12.0  # a colour step weaker than this (RGB 0-255 per pixel of profile) is no edge
TUKEY_C = 4.685  # Tukey's constant for 95 % efficiency with Gaussian residuals
MIN_SCALE_PX = 0.25  # the residual scale is not taken below this (aliasing of the render)
FINE_RANGE_PX = 3  # the last iterations search this far either side
# the first moving-edge searches reach this far; a start uncertain beyond it is aligned
# first (a whole-model search: moving edges that far would take a neighbour's step)
COARSE_RANGE_PX = 6
MAX_REACH_PX = 20  # edges are aligned at most this far: beyond, texture outnumbers them
DEPTH_HYPOTHESES = 9  # distances tried by the region alignment, across +-3 sd
MAX_REGION_REACH_PX = 80  # a region at most this far (its object's colour does not alias)
MIN_INLIERS = 24  # a fit needs this many matched edge points (six unknowns, margin)
# and at least this share of the points its visible edges show where they may search a
# pixel or more (an edge crowded by its neighbours is searched too near to be missed)
MIN_EXPLAINED = 0.5
MIN_UNHIDDEN = 0.3  # and at least this share of its edges not hidden by the other models
MIN_COVER = 0.9  # and its silhouette this share of the object's pixels (its colour's hull)
HYPOTHESES = 4  # starts fitted from the alignment's best shifts
HYPOTHESIS_SHARE = 0.7  # ... those scoring at least this share of the best
COMPARE_SCALE_PX = 0.5  # residual scale at which fits from different starts are compared
# The fit's covariance counts every edge point as an independent measurement; neighbours
# along an edge are not (the render's aliasing and the lens's blur are shared), so its
# standard deviations are scaled by this: over 160 rendered views at 0.5-1.2 m and 0-50
# deg (bench/measurement.py, seed 0, 20 views a cell, in focus, unoccluded) the 95th
# percentile of the displacement's error in its own standard deviations was 6.55 where a
# true covariance gives 2.80 (the root of chi-square with 3 degrees of freedom)
FIT_SD_SCALE = 2.3
ITERATIONS = 12  # moving-edge iterations from each start (it settles in 4-6)
# which edges are seen is decided at these iterations (the start, and where the coarse
# searches have brought the pose); between, the same points are projected anew
RESAMPLE_AT = (0, 2)


@dataclass(frozen=True)
class Boxes:
    """A rigid model made of boxes: centres and half extents (n, 3) in its frame (m)."""

    centres: np.ndarray
    halves: np.ndarray


@dataclass(frozen=True)
class StereoRig:
    """A rectified stereo pair's intrinsics (px) and baseline (m)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float

    def project(self, points: np.ndarray, camera: int) -> np.ndarray:
        """Pixels (n, 2) of left-camera points (n, 3) in camera 0 (left) or 1 (right)."""
        x = points[:, 0] - camera * self.baseline_m
        return np.stack([self.fx * x / points[:, 2] + self.cx,
                         self.fy * points[:, 1] / points[:, 2] + self.cy], -1)


@dataclass(frozen=True)
class EdgeFit:
    """A fitted pose (object to left camera, 4x4), its covariance (6x6, see the module),
    the matched edge points, and the RMS of the inliers' residuals (px); ``why`` is set
    when the fit is not to be used."""

    pose: np.ndarray
    covariance: np.ndarray
    inliers: int
    rms_px: float
    centre: np.ndarray  # the point (object frame) the covariance's rotation turns about
    cost: float  # -log posterior (up to a constant): fits from different starts compare
    matched: list[np.ndarray] = field(default_factory=list)  # per camera, pixels (n, 2)
    why: str | None = None
    # what the edges alone say (6x6, the prior's information taken out)
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))

    def rotation_information(self) -> np.ndarray:
        """The edges' information (3x3, rad^-2, camera frame) about the rotation alone,
        the translation unknown (the Schur complement)."""
        H = self.information
        tt, tr, rr = H[:3, :3], H[:3, 3:], H[3:, 3:]
        return rr - tr.T @ np.linalg.pinv(tt) @ tr

    @property
    def ok(self) -> bool:
        return self.why is None


def box_edges(boxes: Boxes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every box's 12 edges: endpoints (m, 2, 3), the outward normals of the two faces
    that meet there (m, 2, 3), and the box each belongs to (m,)."""
    ends, normals, owner = [], [], []
    for i, (c, h) in enumerate(zip(boxes.centres, boxes.halves, strict=True)):
        for axis in range(3):
            a, b = [k for k in range(3) if k != axis]
            for sa in (-1.0, 1.0):
                for sb in (-1.0, 1.0):
                    p = c.copy()
                    p[a] += sa * h[a]
                    p[b] += sb * h[b]
                    lo, hi = p.copy(), p.copy()
                    lo[axis] -= h[axis]
                    hi[axis] += h[axis]
                    na, nb = np.zeros(3), np.zeros(3)
                    na[a], nb[b] = sa, sb
                    ends.append([lo, hi])
                    normals.append([na, nb])
                    owner.append(i)
    return np.array(ends), np.array(normals), np.array(owner)


def _hidden(eye: np.ndarray, points: np.ndarray, pose: np.ndarray, boxes: Boxes,
            grow: np.ndarray, skip: np.ndarray | None) -> np.ndarray:
    """Which segments eye -> point (left-camera frame) pass through one of ``boxes`` at
    ``pose`` grown by ``grow`` (per point, m), short of the point; ``skip[k]`` is a box
    index not tested for point k (its own)."""
    R, t = pose[:3, :3], pose[:3, 3]
    e = (eye - t) @ R
    local = (points - t) @ R
    d = local - e
    hidden = np.zeros(len(points), bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, (c, h) in enumerate(zip(boxes.centres, boxes.halves, strict=True)):
            half = h[None, :] + grow[:, None]
            a = (c - half - e) / d
            b = (c + half - e) / d
            near = np.nanmax(np.minimum(a, b), axis=1)
            far = np.nanmin(np.maximum(a, b), axis=1)
            hit = (near < far) & (far > 0) & (near < 1.0 - 1e-6)
            if skip is not None:
                hit &= skip != i
            hidden |= hit
    return hidden


@dataclass(frozen=True)
class _Samples:
    """Points on visible edges in one camera: object frame (n, 3), predicted pixels and
    unit image normals (n, 2)."""

    points: np.ndarray
    pixels: np.ndarray
    normals: np.ndarray
    reach: np.ndarray  # how far (px) each may search: halfway to its nearest other edge
    tangent: np.ndarray  # its edge's direction (object frame; at an end, outward)
    end: np.ndarray  # bool: searched along its edge (an end), not across it
    alone: int = 0  # how many there would be if the other models hid nothing

    def moved(self, pose: np.ndarray, rig: StereoRig, camera: int) -> _Samples:
        """The same points projected with ``pose`` (their pixels and normals anew)."""
        if len(self.points) == 0:
            return self
        R, t = pose[:3, :3], pose[:3, 3]
        pixels = rig.project(self.points @ R.T + t, camera)
        ahead = rig.project((self.points + 1e-3 * self.tangent) @ R.T + t, camera)
        direction = ahead - pixels
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        across = np.stack([-direction[:, 1], direction[:, 0]], -1)
        normals = np.where(self.end[:, None], direction, across)
        return dataclasses.replace(self, pixels=pixels, normals=normals)


def _facing_edges(pose: np.ndarray, boxes: Boxes, camera: int, rig: StereoRig
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The edges of ``boxes`` at ``pose`` with a face toward camera ``camera``: their
    endpoints in the object frame (m, 2, 3) and the box each belongs to."""
    ends, normals, owner = box_edges(boxes)
    R, t = pose[:3, :3], pose[:3, 3]
    eye = np.array([camera * rig.baseline_m, 0.0, 0.0])
    mid = (ends[:, 0] + ends[:, 1]) / 2 @ R.T + t
    sight = (eye - mid) / np.linalg.norm(eye - mid, axis=1, keepdims=True)
    facing = ((normals @ R.T) * sight[:, None, :]).sum(-1) > MIN_FACING  # (m, 2)
    keep = facing.any(axis=1)
    return ends[keep], owner[keep]


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (n, k) from 2-D points (n, 2) to segments a-b (k, 2)."""
    ab = b - a
    rel = points[:, None, :] - a[None, :, :]
    t = np.clip((rel * ab[None]).sum(-1) / np.maximum((ab ** 2).sum(-1), 1e-12)[None], 0, 1)
    return np.linalg.norm(rel - t[..., None] * ab[None], axis=-1)


def visible_samples(pose: np.ndarray, boxes: Boxes, rig: StereoRig, camera: int,
                    occluders: list[tuple[np.ndarray, Boxes]], margin_px: float
                    ) -> _Samples:
    """Points along the model's edges that camera ``camera`` sees at ``pose``, spaced
    SAMPLE_SPACING_PX apart, at least ``margin_px`` inside the image, each with how far
    it may search (halfway to the nearest other edge that faces the camera, this
    model's or an occluder's); ``occluders`` are other modelled objects (pose, boxes)
    that may hide them."""
    ends, owner = _facing_edges(pose, boxes, camera, rig)
    R, t = pose[:3, :3], pose[:3, 3]
    eye = np.array([camera * rig.baseline_m, 0.0, 0.0])
    a = ends[:, 0] @ R.T + t
    b = ends[:, 1] @ R.T + t
    if len(a) == 0 or (a[:, 2] <= 0).any() or (b[:, 2] <= 0).any():
        return _none()
    length_px = np.linalg.norm(rig.project(a, camera) - rig.project(b, camera), axis=1)
    counts = np.maximum(0, ((1 - 2 * END_MARGIN) * length_px / SAMPLE_SPACING_PX).astype(int))
    which = np.repeat(np.arange(len(a)), counts)
    if len(which) == 0:
        return _none()
    start = np.concatenate([np.arange(n) for n in counts])
    s = END_MARGIN + (1 - 2 * END_MARGIN) * (start + 0.5) / counts[which]
    local = ends[which, 0] + s[:, None] * (ends[which, 1] - ends[which, 0])
    world = local @ R.T + t
    pixels = rig.project(world, camera)
    direction = rig.project(b[which], camera) - rig.project(a[which], camera)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    image_normals = np.stack([-direction[:, 1], direction[:, 0]], -1)
    grow = GROW_PX * world[:, 2] / rig.fx
    hidden = _hidden(eye, world, pose, boxes, np.zeros(len(world)), owner[which])
    by_others = np.zeros(len(world), bool)
    for other_pose, other in occluders:
        by_others |= _hidden(eye, world, other_pose, other, grow, None)
    inside = ((pixels[:, 0] >= margin_px) & (pixels[:, 0] <= rig.width - 1 - margin_px)
              & (pixels[:, 1] >= margin_px) & (pixels[:, 1] <= rig.height - 1 - margin_px))
    near = _segment_distance(pixels, rig.project(a, camera), rig.project(b, camera))
    near[np.arange(len(which)), which] = np.inf  # its own edge
    room = near.min(axis=1)
    alone = int((inside & ~hidden).sum())
    hidden |= by_others
    for other_pose, other in occluders:
        o_ends, _ = _facing_edges(other_pose, other, camera, rig)
        oa = o_ends[:, 0] @ other_pose[:3, :3].T + other_pose[:3, 3]
        ob = o_ends[:, 1] @ other_pose[:3, :3].T + other_pose[:3, 3]
        if len(oa) and (oa[:, 2] > 0).all() and (ob[:, 2] > 0).all():
            room = np.minimum(room, _segment_distance(pixels, rig.project(oa, camera),
                                                      rig.project(ob, camera)).min(axis=1))
    use = inside & ~hidden
    tangent = ends[which, 1] - ends[which, 0]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    sides = _Samples(local[use], pixels[use], image_normals[use], room[use] / 2, tangent[use],
                     np.zeros(int(use.sum()), bool), alone)
    return _join(sides, _end_samples(ends, owner, pose, boxes, rig, camera, occluders,
                                     margin_px))


def _none() -> _Samples:
    return _Samples(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                    np.zeros((0, 3)), np.zeros(0, bool), 0)


def _join(a: _Samples, b: _Samples) -> _Samples:
    def both(name: str) -> np.ndarray:
        return np.concatenate([getattr(a, name), getattr(b, name)])

    return _Samples(both("points"), both("pixels"), both("normals"), both("reach"),
                    both("tangent"), both("end"), a.alone + b.alone)


def _end_samples(ends: np.ndarray, owner: np.ndarray, pose: np.ndarray, boxes: Boxes,
                 rig: StereoRig, camera: int, occluders: list[tuple[np.ndarray, Boxes]],
                 margin_px: float) -> _Samples:
    """Where the facing edges end: each visible end searched along its edge, so that a
    model whose edges all run one way (a thin panel seen from the side shows mostly its
    vertical edges) is still held along them; each searches at most halfway to the
    nearest edge that does not meet there."""
    R, t = pose[:3, :3], pose[:3, 3]
    eye = np.array([camera * rig.baseline_m, 0.0, 0.0])
    a2 = rig.project(ends[:, 0] @ R.T + t, camera)
    b2 = rig.project(ends[:, 1] @ R.T + t, camera)
    points = np.concatenate([ends[:, 0], ends[:, 1]])
    pixels = np.concatenate([a2, b2])
    out = np.concatenate([a2 - b2, b2 - a2])
    length = np.linalg.norm(out, axis=1)
    out /= np.maximum(length, 1e-9)[:, None]
    mine = np.concatenate([owner, owner])
    X = points @ R.T + t
    hidden = _hidden(eye, X, pose, boxes, np.zeros(len(X)), mine)
    grow = GROW_PX * X[:, 2] / rig.fx
    by_others = np.zeros(len(X), bool)
    for other_pose, other in occluders:
        by_others |= _hidden(eye, X, other_pose, other, grow, None)
    meets = (np.linalg.norm(points[:, None, None, :] - ends[None], axis=-1) < 1e-9).any(-1)
    near = np.where(meets, np.inf, _segment_distance(pixels, a2, b2))
    room = near.min(axis=1) if near.shape[1] else np.full(len(points), np.inf)
    inside = ((pixels[:, 0] >= margin_px) & (pixels[:, 0] <= rig.width - 1 - margin_px)
              & (pixels[:, 1] >= margin_px) & (pixels[:, 1] <= rig.height - 1 - margin_px))
    use = inside & ~hidden & (length >= MIN_END_EDGE_PX)
    alone = int(use.sum())
    use &= ~by_others
    outward = np.concatenate([ends[:, 0] - ends[:, 1], ends[:, 1] - ends[:, 0]])
    outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
    return _Samples(points[use], pixels[use], out[use], np.minimum(room[use], length[use]) / 2,
                    outward[use], np.ones(int(use.sum()), bool), alone)


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


def _twist(xi: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The rigid motion (4x4) that turns by the rotation vector ``xi[3:]`` about
    ``centre`` and then moves by ``xi[:3]``."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[3:]).as_matrix()
    T[:3, 3] = centre + xi[:3] - T[:3, :3] @ centre
    return T


def _rows(points: np.ndarray, normals: np.ndarray, rig: StereoRig, camera: int,
          centre: np.ndarray) -> np.ndarray:
    """d(n . pixel)/d(xi) for left-camera points (n, 3), the motion about ``centre``."""
    x = points[:, 0] - camera * rig.baseline_m
    y, z = points[:, 1], points[:, 2]
    du = np.stack([rig.fx / z, np.zeros_like(z), -rig.fx * x / z ** 2], -1)
    dv = np.stack([np.zeros_like(z), rig.fy / z, -rig.fy * y / z ** 2], -1)
    dn = normals[:, :1] * du + normals[:, 1:] * dv  # (n, 3): d(n.p)/dX
    # dX/dxi = [I, -[X - centre]x]
    return np.concatenate([dn, np.cross(points - centre, dn)], axis=1)


def _log(T: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The motion (translation, rotation vector) whose :func:`_twist` about ``centre``
    is ``T``."""
    return np.concatenate([T[:3, :3] @ centre + T[:3, 3] - centre,
                           Rotation.from_matrix(T[:3, :3]).as_rotvec()])


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


def align(frames: list[np.ndarray], samples: list[_Samples], reach_px: int
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


def silhouette(pose: np.ndarray, boxes: Boxes, rig: StereoRig, shape: tuple[int, int],
               camera: int = 0) -> np.ndarray:
    """The model's silhouette in camera ``camera``'s image (bool, ``shape``): its boxes'
    projected hulls."""
    out = np.zeros(shape, np.uint8)
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    for c, h in zip(boxes.centres, boxes.halves, strict=True):
        X = (c + signs * h) @ pose[:3, :3].T + pose[:3, 3]
        if (X[:, 2] <= 0).any():
            continue
        hull = cv2.convexHull(np.round(rig.project(X, camera)).astype(np.int32))
        cv2.fillConvexPoly(out, hull, 1)
    return out.astype(bool)


def _region_scores(mask: np.ndarray, pose: np.ndarray, boxes: Boxes, rig: StereoRig,
                   camera: int, reach_px: int) -> np.ndarray | None:
    """For every image shift within ``reach_px`` ((2 reach + 1)^2, rows then columns):
    silhouette pixels on ``mask`` minus those off it."""
    shape = silhouette(pose, boxes, rig, mask.shape, camera)
    ys, xs = np.nonzero(shape)
    if len(ys) == 0:
        return None
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    signed = np.pad(2 * mask.astype(np.float32) - 1, reach_px, constant_values=-1)
    area = signed[y0:y1 + 2 * reach_px, x0:x1 + 2 * reach_px]
    template = shape[y0:y1, x0:x1].astype(np.float32)
    if area.shape[0] < template.shape[0] or area.shape[1] < template.shape[1]:
        return None
    return cv2.matchTemplate(area, template, cv2.TM_CCORR)


def align_region(masks: tuple[np.ndarray, np.ndarray], pose: np.ndarray, boxes: Boxes,
                 rig: StereoRig, reach_px: int, depth_sd_m: float) -> np.ndarray:
    """The pose, moved from ``pose`` across the image (within ``reach_px``) and along the
    line of sight (within three ``depth_sd_m``), whose silhouettes best lay over
    ``masks``, the object's pixels in the left and right images (found by its colour):
    each silhouette pixel on a mask counts one, off it minus one. Regions do not alias
    as parallel edges and texture do, and the two images together tell the distance
    (by the disparity, where the region's size cannot: a thin panel seen end-on)."""
    centre = pose[:3, :3] @ boxes.centres.mean(axis=0) + pose[:3, 3]
    ray = centre / np.linalg.norm(centre)
    best, best_pose = -np.inf, pose
    for along in np.linspace(-3 * depth_sd_m, 3 * depth_sd_m, DEPTH_HYPOTHESES):
        moved = pose.copy()
        moved[:3, 3] += along * ray
        z = float((moved[:3, :3] @ boxes.centres.mean(axis=0) + moved[:3, 3])[2])
        if z <= 0.05:
            continue
        maps = [_region_scores(m, moved, boxes, rig, c, reach_px) for c, m in enumerate(masks)]
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


def fit_edges(images: tuple[np.ndarray, np.ndarray], boxes: Boxes, rig: StereoRig,
              start: np.ndarray, start_sd: tuple[float, float],
              occluders: list[tuple[np.ndarray, Boxes]] | None = None,
              masks: tuple[np.ndarray, np.ndarray] | None = None) -> EdgeFit:
    """Fit ``boxes``' pose (object to left camera) to the edges of the stereo pair
    ``images`` (RGB), from ``start``, uncertain by ``start_sd`` (m, rad per axis).

    Where the start's uncertainty projects beyond COARSE_RANGE_PX, the model's
    projection is first shifted across the images to where its edges meet colour steps
    (an exhaustive search within three standard deviations, at most MAX_REACH_PX; see
    :func:`align`); from each start edges are searched within COARSE_RANGE_PX (or the
    start's three standard deviations, if less), then FINE_RANGE_PX, and the pose
    fitted, the start's uncertainty holding the directions the edges leave
    unconstrained (a Gaussian prior: the covariance returned is the posterior's, of a
    motion about the model's centre, see :func:`point_covariance`). The fit that
    is the most probable is returned; ``why`` says if it is not to be used. With the
    object's pixels in both images (``masks``), its region aligns the start instead
    (:func:`align_region`), and that one start is fitted."""
    occluders = occluders or []
    frames = [np.asarray(im, np.float32) for im in images]
    middle = boxes.centres.mean(axis=0)
    prior = np.diag(np.concatenate([np.full(3, start_sd[0] ** -2),
                                    np.full(3, start_sd[1] ** -2)]))
    starts = [start]
    needed = search_reach_px(start, boxes, rig, *start_sd)
    reach = min(needed, MAX_REACH_PX)
    if needed > COARSE_RANGE_PX:
        z = float((start[:3, :3] @ middle + start[:3, 3])[2])
        if masks is not None:
            starts = [align_region(masks, start, boxes, rig, min(needed, MAX_REGION_REACH_PX),
                                   start_sd[0])]
        else:
            starts = []
            for shift in align(frames, [visible_samples(start, boxes, rig, c, occluders, 2)
                                        for c in (0, 1)], reach):
                moved = start.copy()
                moved[:3, 3] += [shift[0] * z / rig.fx, shift[1] * z / rig.fy, 0.0]
                starts.append(moved)
    first = min(reach, COARSE_RANGE_PX)
    fits = [_refine(frames, boxes, rig, s, start, prior, middle, occluders, first)
            for s in starts]
    if not fits:
        return EdgeFit(start, np.full((6, 6), np.inf), 0, np.inf, middle, np.inf, [],
                       "no edges of the model in view")
    if masks is not None:
        fits = [_covering(f, masks[0], boxes, rig) for f in fits]
    best = min(fits, key=lambda f: (not f.ok, f.cost))
    if needed <= COARSE_RANGE_PX:
        return best
    # A far start may settle turned where one edge hides (a panel tilted about its top
    # edge when its bottom is hidden): once more from where it settled, turned as at
    # the start, and the more probable of the two is kept.
    again = start.copy()
    again[:3, 3] = best.pose[:3, :3] @ middle + best.pose[:3, 3] - start[:3, :3] @ middle
    second = _refine(frames, boxes, rig, again, start, prior, middle, occluders, FINE_RANGE_PX)
    if masks is not None:
        second = _covering(second, masks[0], boxes, rig)
    return min((best, second), key=lambda f: (not f.ok, f.cost))


def _covering(fit: EdgeFit, mask: np.ndarray, boxes: Boxes, rig: StereoRig) -> EdgeFit:
    """The fit, told not to be used when its silhouette leaves more than 1 - MIN_COVER of
    the object's pixels (``mask``) uncovered: edges can agree with a wrong pose (another
    object's, the texture's) that the object's region shows up."""
    if not fit.ok:
        return fit
    shape = silhouette(fit.pose, boxes, rig, mask.shape)
    cover = float((shape & mask).sum() / max(int(mask.sum()), 1))
    if cover >= MIN_COVER:
        return fit
    return dataclasses.replace(fit, why=f"its silhouette covers {cover:.0%} of the object's "
                                        f"pixels (at least {MIN_COVER:.0%} needed)")


def _refine(frames: list[np.ndarray], boxes: Boxes, rig: StereoRig, pose: np.ndarray,
            start: np.ndarray, prior: np.ndarray, middle: np.ndarray,
            occluders: list[tuple[np.ndarray, Boxes]], first_reach: int) -> EdgeFit:
    """Moving edges from ``pose``: search within ``first_reach`` pixels, then within
    FINE_RANGE_PX, fit with Tukey's weights and the prior (information ``prior`` about
    ``start``), until the pose settles."""
    reach = max(first_reach, FINE_RANGE_PX)
    scale = reach / 2.0
    seen: list[_Samples] = []
    last: tuple[Any, ...] | None = None
    for it in range(ITERATIONS):
        centre = pose[:3, :3] @ middle + pose[:3, 3]
        rows, residuals, matched, roomy = [], [], [], []
        if it == 0 or (it in RESAMPLE_AT and first_reach > FINE_RANGE_PX):
            seen = [visible_samples(pose, boxes, rig, c, occluders, reach + 2) for c in (0, 1)]
        expected = searchable = 0
        for camera in (0, 1):
            samples = seen[camera].moved(pose, rig, camera)
            expected += len(samples.points)
            searchable += int((samples.reach >= 1).sum())
            found = search_edges(frames[camera], samples.pixels, samples.normals, reach,
                                 samples.reach) if len(samples.points) else np.zeros(0)
            ok = np.isfinite(found)
            X = samples.points[ok] @ pose[:3, :3].T + pose[:3, 3]
            rows.append(_rows(X, samples.normals[ok], rig, camera, centre))
            residuals.append(-found[ok])  # predicted minus found, along the normal
            matched.append(samples.pixels[ok] + found[ok, None] * samples.normals[ok])
            roomy.append(samples.reach[ok] >= 1)
        J, r = np.concatenate(rows), np.concatenate(residuals)
        if len(r) < MIN_INLIERS:
            return EdgeFit(pose, np.full((6, 6), np.inf), 0, np.inf, middle, np.inf, matched,
                           f"{len(r)} edge points found, {MIN_INLIERS} needed")
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        scale = max(min(scale, mad), MIN_SCALE_PX)
        u = r / (TUKEY_C * scale)
        w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0) / scale ** 2
        away = _log(pose @ np.linalg.inv(start), centre)  # from the start, for the prior
        H = J.T @ (w[:, None] * J) + prior
        xi = -np.linalg.solve(H, J.T @ (w * r) + prior @ away)
        pose = _twist(xi, centre) @ pose
        last = (H, r, w, matched, expected, away, searchable, np.concatenate(roomy))
        reach = max(FINE_RANGE_PX, reach - 1)
        if it >= 2 and np.linalg.norm(xi[:3]) < 1e-6 and np.linalg.norm(xi[3:]) < 1e-6:
            break
    assert last is not None
    H, r, w, matched, expected, away, searchable, free = last
    inliers = int((w > 0).sum())
    # Tukey's loss at a common scale, every edge point shown but not found an outlier,
    # and the prior: which start's fit is the most probable
    v = np.minimum(np.abs(r) / (TUKEY_C * COMPARE_SCALE_PX), 1.0)
    outlier = TUKEY_C ** 2 / 6
    cost = float(outlier * np.sum(1 - (1 - v ** 2) ** 3) + outlier * (expected - len(r))
                 + 0.5 * away @ prior @ away)
    rms = float(np.sqrt(np.sum(w * r ** 2) / max(w.sum(), 1e-12)))
    why = None
    unhidden = sum(sample.alone for sample in seen)
    if occluders and expected < MIN_UNHIDDEN * unhidden:
        why = (f"the other model hides {1 - expected / max(unhidden, 1):.0%} of its edges "
               f"(at most {1 - MIN_UNHIDDEN:.0%})")
    elif inliers < MIN_INLIERS:
        why = f"{inliers} edge points agree with the model, {MIN_INLIERS} needed"
    elif (explained := int(((w > 0) & free).sum())) < MIN_EXPLAINED * searchable:
        why = (f"{explained} of the {searchable} edge points the model shows apart from "
               f"its other edges agree with it (at least {MIN_EXPLAINED:.0%} needed)")
    scale = FIT_SD_SCALE ** 2
    return EdgeFit(pose, scale * np.linalg.inv(H), inliers, rms, middle, cost, matched, why,
                   (H - prior) / scale)


def point_covariance(fit: EdgeFit, point: np.ndarray) -> np.ndarray:
    """The 3x3 covariance (left-camera frame) of an object point carried by a fit."""
    pose = fit.pose
    X = pose[:3, :3] @ (point - fit.centre)
    skew = np.array([[0, -X[2], X[1]], [X[2], 0, -X[0]], [-X[1], X[0], 0]])
    A = np.hstack([np.eye(3), -skew])
    return A @ fit.covariance @ A.T
