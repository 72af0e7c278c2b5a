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

An edge is used where the camera sees at least one of its two faces (turned toward it,
or nearly edge-on but a pixel or more wide in the image: a silhouette or a crease) and
nothing in the scene that is modelled hides it: the boxes of every fitted model, grown by
a pixel and a half so that points next to another model's outline are not used either.
Edges along the image rows carry no disparity; the ends, corners and the edges across
the rows constrain depth, and every edge is used.

The fit's covariance counts the edge points' errors as they are: each point's own noise,
and a bias that all points of one edge in one image share (aliasing and blur along it),
both measured from the fit's own residuals (see ``edge_covariance``); points along one edge
are therefore not independent measurements, and a direction held by a few edges is as
uncertain as those edges are.

Frames: OpenCV camera (+z forward, +x right, +y down), the left camera's; the right one
sits ``baseline_m`` along its +x. Poses map object to left-camera coordinates; a pose's
uncertainty is a 6x6 covariance of a small motion (translation, then rotation vector)
applied in the left camera's frame: ``T <- exp(xi) T``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .edge_model import Boxes, Samples, Seen, StereoRig, visible_samples
from .edge_search import (
    MAX_REACH_PX,
    MAX_REGION_REACH_PX,
    align,
    align_region,
    merge_bias_px,
    search_edges,
    search_reach_px,
    silhouette,
)

TUKEY_C = 4.685  # Tukey's constant for 95 % efficiency with Gaussian residuals
MIN_SCALE_PX = 0.25  # the residual scale is not taken below this (aliasing of the render)
FINE_RANGE_PX = 3  # the last iterations search this far either side
# the first moving-edge searches reach this far; a start uncertain beyond it is aligned
# first (a whole-model search: moving edges that far would take a neighbour's step)
COARSE_RANGE_PX = 6
MIN_INLIERS = 24  # a fit needs this many matched edge points (six unknowns, margin)
# and at least this share of the points its visible edges show where they may search a
# pixel or more (an edge crowded by its neighbours is searched too near to be missed)
MIN_EXPLAINED = 0.5
MIN_UNHIDDEN = 0.3  # and at least this share of its edges not hidden by the other models
MIN_COVER = 0.9  # and its silhouette this share of the object's pixels (its colour's hull)
COMPARE_SCALE_PX = 0.5  # residual scale at which fits from different starts are compared
ITERATIONS = 12  # moving-edge iterations from each start (it settles in 4-6)
# which edges are seen is decided at these iterations (the start, and where the coarse
# searches have brought the pose); between, the same points are projected anew
RESAMPLE_AT = (0, 2)


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
    # dX/dxi = [I, -[X - centre]x]: the lever arm crossed with dn (as np.cross, written
    # out: a third of its time on the few hundred rows of a fit)
    a = points - centre
    return np.column_stack([dn, a[:, 1] * dn[:, 2] - a[:, 2] * dn[:, 1],
                            a[:, 2] * dn[:, 0] - a[:, 0] * dn[:, 2],
                            a[:, 0] * dn[:, 1] - a[:, 1] * dn[:, 0]])


