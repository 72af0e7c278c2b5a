"""One placement of one robot's camera as it ended, and how its poses are reported.

A placement is the first (``step`` None) or a re-placement during the task. Its
``pose`` is where the camera truly was when the move ended: only the evaluation reads
it. The robot believes its camera where the correction put it, or, with no trusted
correction, where it was commanded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from taskcam.calibration.pose import rotation_deg
from taskcam.mapping import Target
from taskcam.sim.stages.correction import Correction
from taskcam.sim.stages.task_result import Camera
from taskcam.sim.world.ik import IKResult
from taskcam.sim.world.motion import MotionResult
from taskcam.sim.world.plan import Plan
from taskcam.sim.world.scene import Robot


def pose_dict(T: np.ndarray) -> dict[str, list[float]]:
    """World position and quaternion (w, x, y, z) of a pose (4x4)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, T[:3, :3].ravel())
    return {"position": T[:3, 3].tolist(), "quat_wxyz": quat.tolist()}


def pose_error(commanded: np.ndarray, achieved: np.ndarray) -> dict[str, float]:
    """Position (m) and rotation angle (deg) from a commanded camera pose to the achieved
    one (4x4 each)."""
    return {"position_m": float(np.linalg.norm(achieved[:3, 3] - commanded[:3, 3])),
            "orientation_deg": rotation_deg(commanded, achieved)}


def correction_summary(c: Correction | None, commanded: np.ndarray,
                       achieved: np.ndarray) -> dict[str, Any]:
    """The pose correction's outcome (``estimated_pose`` and ``correction``), with its
    error against the simulator's truth before (the commanded pose) and after."""
    if c is None:
        return {}
    out = {**c.summary(), "error_before": pose_error(commanded, achieved)}
    if c.pose is not None:
        out["error_after"] = pose_error(c.pose, achieved)
    if c.bundle_pose is not None:
        out["bundle_error"] = pose_error(c.bundle_pose, achieved)
    out["other_estimators_error"] = {m: pose_error(T, achieved) for m, T in c.others.items()}
    estimated = {} if c.pose is None else {"estimated_pose": pose_dict(c.pose)}
    return {**estimated, "correction": out}


