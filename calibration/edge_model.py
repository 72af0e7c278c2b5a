"""Which edges of a box model a stereo camera sees, and where along them to search: the
model's edges whose faces turn toward the camera, sampled every few pixels, less those
that a modelled object (this model's other boxes, or another model) or what the stereo
pair saw in front of them (a beam, an arm: ``Seen``) hides, each allowed
to search halfway to its nearest neighbouring edge; and the edges' ends, searched along
the edges. Frames as in calibration/edge_fit.py (OpenCV, the left camera's)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from taskcam.mapping.camera import Pinhole

SAMPLE_SPACING_PX = 2.0  # one search per this many pixels of projected edge
END_MARGIN = 0.12  # no searches in this share of an edge at each end: corners mislead

# An edge is searched at most halfway to its nearest neighbour in the image (the other
# model's edges included), so that it never takes its neighbour's step for its own;
# excluding close edges altogether measured worse (bench/studies/measurement.py: 0.8 m, 30 deg,
# lateral p95 0.44 mm searched this way, 1.12 mm without edges closer than 2 px).

# A face is seen when turned toward the camera by more than MIN_FACING (the cosine of its
# normal to the line of sight: 6 deg from edge-on), or, nearer edge-on, where its far edge
# still projects MIN_FACE_PX or more from its near one: a 150 mm face turned 5 deg to the
# camera shows 13 mm, 7 px at 0.8 m, and its far edge is the object's outline there. A
# face seen edge-on and narrower shows its far edges on top of its near ones (a rail's
# foot under its top, seen from straight above). Measured (docs/measurement.md): by the
# width alone, 1 px, the faces narrower than a pixel but turned to the camera went
# unsearched, and the default scenario's camera 60 deg off the slot's normal lost most.
MIN_FACING = 0.1
MIN_FACE_PX = 1.0
MIN_END_EDGE_PX = 4.0  # an edge's ends are searched where it projects at least this long
GROW_PX = 1.5  # modelled occluders are grown by this: no searches next to their outline
# What is not modelled hides a model's point where the pair saw something nearer there:
# the left image's disparity at the point's pixel exceeds the point's own by more than
# this (px): 7.5 cm nearer at 1.1 m, 4 cm at 0.8 m. SGBM averages over its block, at
# half resolution (sim/stages/task_images.py) 10 px: over the half of it beside an edge,
# the model's own face turned 70 deg from the camera changes its disparity by
# 5 b tan(70 deg) / z px, 2.3 px at 0.7 m, and must not hide the model's edge.
NEARER_PX = 3.0
# SGBM matches nothing over about its block's half-width (2 px) and its left-right
# check's pixel on either side of a depth edge: an unmatched pixel takes the largest
# disparity matched within this many pixels (the nearest surface beside it), so that
# a model's point next to a nearer surface's outline is taken as hidden, as one next
# to a modelled occluder's is (GROW_PX).
FILL_PX = 3


@dataclass(frozen=True)
class Boxes:
    """A rigid model made of boxes: centres and half extents (n, 3) in its frame (m)."""

    centres: np.ndarray
    halves: np.ndarray


@dataclass(frozen=True)
class Seen:
    """What the stereo pair saw: the left image's disparity (px, NaN where unmatched),
    with which whatever no model holds (a beam, an arm) hides the points behind it."""

    disparity: np.ndarray

    @classmethod
    def of(cls, disparity: np.ndarray) -> Seen:
        """From SGBM's disparity (px, NaN where unmatched): its unmatched pixels filled
        with the largest disparity matched within FILL_PX of them, if any."""
        d = np.asarray(disparity, np.float32)
        side = 2 * FILL_PX + 1
        nearest = cv2.dilate(np.where(np.isfinite(d), d, -1.0), np.ones((side, side), np.uint8))
        filled = np.where(np.isfinite(d), d, nearest)
        return cls(np.where(filled >= 0, filled, np.nan))

    def hides(self, points: np.ndarray, rig: StereoRig, depth_sd_m: float = 0.0) -> np.ndarray:
        """Which left-camera points (n, 3, m) something seen nearer hides: the disparity at
        their left pixel exceeds theirs by NEARER_PX and what their own depth's
        uncertainty (``depth_sd_m``, 3 sd) allows."""
        h, w = self.disparity.shape
        u, v = np.rint(rig.project(points, 0)).astype(int).T
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (points[:, 2] > 0)
        seen = np.full(len(points), np.nan)
        seen[inside] = self.disparity[v[inside], u[inside]]
        z = np.maximum(points[:, 2], 1e-6)
        own = rig.fx * rig.baseline_m / z
        slack = NEARER_PX + 3 * depth_sd_m * own / z
        with np.errstate(invalid="ignore"):
            return np.isfinite(seen) & (seen > own + slack)


@dataclass(frozen=True)
class StereoRig(Pinhole):
    """A rectified stereo pair: the cameras' intrinsics (px), their baseline (m) and
    their lenses' blur (Gaussian sd, px: at most what the depth of field accepts)."""

    baseline_m: float = 0.0
    blur_sd_px: float = 0.0

    def project(self, points: np.ndarray, camera: int = 0) -> np.ndarray:
        """Pixels (n, 2) of left-camera points (n, 3) in camera 0 (left) or 1 (right)."""
        return super().project(points - [camera * self.baseline_m, 0.0, 0.0])


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
class Samples:
    """Points on visible edges in one camera: object frame (n, 3), predicted pixels and
    unit image normals (n, 2)."""

    points: np.ndarray
    pixels: np.ndarray
    normals: np.ndarray
    reach: np.ndarray  # how far (px) each may search: halfway to its nearest other edge
    tangent: np.ndarray  # its edge's direction (object frame; at an end, outward)
    end: np.ndarray  # bool: searched along its edge (an end), not across it
    edge: np.ndarray  # which edge (or end) each lies on: points of one share its bias
    # how far (px) the nearest other step lies across it: an edge nearly parallel to it
    # (an end: any edge not meeting there); within a few blur widths the two merge
    apart: np.ndarray
    alone: int = 0  # how many there would be if the other models hid nothing

    def moved(self, pose: np.ndarray, rig: StereoRig, camera: int) -> Samples:
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
    """The edges of ``boxes`` at ``pose`` with a face camera ``camera`` sees (turned toward
    it beyond MIN_FACING, or showing MIN_FACE_PX across): their endpoints in the object
    frame (m, 2, 3) and the box each belongs to."""
    ends, normals, owner = box_edges(boxes)
    R, t = pose[:3, :3], pose[:3, 3]
    eye = np.array([camera * rig.baseline_m, 0.0, 0.0])
    mid = (ends[:, 0] + ends[:, 1]) / 2 @ R.T + t
    distance = np.linalg.norm(eye - mid, axis=1)
    sight = (eye - mid) / distance[:, None]
    turned = ((normals @ R.T) * sight[:, None, :]).sum(-1)  # (m, 2): cos, normal to sight
    along = np.abs(((ends[:, 1] - ends[:, 0]) @ R.T * sight).sum(-1)) / np.linalg.norm(
        ends[:, 1] - ends[:, 0], axis=1)
    # each face's width across the edge (m): the box's extent along the other face's normal
    extent = 2 * np.abs(normals[:, ::-1] * boxes.halves[owner][:, None, :]).sum(-1)
    # the far edge's distance from the near one in the image (px): the width times the cos,
    # over the sine of the edge's own angle to the line of sight
    shown = rig.fx * extent * turned / np.sqrt(np.maximum(1 - along ** 2, 1e-12))[:, None]
    wide = (turned > 0) & (shown / distance[:, None] >= MIN_FACE_PX)
    keep = ((turned > MIN_FACING) | wide).any(axis=1)
    return ends[keep], owner[keep]