def _log(T: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The motion (translation, rotation vector) whose :func:`_twist` about ``centre``
    is ``T``."""
    return np.concatenate([T[:3, :3] @ centre + T[:3, 3] - centre,
                           Rotation.from_matrix(T[:3, :3]).as_rotvec()])


# How uncertain a start is: (m, rad) per axis, or the 6x6 covariance of its motion (see
# the module), when some directions are known better than others
Uncertainty = tuple[float, float] | np.ndarray


def prior_information(start_sd: Uncertainty) -> tuple[np.ndarray, float, float]:
    """A start's uncertainty as the prior's information (6x6) and its largest standard
    deviations in position (m) and rotation (rad)."""
    if isinstance(start_sd, tuple):
        sd_m, sd_rad = start_sd
        return (np.diag(np.concatenate([np.full(3, sd_m ** -2), np.full(3, sd_rad ** -2)])),
                sd_m, sd_rad)
    largest = [float(np.sqrt(np.linalg.eigvalsh(start_sd[k:k + 3, k:k + 3]).max()))
               for k in (0, 3)]
    return np.linalg.inv(start_sd), largest[0], largest[1]


def moved_chi2(fit: EdgeFit, start: np.ndarray, start_sd: Uncertainty) -> float:
    """How far ``fit`` moved from its ``start`` in the start's own uncertainty: the
    motion's squared Mahalanobis length (chi-square with 6 degrees of freedom where the
    start's uncertainty holds and the fit found the same thing)."""
    prior, _, _ = prior_information(start_sd)
    centre = fit.pose[:3, :3] @ fit.centre + fit.pose[:3, 3]
    away = _log(fit.pose @ np.linalg.inv(start), centre)
    return float(away @ prior @ away)


def fit_edges(images: tuple[np.ndarray, np.ndarray], boxes: Boxes, rig: StereoRig,
              start: np.ndarray, start_sd: Uncertainty,
              occluders: list[tuple[np.ndarray, Boxes]] | None = None,
              masks: tuple[np.ndarray, np.ndarray] | None = None,
              seen: Seen | None = None) -> EdgeFit:
    """Fit ``boxes``' pose (object to left camera) to the edges of the stereo pair
    ``images`` (RGB), from ``start``, uncertain by ``start_sd`` (m, rad per axis, or a
    covariance: see ``Uncertainty``).

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
    (:func:`align_region`), and that one start is fitted. ``seen``, the pair's
    disparity, hides the edges that something nearer than the model covers."""
    occluders = occluders or []
    frames = [np.asarray(im, np.float32) for im in images]
    middle = boxes.centres.mean(axis=0)
    prior, sd_m, sd_rad = prior_information(start_sd)
    starts = [start]
    needed = search_reach_px(start, boxes, rig, sd_m, sd_rad)
    reach = min(needed, MAX_REACH_PX)
    if needed > COARSE_RANGE_PX:
        z = float((start[:3, :3] @ middle + start[:3, 3])[2])
        if masks is not None:
            starts = [align_region(masks, start, boxes, rig, min(needed, MAX_REGION_REACH_PX),
                                   sd_m, seen)]
        else:
            starts = []
            for shift in align(frames, [visible_samples(start, boxes, rig, c, occluders, 2,
                                                        seen, sd_m) for c in (0, 1)], reach):
                moved = start.copy()
                moved[:3, 3] += [shift[0] * z / rig.fx, shift[1] * z / rig.fy, 0.0]
                starts.append(moved)
    first = min(reach, COARSE_RANGE_PX)
    fits = [_refine(frames, boxes, rig, s, start, prior, middle, occluders, first, seen, sd_m)
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
    second = _refine(frames, boxes, rig, again, start, prior, middle, occluders, FINE_RANGE_PX,
                     seen, sd_m)
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
            occluders: list[tuple[np.ndarray, Boxes]], first_reach: int,
            seen: Seen | None = None, depth_sd_m: float = 0.0) -> EdgeFit:
    """Moving edges from ``pose``: search within ``first_reach`` pixels, then within
    FINE_RANGE_PX, fit with Tukey's weights and the prior (information ``prior`` about
    ``start``, whose depth is uncertain by ``depth_sd_m``), until the pose settles;
    ``seen`` hides what something nearer covers."""
    reach = max(first_reach, FINE_RANGE_PX)
    scale = reach / 2.0
    shown: list[Samples] = []
    last: tuple[Any, ...] | None = None
    from_start = np.linalg.inv(start)
    for it in range(ITERATIONS):
        centre = pose[:3, :3] @ middle + pose[:3, 3]
        rows, residuals, matched, roomy, groups, merged = [], [], [], [], [], []
        if it == 0 or (it in RESAMPLE_AT and first_reach > FINE_RANGE_PX):
            shown = [visible_samples(pose, boxes, rig, c, occluders, reach + 2, seen,
                                     depth_sd_m) for c in (0, 1)]
        expected = searchable = 0
        for camera in (0, 1):
            samples = shown[camera].moved(pose, rig, camera)
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
            groups.append(2 * samples.edge[ok] + camera)  # an edge in one image
            merged.append(merge_bias_px(samples.apart[ok], rig.blur_sd_px))
        J, r = np.concatenate(rows), np.concatenate(residuals)
        if len(r) < MIN_INLIERS:
            return EdgeFit(pose, np.full((6, 6), np.inf), 0, np.inf, middle, np.inf, matched,
                           f"{len(r)} edge points found, {MIN_INLIERS} needed")
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        scale = max(min(scale, max(mad, scale / 2)), MIN_SCALE_PX)
        u = r / (TUKEY_C * scale)
        w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0) / scale ** 2
        away = _log(pose @ from_start, centre)  # from the start, for the prior
        H = J.T @ (w[:, None] * J) + prior
        xi = -np.linalg.solve(H, J.T @ (w * r) + prior @ away)
        pose = _twist(xi, centre) @ pose
        last = (H, J, r, w, scale, np.concatenate(groups), matched, expected, away, searchable,
                np.concatenate(roomy), np.concatenate(merged))
        reach = max(FINE_RANGE_PX, reach - 1)
        if it >= 2 and np.linalg.norm(xi[:3]) < 1e-6 and np.linalg.norm(xi[3:]) < 1e-6:
            break
    assert last is not None
    H, J, r, w, scale, edge_of, matched, expected, away, searchable, free, merge = last
    inliers = int((w > 0).sum())
    # Tukey's loss at a common scale, every edge point shown but not found an outlier,
    # and the prior: which start's fit is the most probable
    v = np.minimum(np.abs(r) / (TUKEY_C * COMPARE_SCALE_PX), 1.0)
    outlier = TUKEY_C ** 2 / 6
    cost = float(outlier * np.sum(1 - (1 - v ** 2) ** 3) + outlier * (expected - len(r))
                 + 0.5 * away @ prior @ away)
    rms = float(np.sqrt(np.sum(w * r ** 2) / max(w.sum(), 1e-12)))
    why = None
    unhidden = sum(sample.alone for sample in shown)
    if (occluders or seen is not None) and expected < MIN_UNHIDDEN * unhidden:
        what = "the other model" if seen is None else "what is in front"
        why = (f"{what} hides {1 - expected / max(unhidden, 1):.0%} of its edges "
               f"(at most {1 - MIN_UNHIDDEN:.0%})")
    elif inliers < MIN_INLIERS:
        why = f"{inliers} edge points agree with the model, {MIN_INLIERS} needed"
    elif (explained := int(((w > 0) & free).sum())) < MIN_EXPLAINED * searchable:
        why = (f"{explained} of the {searchable} edge points the model shows apart from "
               f"its other edges agree with it (at least {MIN_EXPLAINED:.0%} needed)")
    covariance, information = edge_covariance(J, r, w, scale, edge_of, merge, prior)
    return EdgeFit(pose, covariance, inliers, rms, middle, cost, matched, why, information)