@dataclass(frozen=True)
class Placement:
    """One placement of one robot: the search's counts, and with a target taken, the
    candidate, the IK solution, the move and the correction."""

    robot: Robot
    index: int = 0  # in the robot's placements
    step: int | None = None  # the task step of a re-placement
    reason: str = "initial"
    target: Target | None = None
    commanded: np.ndarray | None = None  # the candidate position (m)
    commanded_pose: np.ndarray | None = None  # the camera at the IK solution (4x4)
    pose: np.ndarray | None = None  # the camera's true pose after the move (4x4)
    rating: dict[str, float] = field(default_factory=dict)
    ik: IKResult | None = None
    motion: MotionResult | None = None
    correction: Correction | None = None
    plan: Plan | None = None  # the goal and the path there
    strategy: str = "exhaustive"
    evaluated: int = 0  # candidates the search rated
    rated: int = 0  # of them, with a positive rating (or ordered by the method)
    candidates_tried: int = 0  # of them, tried with IK
    undetectable: int = 0  # candidates skipped: the detector could not find the target
    # ... and those that would not hold the insertion site in focus and in frame
    site_unseen: int = 0
    out_of_reach: int = 0  # ... and those the arm reaches from no place the base gets to
    farthest: dict[str, Any] | None = None  # the best of those: rating, position, height
    trips: list[dict[str, Any]] = field(default_factory=list)  # looks and drives to see more
    reach_m: float = 1.0  # the arm's reach (m): a rotation's error swings the camera there
    rejections: dict[str, int] = field(default_factory=dict)  # by why
    unreachable: list[dict[str, Any]] = field(default_factory=list)  # why, first few

    @property
    def placed(self) -> bool:
        return self.target is not None

    def refused(self) -> str:
        """Why no candidate was taken (empty when placed)."""
        if self.placed:
            return ""
        if self.evaluated == 0:
            return "no known-free candidate in the robot's region"
        if self.rated == 0:
            return (f"no candidate with a positive rating among the {self.evaluated} "
                    "known-free ones in the robot's region")
        best = ""
        if self.farthest is not None:
            f = self.farthest
            best = (f"; the best out of reach, RF {f['rating']:.3g}, stands "
                    f"{f['height_m']:.2f} m high at {f['position']}")
        looked = f"; it drove {len(self.trips)} times to scan the floor" if self.trips else ""
        if self.candidates_tried == 0:
            standless = self.rejections.get("no place to stand", 0)
            return ("no reachable candidate with a positive rating from which the detector "
                    "can find the target and the insertion site is in view "
                    f"({self.out_of_reach} out of the arm's reach from every place the base "
                    f"gets to, {self.undetectable} undetectable, {self.site_unseen} with the "
                    f"site out of view, {standless} with every stand in collision){best}"
                    f"{looked}")
        why = ", ".join(f"{k} {v}" for k, v in sorted(self.rejections.items()))
        return (f"every candidate tried was rejected ({why}; {self.out_of_reach} out of "
                f"reach){best}{looked}")

    # ------------------------------------------------------------ the robot's belief

    def believed_pose(self) -> np.ndarray:
        """Where the robot believes its camera is: the correction's estimate unless it
        failed, else as commanded (4x4, MuJoCo camera convention)."""
        if self.correction is not None and self.correction.pose is not None:
            return self.correction.pose
        assert self.commanded_pose is not None, "only placed robots have a camera pose"
        return self.commanded_pose

    def believed_sd(self, prior: tuple[float, float]) -> tuple[float, float]:
        """Standard deviation of the believed camera pose: position (m), rotation (deg);
        ``prior`` is an uncorrected pose's."""
        return prior if self.correction is None else self.correction.believed_sd(prior)

    @property
    def pose_status(self) -> str:
        """``corrected``, ``uncertain`` or ``failed`` (see Correction.status), or ``as
        commanded`` with correction off."""
        return "as commanded" if self.correction is None else self.correction.status

    def camera(self, prior: tuple[float, float]) -> Camera:
        """The placed camera as the task knows it: believed pose, its uncertainty at the
        arm's reach (m) and status; ``prior`` is an uncorrected pose's (m, deg)."""
        position_sd, rotation_sd = self.believed_sd(prior)
        return Camera(self.robot, self.believed_pose(),
                      math.hypot(position_sd, self.reach_m * math.radians(rotation_sd)),
                      self.pose_status, math.radians(rotation_sd))

    # ------------------------------------------------------------ the record

    def summary(self) -> dict[str, Any]:
        """This placement's record in ``summary.json``'s ``placements``."""
        out: dict[str, Any] = {
            "index": self.index, "step": self.step, "reason": self.reason,
            "placed": self.placed,
            "search": {"strategy": self.strategy, "candidates_evaluated": self.evaluated,
                       "candidates_rated": self.rated,
                       "refused_undetectable": self.undetectable,
                       "refused_site_out_of_view": self.site_unseen,
                       "refused_out_of_reach": self.out_of_reach,
                       "best_out_of_reach": self.farthest, "scouting_trips": self.trips},
            "candidates_tried": self.candidates_tried, "rejections": dict(self.rejections),
            "unreachable": self.unreachable}
        if not self.placed:
            return {**out, "refused": self.refused()}
        assert (self.target is not None and self.commanded is not None and self.ik is not None
                and self.commanded_pose is not None and self.pose is not None)
        return {**out,
                "candidate_position": self.commanded.tolist(),
                "commanded_pose": pose_dict(self.commanded_pose),
                "pose": pose_dict(self.pose),
                "positioning_error": pose_error(self.commanded_pose, self.pose),
                "target": self.target.summary(), "rating": self.rating,
                "ik": self.ik.summary(),
                "path": None if self.plan is None else self.plan.summary(),
                "motion": None if self.motion is None else self.motion.summary(),
                **correction_summary(self.correction, self.commanded_pose, self.pose)}