PARALLEL_COS = np.cos(np.radians(30.0))  # edges this near parallel merge when close


def _parallel(directions: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Which segments a-b (k, 2) run within 30 deg of parallel to each of ``directions``
    (n, 2, unit): (n, k) bool."""
    ab = b - a
    cos = np.abs(directions @ ab.T) / np.maximum(np.linalg.norm(ab, axis=1), 1e-12)[None]
    return cos >= PARALLEL_COS


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (n, k) from 2-D points (n, 2) to segments a-b (k, 2)."""
    ab = b - a
    rel = points[:, None, :] - a[None, :, :]
    t = np.clip((rel * ab[None]).sum(-1) / np.maximum((ab ** 2).sum(-1), 1e-12)[None], 0, 1)
    return np.linalg.norm(rel - t[..., None] * ab[None], axis=-1)


def visible_samples(pose: np.ndarray, boxes: Boxes, rig: StereoRig, camera: int,
                    occluders: list[tuple[np.ndarray, Boxes]], margin_px: float,
                    seen: Seen | None = None, depth_sd_m: float = 0.0) -> Samples:
    """Points along the model's edges that camera ``camera`` sees at ``pose``, spaced
    SAMPLE_SPACING_PX apart, at least ``margin_px`` inside the image, each with how far
    it may search (halfway to the nearest other edge that faces the camera, this
    model's or an occluder's); ``occluders`` are other modelled objects (pose, boxes)
    that may hide them, ``seen`` what the pair saw in front of them (the pose's depth
    uncertain by ``depth_sd_m``)."""
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
    by_others = _hidden_by_others(eye, world, occluders, grow, rig, seen, depth_sd_m)
    inside = ((pixels[:, 0] >= margin_px) & (pixels[:, 0] <= rig.width - 1 - margin_px)
              & (pixels[:, 1] >= margin_px) & (pixels[:, 1] <= rig.height - 1 - margin_px))
    a2, b2 = rig.project(a, camera), rig.project(b, camera)
    near = _segment_distance(pixels, a2, b2)
    near[np.arange(len(which)), which] = np.inf  # its own edge
    room = near.min(axis=1)
    apart = np.where(_parallel(direction, a2, b2), near, np.inf).min(axis=1)
    alone = int((inside & ~hidden).sum())
    hidden |= by_others
    for other_pose, other in occluders:
        o_ends, _ = _facing_edges(other_pose, other, camera, rig)
        oa = o_ends[:, 0] @ other_pose[:3, :3].T + other_pose[:3, 3]
        ob = o_ends[:, 1] @ other_pose[:3, :3].T + other_pose[:3, 3]
        if len(oa) and (oa[:, 2] > 0).all() and (ob[:, 2] > 0).all():
            oa2, ob2 = rig.project(oa, camera), rig.project(ob, camera)
            other_near = _segment_distance(pixels, oa2, ob2)
            room = np.minimum(room, other_near.min(axis=1))
            apart = np.minimum(apart, np.where(_parallel(direction, oa2, ob2), other_near,
                                               np.inf).min(axis=1))
    use = inside & ~hidden
    tangent = ends[which, 1] - ends[which, 0]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    sides = Samples(local[use], pixels[use], image_normals[use], room[use] / 2, tangent[use],
                     np.zeros(int(use.sum()), bool), which[use], apart[use], alone)
    return _join(sides, _end_samples(ends, owner, pose, boxes, rig, camera, occluders,
                                     margin_px, seen, depth_sd_m))


def _hidden_by_others(eye: np.ndarray, points: np.ndarray,
                      occluders: list[tuple[np.ndarray, Boxes]], grow: np.ndarray,
                      rig: StereoRig, seen: Seen | None, depth_sd_m: float) -> np.ndarray:
    """Which left-camera points the ``occluders`` (grown by ``grow``, m per point) or
    what the pair saw in front of them (``seen``) hide from ``eye``."""
    hidden = np.zeros(len(points), bool)
    for other_pose, other in occluders:
        hidden |= _hidden(eye, points, other_pose, other, grow, None)
    if seen is not None:
        hidden |= seen.hides(points, rig, depth_sd_m)
    return hidden


def _none() -> Samples:
    return Samples(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                    np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0, int), np.zeros(0), 0)


def _join(a: Samples, b: Samples) -> Samples:
    def both(name: str) -> np.ndarray:
        return np.concatenate([getattr(a, name), getattr(b, name)])

    return Samples(both("points"), both("pixels"), both("normals"), both("reach"),
                    both("tangent"), both("end"), both("edge"), both("apart"),
                    a.alone + b.alone)


def _end_samples(ends: np.ndarray, owner: np.ndarray, pose: np.ndarray, boxes: Boxes,
                 rig: StereoRig, camera: int, occluders: list[tuple[np.ndarray, Boxes]],
                 margin_px: float, seen: Seen | None = None, depth_sd_m: float = 0.0
                 ) -> Samples:
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
    by_others = _hidden_by_others(eye, X, occluders, grow, rig, seen, depth_sd_m)
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
    # each end is its own edge, numbered after the edges (one per end of each)
    return Samples(points[use], pixels[use], out[use], np.minimum(room[use], length[use]) / 2,
                    outward[use], np.ones(int(use.sum()), bool),
                    len(ends) + np.flatnonzero(use), room[use], alone)