def edge_covariance(J: np.ndarray, r: np.ndarray, w: np.ndarray, scale: float,
                edge_of: np.ndarray, merge: np.ndarray, prior: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """The fit's covariance (6x6) and what its edges alone say (their information), with
    the edge points' errors as they are: each point's own noise, and a bias its whole
    edge shares (the render's aliasing and the lens's blur along it, an edge's shading),
    which more points along that edge do not average away. Both are measured from the
    fit's own inliers: the noise from the residuals' scatter about their edge's mean,
    the bias from the edges' means beyond what that noise explains (the pose has taken
    up six of the edges' degrees of freedom). An edge that lies within a few blur widths
    of another step (``merge``: each point's RMS shift from that, px, see
    :func:`merge_bias_px`) is biased by its neighbour in a way its residuals do not show
    (the fit follows the merged step): that bias adds to its edge's, and is not counted
    again in the shared one. The covariance is then the least-squares one for those
    errors (the sandwich H^-1 J^T W S W J H^-1, the prior as one more measurement);
    ``w`` are the fit's weights (Tukey's, over ``scale`` squared), ``edge_of`` each
    point's edge."""
    tukey = w * scale ** 2
    inlier = tukey > 0
    Ji, ri, wi, ti, mi = J[inlier], r[inlier], w[inlier], tukey[inlier], merge[inlier]
    _, edge = np.unique(edge_of[inlier], return_inverse=True)
    count = np.bincount(edge, weights=ti)
    mean = np.bincount(edge, weights=ti * ri) / count
    merged = np.bincount(edge, weights=ti * mi ** 2) / count  # each edge's, px^2
    scatter_dof = float(ti.sum()) - len(count)
    noise = (float(np.sum(ti * (ri - mean[edge]) ** 2)) / scatter_dof if scatter_dof > 0
             else float(np.sum(ti * ri ** 2) / ti.sum()))
    sides = count >= 2  # an end is one point: its bias and its noise are one
    bias = max(0.0, float(np.sum((mean ** 2 - noise / count - merged)[sides]))
               / max(int(sides.sum()) - 6, 1))
    pulls = np.zeros((len(count), 6))
    np.add.at(pulls, edge, wi[:, None] * Ji)  # what each edge's shared error does
    spread = (noise * Ji.T @ ((wi ** 2)[:, None] * Ji)
              + pulls.T @ ((bias + merged)[:, None] * pulls))
    edges = Ji.T @ (wi[:, None] * Ji)
    inverse = np.linalg.inv(edges + prior)
    return inverse @ (spread + prior) @ inverse, edges @ np.linalg.pinv(spread) @ edges


def point_covariance(fit: EdgeFit, point: np.ndarray) -> np.ndarray:
    """The 3x3 covariance (left-camera frame) of an object point carried by a fit."""
    pose = fit.pose
    X = pose[:3, :3] @ (point - fit.centre)
    skew = np.array([[0, -X[2], X[1]], [X[2], 0, -X[0]], [-X[1], X[0], 0]])
    A = np.hstack([np.eye(3), -skew])
    return A @ fit.covariance @ A.T
