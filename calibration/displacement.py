"""The task's target, the displacement from the object to its goal (sec. 3), measured
relatively: the object's CAD model and the goal's (the slot's walls) are fitted to the
edges of the same stereo pair (calibration/edge_fit.py), and the object minus the goal is
taken in that camera's frame. An error of the camera's pose turns the displacement but
does not shift it, so it cancels to first order as the displacement shrinks; an error of
the work-piece's place does not enter at all.

Each camera's displacement carries a covariance from its two fits; cameras are fused by
inverse covariance in the world frame (where their believed poses put them); the task
stops when the fused displacement is confidently within its tightest tolerance.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi_square
from scipy.stats import ncx2

from .edge_fit import EdgeFit, Uncertainty, fit_edges, moved_chi2, point_covariance
from .edge_model import Boxes, Seen, StereoRig

# Cameras disagree beyond chance, or one disagrees with the prediction, when their
# chi-square exceeds its 99.9th percentile: once in a thousand measurements by chance
CHANCE = 0.999
# A goal's fit that moved further from its start than its start's uncertainty allows
# but once in a thousand times (6 degrees of freedom) fitted something else: a hood's
# slit 5 cm over the slot passed for its walls
GOAL_MOVED_CHI2 = float(chi_square.ppf(CHANCE, 6))
# The object's start, once the goal is fitted, is searched again from its first fit with
# this uncertainty (m, rad): a first fit is this good where it is good at all
REFIT_SD = (0.002, math.radians(0.3))
# ... but only if the goal's fit moved it more than this (px) from where it was taken to
# hide the object: a third of the edge fit's residual
REFIT_MOVED_PX = 0.1


@dataclass(frozen=True)
class Relative:
    """One camera's relative measurement. ``displacement`` is the object's point minus the
    goal's point in the left camera's OpenCV frame (m) with its covariance (3x3, m^2);
    the fitted poses (object to camera) are kept for the next step's start; ``why`` says
    why there is no measurement."""

    displacement: np.ndarray | None
    covariance: np.ndarray | None
    object_fit: EdgeFit | None = None
    goal_fit: EdgeFit | None = None
    why: str | None = None


def measure_relative(images: tuple[np.ndarray, np.ndarray], rig: StereoRig,
                     object_boxes: Boxes, object_start: np.ndarray,
                     object_sd: tuple[float, float], goal_boxes: Boxes,
                     goal_start: np.ndarray, goal_sd: Uncertainty,
                     object_masks: tuple[np.ndarray, np.ndarray] | None = None,
                     seen: Seen | None = None) -> Relative:
    """Fit the object and the goal in one stereo pair (RGB) and return the displacement
    of the object's frame origin from the goal's (both models' frames put their point of
    interest at the origin). Starts are poses to the left camera (OpenCV), with their
    uncertainty (m, rad per axis; the goal's may be a covariance, ``Uncertainty``);
    ``object_masks`` (the object's pixels in the left and right images, by its colour)
    align a far start. Each model hides the other: the object is
    fitted with the goal at its start, the goal with the object as fitted, the object
    again with the goal as fitted; what the pair saw in front of both (``seen``, its
    disparity) hides them too."""
    first = fit_edges(images, object_boxes, rig, object_start, object_sd,
                      [(goal_start, goal_boxes)], masks=object_masks, seen=seen)
    if not first.ok:
        return Relative(None, None, first, None, f"object: {first.why}")
    goal = fit_edges(images, goal_boxes, rig, goal_start, goal_sd,
                     [(first.pose, object_boxes)], seen=seen)
    if not goal.ok:
        return Relative(None, None, first, goal, f"goal: {goal.why}")
    away_m = float(np.linalg.norm(goal.pose[:3, 3] - goal_start[:3, 3]))
    moved = moved_chi2(goal, goal_start, goal_sd)
    if moved > GOAL_MOVED_CHI2:  # the goal stands still: other edges were taken for it
        return Relative(None, None, first, goal,
                        f"goal: fitted {1000 * away_m:.0f} mm from where it was believed, "
                        f"beyond that belief's uncertainty (chi-square {moved:.0f} > "
                        f"{GOAL_MOVED_CHI2:.1f}): other edges taken for it")
    obj = first
    moved_px = rig.fx * away_m / float(goal.pose[2, 3])
    if moved_px > REFIT_MOVED_PX:  # the goal was not where it hid the object from
        again = fit_edges(images, object_boxes, rig, first.pose, REFIT_SD,
                          [(goal.pose, goal_boxes)], seen=seen)
        obj = again if again.ok and again.cost <= first.cost else first
    origin = np.zeros(3)
    displacement = obj.pose[:3, 3] - goal.pose[:3, 3]
    covariance = point_covariance(obj, origin) + point_covariance(goal, origin)
    return Relative(displacement, covariance, obj, goal)


def via_feature(object_fit: EdgeFit, goal: np.ndarray, goal_covariance: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """The displacement of the object's origin from a goal its camera cannot fit, where a
    feature the camera sees puts the goal (``goal``: the feature's measured place plus
    its known relation to the goal, left camera frame, m; ``goal_covariance``: of both,
    3x3, m^2): eq. 4's stand-in. Returns the displacement and its covariance."""
    origin = np.zeros(3)
    return (object_fit.pose[:3, 3] - goal,
            point_covariance(object_fit, origin) + goal_covariance)


@dataclass(frozen=True)
class Fused:
    """Displacements of several cameras fused by inverse covariance (world frame, m)."""

    displacement: np.ndarray
    covariance: np.ndarray
    cameras: list[str] = field(default_factory=list)
    chi2: float = 0.0  # of the cameras' disagreement, 3 (n - 1) degrees of freedom
    dropped: dict[str, str] = field(default_factory=dict)  # camera -> why it was left out
    # with cameras left out: all of them fused (``fuse``: grown by their disagreement)
    disputed: Fused | None = None

    @property
    def agreed(self) -> bool:
        """Whether the cameras fused agree within chance (chi-square at most its
        CHANCE percentile for 3 (n - 1) degrees of freedom; one camera always does)."""
        dof = 3 * (len(self.cameras) - 1)
        return dof == 0 or self.chi2 <= chi_square.ppf(CHANCE, dof)

    @property
    def sd_m(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def summary(self) -> dict[str, Any]:
        out = {"displacement": self.displacement.round(6).tolist(),
               "covariance": self.covariance.round(10).tolist(),
               "sd_m": self.sd_m.round(6).tolist(), "cameras": self.cameras,
               "chi2": round(self.chi2, 3)}
        return out | ({"dropped": self.dropped} if self.dropped else {})


def fuse(measured: dict[str, tuple[np.ndarray, np.ndarray]]) -> Fused | None:
    """The inverse-covariance mean of each camera's (displacement, covariance) in one
    frame; None when there are none. Where the cameras disagree by more than their
    covariances allow (chi-square above its 3 (n - 1) degrees of freedom), the mean's
    covariance is scaled by that ratio (the Birge ratio, squared): some camera's error is
    larger than it says, and nothing tells which."""
    if not measured:
        return None
    information = {name: np.linalg.inv(c) for name, (_, c) in measured.items()}
    total = sum(information.values())
    covariance = np.linalg.inv(total)
    mean = covariance @ sum(information[n] @ d for n, (d, _) in measured.items())
    chi2 = float(sum((d - mean) @ information[n] @ (d - mean) for n, (d, _) in measured.items()))
    dof = 3 * (len(measured) - 1)
    if dof and chi2 > dof:
        covariance = covariance * (chi2 / dof)
    return Fused(mean, covariance, sorted(measured), chi2)


def fuse_robust(measured: dict[str, tuple[np.ndarray, np.ndarray]],
                prediction: tuple[np.ndarray, np.ndarray] | None) -> Fused | None:
    """``fuse``, with the prediction (the last fused displacement plus the commanded
    step, and its covariance) as the arbiter where the cameras disagree beyond chance:
    a camera whose measurement the prediction, too, puts beyond chance is left out,
    unless that would leave out every camera (then the prediction is what is wrong)."""
    fused = fuse(measured)
    if fused is None or prediction is None or fused.agreed:
        return fused
    expected, spread = prediction
    dropped = {}
    for name, (d, c) in measured.items():
        off = d - expected
        distance = float(off @ np.linalg.solve(c + spread, off))
        if distance > chi_square.ppf(CHANCE, 3):
            dropped[name] = (f"disagrees with the other cameras (chi-square {fused.chi2:.1f}) "
                             f"and with the prediction by {math.sqrt(distance):.1f} sd")
    kept = {n: m for n, m in measured.items() if n not in dropped}
    if not dropped or not kept:
        return fused
    rest = fuse(kept)
    assert rest is not None
    return dataclasses.replace(rest, dropped=dropped, disputed=fused)


def prediction_start(fused: Fused) -> tuple[np.ndarray, np.ndarray]:
    """Where the next step's prediction starts (displacement, covariance): the fusion,
    or, with cameras left out, all of them fused (``Fused.disputed``), as uncertain as
    their disagreement. A prediction from the cameras kept would follow them, and leave
    out a camera that was right every step after."""
    whole = fused if fused.disputed is None else fused.disputed
    return whole.displacement, whole.covariance


def in_world(displacement: np.ndarray, covariance: np.ndarray, R_world_cam: np.ndarray,
             rotation_sd_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """A camera-frame displacement and its covariance turned into the world by the
    camera's believed rotation (OpenCV camera to world), whose own uncertainty (rad per
    axis) turns the displacement and adds (sd x its length)^2 across it."""
    d = R_world_cam @ displacement
    length = float(np.linalg.norm(d))
    across = np.eye(3) - np.outer(d, d) / max(length ** 2, 1e-18)
    turned = (rotation_sd_rad * length) ** 2 * across
    return d, R_world_cam @ covariance @ R_world_cam.T + turned


def largest_sd(covariance: np.ndarray) -> float:
    """The standard deviation along a covariance's most uncertain axis."""
    return math.sqrt(max(float(np.linalg.eigvalsh(covariance).max()), 0.0))


def within_probability(mean: np.ndarray, sd_m: float, tolerance_m: float) -> float:
    """The probability that a displacement normally distributed about ``mean`` (m) with
    ``sd_m`` per axis lies within ``tolerance_m`` of zero (non-central chi-square, three
    degrees of freedom)."""
    if sd_m <= 0:
        return float(np.linalg.norm(mean) <= tolerance_m)
    return float(ncx2.cdf((tolerance_m / sd_m) ** 2, 3, float(mean @ mean) / sd_m ** 2))


# how :func:`stop_reason` begins its two reasons: the task stopped believing the panel
# within the tightest tolerance (rather than at the step bound, or having lost it)
CONFIDENT = "confident within the tightest tolerance"
LIKELIER = "within stop_share of the tightest tolerance"
STOPPED_WITHIN = (CONFIDENT, LIKELIER)


def stop_reason(displacement: np.ndarray, covariance: np.ndarray, tolerance_m: float,
                share: float, sigmas: float, agreed: bool = True, gain: float = 1.0,
                execution_sd_m: float = 0.0) -> str | None:
    """Why the guided motion should stop here, if it should, once the displacement is
    within ``share`` of ``tolerance_m``: its bound at ``sigmas`` standard deviations (the
    covariance's largest axis) is within the tolerance itself (the true displacement is
    then within it with that confidence); or stopping here is likelier to end within the
    tolerance than one more step, which moves by ``gain`` of the displacement and errs by
    ``execution_sd_m`` per axis on top of this measurement's error (each probability with
    the largest axis's sd on every axis: ``within_probability``). Otherwise it goes on. A
    fusion of cameras that disagree beyond chance (not ``agreed``) is uncertain by their
    disagreement, which the next measurement may not share: only the first reason
    stops it."""
    length = float(np.linalg.norm(displacement))
    if length > share * tolerance_m:
        return None
    worst = largest_sd(covariance)
    if length + sigmas * worst <= tolerance_m:
        return CONFIDENT
    if not agreed:
        return None
    now = within_probability(displacement, worst, tolerance_m)
    after = within_probability((1 - gain) * displacement, math.hypot(worst, execution_sd_m),
                               tolerance_m)
    if now >= after:
        return (f"{LIKELIER}, where stopping ({now:.2f}) is "
                f"likelier than one more step ({after:.2f}) to end within it")
    return None
