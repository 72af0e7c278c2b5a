"""The relative measurement as the insertion task makes it: what the task
believes of the panel and the slot becomes each camera's starting poses, the camera's
stereo pair is fitted (calibration/displacement.py), and the cameras' displacements are
turned into the world and fused.

The task keeps two beliefs between steps. The slot: the work-piece is fixed and a placed
camera does not move during a step, so a camera's fitted slot (in its own frame) is its
next step's start. The panel: its carrier holds it without turning it, so its orientation
is one constant, estimated by an information filter over every fit of every camera; its
position is where the last measurement put it plus the commanded step, uncertain by the
step's execution error.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from taskcam.calibration.displacement import (
    Fused,
    Relative,
    fuse_robust,
    in_world,
    largest_sd,
    measure_relative,
    via_feature,
)
from taskcam.calibration.edge_fit import fit_edges
from taskcam.calibration.edge_model import Boxes, Seen, StereoRig
from taskcam.calibration.ekf import StereoCamera
from taskcam.calibration.target_frame import Sighting, frame_motion
from taskcam.mapping import Target, opencv_pose
from taskcam.sim.stages.task_result import Camera

# The holes' frame puts the slot within about this (m, rad per axis): in 15 views at 0.8 m
# and 30 deg (bench/studies/measurement.py's views) the slot it carried was 0.3-2.7 mm off per axis
SLOT_FRAME_SD = (0.002, math.radians(0.5))
# The slot's fit, carried to the same camera's next step, starts this uncertain (m, rad):
# the work-piece does not move, a fit is this repeatable (a few tenths of a pixel)
SLOT_REFIT_SD = (0.001, math.radians(0.2))
# The work-piece stands level on the floor (a scenario turns it about the vertical only),
# so the slot's tilt is known: in a camera's frame as well as that camera's rotation is.
# Only its yaw is as uncertain as the start says. The rails' edges hardly show their tilt
# about their length (their tops lie in one plane); left free, small biases of those
# edges turned the fit by 1-1.5 deg and moved the slot's point, at the rails' feet 30 mm
# below their tops, 0.5-0.7 mm across (bench/studies/measurement.py, 0.8 m, straight down).
# A tilt known exactly is held to this (rad): 3 um at the rails' height, a numerical floor
LEVEL_SD_RAD = 1e-4
# A hole's centre as the detector finds it, per axis (px): within the detector's limits
# 0.10-0.17 px off the ellipse's centre at the median, at most 0.54 px in ~1200 views
# (docs/detector_limits.md); a circular Gaussian's median radius is 1.18 sd, and at
# 0.15 px one in a thousand lies past 0.54 px
HOLE_CENTRE_SD_PX = 0.15
# A camera's pose uncertainty (m at a metre, status "uncertain") turns its displacement;
# an uncorrected camera's rotation is uncertain by this much (rad): the positioning
# error's scale in the default scenario (0.5 deg)
UNCORRECTED_ROTATION_SD = math.radians(0.5)
# A measured panel pose the belief holds this unlikely, in position or in orientation
# (chi-square, 3 degrees of freedom: scipy.stats.chi2.ppf(0.999, 3)), is a wrong fit, not
# the panel: one right pose in 1000 is refused
GATE_CHI2 = 16.27


Images = tuple[np.ndarray, np.ndarray] | str  # a camera's stereo pair, or why it has none
Masks = tuple[np.ndarray, np.ndarray] | None  # the panel's pixels in each image


def levelled(pose: np.ndarray, up: np.ndarray, about: np.ndarray) -> np.ndarray:
    """``pose`` (object to camera, 4x4) turned the least that puts its z axis along
    ``up`` (camera frame), about the object point ``about`` (object frame)."""
    z = pose[:3, 2]
    axis = np.cross(z, up)
    angle = math.atan2(float(np.linalg.norm(axis)), float(z @ up))
    if angle < 1e-12:
        return pose.copy()
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    pivot = pose[:3, :3] @ about + pose[:3, 3]
    out = pose.copy()
    out[:3, :3] = turn @ pose[:3, :3]
    out[:3, 3] = pivot - out[:3, :3] @ about
    return out


def level_covariance(position_sd_m: float, yaw_sd_rad: float, tilt_sd_rad: float,
                     up: np.ndarray) -> np.ndarray:
    """The 6x6 covariance (calibration/edge_fit.py's motion, camera frame) of a level
    object's start: ``position_sd_m`` per axis, turns about ``up`` (camera frame) by
    ``yaw_sd_rad`` and about the horizontal axes by ``tilt_sd_rad``."""
    along = np.outer(up, up)
    out = np.zeros((6, 6))
    out[:3, :3] = position_sd_m ** 2 * np.eye(3)
    out[3:, 3:] = yaw_sd_rad ** 2 * along + tilt_sd_rad ** 2 * (np.eye(3) - along)
    return out


@dataclass(frozen=True)
class SlotBelief:
    """Where the task believes the slot is before any camera fitted it: its frame (4x4,
    world; origin the slot's point between the walls' bottoms, axes the work-piece's) and
    its uncertainty (m, rad per axis)."""

    pose: np.ndarray
    sd: tuple[float, float]

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3]


def believed_slot(nominal: np.ndarray, targets: tuple[Target, ...], frame: dict[str, Any],
                  yaw_error_deg: float) -> SlotBelief:
    """Where the measured target frame (``common_frame``) puts the slot whose CAD pose is
    ``nominal`` (4x4, world), and how uncertain: in position the frame's own shift (its
    targets' sightings, secondary ones with their ST_error) and SLOT_FRAME_SD, and the
    frame's turn (the work-piece's yaw error, ``yaw_error_deg``, the scenario's, when one
    target alone set it) on its lever from the targets it rests on."""
    pose = frame_motion(targets, frame) @ nominal
    measured = frame["frame"]
    yaw_sd = measured.get("yaw_sd_deg")
    unknown = math.radians(yaw_error_deg if yaw_sd is None else yaw_sd)  # the turn's sd
    lever = float(np.linalg.norm(pose[:3, 3] - np.asarray(measured["pivot"])))
    position = math.hypot(measured["sd_m"], SLOT_FRAME_SD[0], unknown * lever)
    return SlotBelief(pose, (position, max(unknown, SLOT_FRAME_SD[1])))


SLOT_WALLS = ("workpiece/rail_a", "workpiece/rail_b")  # the slot's walls' geoms


def slot_model(model: mujoco.MjModel, site: str = "workpiece/slot",
               walls: tuple[str, ...] = SLOT_WALLS) -> Boxes:
    """The slot's CAD model: its walls (box geoms of the work-piece) in the slot's frame
    (origin at the slot site, axes the work-piece body's)."""
    s = model.site(site)
    body = int(s.bodyid[0])
    if not np.allclose(s.quat, [1, 0, 0, 0]):
        raise ValueError(f"site '{site}' must not be turned in its body")
    centres, halves = [], []
    for name in walls:
        g = model.geom(name)
        if int(g.bodyid[0]) != body or int(g.type[0]) != mujoco.mjtGeom.mjGEOM_BOX \
                or not np.allclose(g.quat, [1, 0, 0, 0]):
            raise ValueError(f"slot wall '{name}' must be an unturned box of the site's body")
        centres.append(g.pos - s.pos)
        halves.append(g.size.copy())
    return Boxes(np.array(centres), np.array(halves))


def slot_half_width(slot: Boxes) -> float:
    """Half the slot's width (m): from its frame's origin, across (its x axis), to the
    nearest wall's inner face."""
    return float(np.min(np.abs(slot.centres[:, 0]) - slot.halves[:, 0]))


def slot_outer_half_width(slot: Boxes) -> float:
    """Half the width (m) of the slot with its walls: from its frame's origin, across, to
    the farthest wall's outer face."""
    return float(np.max(np.abs(slot.centres[:, 0]) + slot.halves[:, 0]))


def turn_sd(cam: Camera) -> float:
    """How uncertain a camera's believed rotation is beyond what it says (rad per axis):
    an uncorrected camera's positioning error."""
    return 0.0 if cam.trusted else UNCORRECTED_ROTATION_SD


def slot_start_in(cam: Camera, slot: Boxes, belief: SlotBelief, fitted: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Where a camera's slot fit starts (slot to camera, OpenCV, 4x4), levelled, and the
    start's 6x6 covariance: from the camera's own last fit (``fitted``) as repeatable as
    SLOT_REFIT_SD, else from ``belief`` seen through the camera's believed pose (whose
    own error adds to the position's)."""
    T_cam_world = np.linalg.inv(opencv_pose(cam.believed))
    position_sd, yaw_sd = SLOT_REFIT_SD
    start = fitted
    if start is None:
        start = T_cam_world @ belief.pose
        position_sd, yaw_sd = math.hypot(belief.sd[0], cam.pose_sd_m), belief.sd[1]
    up = T_cam_world[:3, 2]  # the world's vertical, in this camera's frame
    tilt_sd = max(math.hypot(cam.rotation_sd_rad, turn_sd(cam)), LEVEL_SD_RAD)
    return (levelled(start, up, slot.centres.mean(axis=0)),
            level_covariance(position_sd, yaw_sd, tilt_sd, up))


@dataclass
class PanelBelief:
    """The panel's pose as the task believes it (world): orientation from an information
    filter over every fit (the carrier does not turn it), position predicted from the
    last measurement and the commanded step."""

    pose: np.ndarray
    position_sd_m: float
    rotation_information: np.ndarray  # 3x3, rad^-2, world frame

    @property
    def rotation_sd_rad(self) -> float:
        return largest_sd(np.linalg.inv(self.rotation_information))

    def implausible(self, pose: np.ndarray, sd: tuple[float, float]) -> str | None:
        """Why ``pose`` (world), measured uncertain by ``sd`` (m, rad per axis), cannot be
        the panel this belief holds: its position or its orientation beyond GATE_CHI2 of
        both uncertainties together (None if it can be)."""
        moved = pose[:3, 3] - self.pose[:3, 3]
        d_position = float(moved @ moved) / (self.position_sd_m ** 2 + sd[0] ** 2)
        turn = Rotation.from_matrix(pose[:3, :3] @ self.pose[:3, :3].T).as_rotvec()
        spread = np.linalg.inv(self.rotation_information) + sd[1] ** 2 * np.eye(3)
        d_rotation = float(turn @ np.linalg.solve(spread, turn))
        if max(d_position, d_rotation) <= GATE_CHI2:
            return None
        return (f"{np.linalg.norm(moved) * 1e3:.0f} mm and "
                f"{math.degrees(float(np.linalg.norm(turn))):.0f} deg from the belief "
                f"(chi-square {d_position:.0f} and {d_rotation:.0f}, at most {GATE_CHI2:.1f})")

    def observe_rotation(self, R_world_panel: np.ndarray, information: np.ndarray) -> None:
        """Fuse one fit's orientation (world) with what its edges say about it (the
        information, world frame, rad^-2: the fit's prior, this belief, taken out)."""
        total = self.rotation_information + information
        seen = Rotation.from_matrix(R_world_panel @ self.pose[:3, :3].T).as_rotvec()
        turn = np.linalg.solve(total, information @ seen)
        self.pose[:3, :3] = Rotation.from_rotvec(turn).as_matrix() @ self.pose[:3, :3]
        self.rotation_information = total


@dataclass(frozen=True)
class Measurement:
    """One step's relative measurement: the fused displacement (world) or None, the
    panel's pose where the best camera put it, and per camera what it found or why not."""

    fused: Fused | None
    panel: np.ndarray | None
    cameras: dict[str, dict[str, Any]] = field(default_factory=dict)
    fits: dict[str, Relative] = field(default_factory=dict)

    @property
    def why(self) -> dict[str, str]:
        return {n: c["why"] for n, c in self.cameras.items() if "why" in c}


@dataclass(frozen=True)
class StandIn:
    """Where a secondary target a camera sighted puts the slot's point: in that camera's
    frame (OpenCV, m), with the covariance of the sighting and of the target's relation
    to the slot (3x3, m^2)."""

    target: str
    goal: np.ndarray
    covariance: np.ndarray
    placed_for: bool = False  # the camera was placed for this target


def stand_in(cam: Camera, sighting: Sighting, target: Target, offset: np.ndarray,
             yaw_sd_rad: float, rig: StereoRig, placed_for: bool = False) -> StandIn:
    """The slot's point by a camera's stereo sighting of a secondary ``target``: the
    sighting (taken back into the camera's frame through the pose that put it in the
    world) plus ``offset``, the slot's point minus the target's (world, m, as the target
    frame turns the CAD model). Its covariance: the triangulation of centres found to
    HOLE_CENTRE_SD_PX and the perspective shift of the hole's image; the relation's
    ST_error along the plate; the frame's turn (``yaw_sd_rad``) and the camera's own
    rotation uncertainty on the offset's lever."""
    T_world_cam = opencv_pose(cam.believed)
    R = T_world_cam[:3, :3]
    point = R.T @ (sighting.position - T_world_cam[:3, 3])
    depth = float(np.linalg.norm(point))
    n = target.normal / np.linalg.norm(target.normal)
    cos = abs(float(n @ (R @ point))) / depth
    shift_px = rig.fx * (target.radius / depth) ** 2 * cos * math.sqrt(max(1 - cos ** 2, 0.0))
    camera = StereoCamera(rig.fx, rig.fy, rig.cx, rig.cy, rig.baseline_m)
    covariance = camera.point_covariance(point, math.hypot(HOLE_CENTRE_SD_PX, shift_px))
    plane = np.eye(3) - np.outer(n, n)
    lever = plane @ offset
    relation = target.st_error ** 2 * plane + yaw_sd_rad ** 2 * (
        float(lever @ lever) * plane - np.outer(lever, lever))
    o = R.T @ offset
    spin = math.hypot(cam.rotation_sd_rad, turn_sd(cam)) ** 2 * (
        float(o @ o) * np.eye(3) - np.outer(o, o))
    return StandIn(target.name, point + o, covariance + R.T @ relation @ R + spin, placed_for)


class RelativeMeasurer:
    """Measures the panel's displacement from its slot camera by camera."""

    def __init__(self, rig: StereoRig, panel: Boxes, slot: Boxes, slot_belief: SlotBelief,
                 stand_ins: dict[str, list[StandIn]] | None = None) -> None:
        self.rig, self.panel, self.slot, self.belief = rig, panel, slot, slot_belief
        self.slot_fits: dict[str, np.ndarray] = {}  # camera name -> slot pose (its frame)
        # camera name -> the secondary targets it sighted where it stands, the one it
        # was placed for (if so) first
        self.stand_ins: dict[str, list[StandIn]] = dict(stand_ins or {})

    def forget(self, name: str) -> None:
        """A camera moved: its slot fit and its stand-ins no longer hold."""
        self.slot_fits.pop(name, None)
        self.stand_ins.pop(name, None)

    def measure(self, cam: Camera, images: Images,
                masks: Masks, panel: PanelBelief, seen: Seen | None = None
                ) -> tuple[Relative | None, dict[str, Any], tuple[np.ndarray, np.ndarray] | None,
                           np.ndarray | None]:
        """One camera: its relative measurement, its record, its displacement and
        covariance in the world (None if it measured nothing) and the panel's world pose
        it fitted (``seen``: the pair's disparity, what hides the models)."""
        name = cam.robot.name
        if isinstance(images, str):
            return None, {"why": images}, None, None
        T_world_cam = opencv_pose(cam.believed)
        T_cam_world = np.linalg.inv(T_world_cam)
        # what the task believes in the world is where this camera's believed pose puts
        # it: that pose's own error (m at a metre) adds to both starts' uncertainty
        own = cam.pose_sd_m
        slot_start, slot_sd = slot_start_in(cam, self.slot, self.belief,
                                            self.slot_fits.get(name))
        panel_start = T_cam_world @ panel.pose
        panel_sd = (math.hypot(panel.position_sd_m, own), panel.rotation_sd_rad)
        stand_ins = self.stand_ins.get(name, [])
        if stand_ins and stand_ins[0].placed_for:  # the panel against its target (eq. 4)
            via: StandIn | None = stand_ins[0]
            fit = fit_edges(images, self.panel, self.rig, panel_start, panel_sd,
                            [(slot_start, self.slot)], masks=masks, seen=seen)
            found = Relative(None, None, fit, None, None if fit.ok else f"object: {fit.why}")
        else:
            found = measure_relative(images, self.rig, self.panel, panel_start, panel_sd,
                                     self.slot, slot_start, slot_sd, masks, seen)
            # where the slot could not be fitted, a target it sighted stands in
            via = None if found.displacement is not None or not stand_ins else min(
                stand_ins, key=lambda f: float(np.trace(f.covariance)))
        if via is not None and found.object_fit is not None and found.object_fit.ok:
            d_cam, c_cam = via_feature(found.object_fit, via.goal, via.covariance)
            found = dataclasses.replace(found, displacement=d_cam, covariance=c_cam,
                                        goal_fit=None, why=None)
        else:
            via = None
        if found.displacement is None or found.covariance is None:
            return found, {"why": found.why or "no measurement"}, None, None
        assert found.object_fit is not None
        goal = found.goal_fit  # None: measured against a secondary target
        if goal is not None:
            self.slot_fits[name] = goal.pose
        d, c = in_world(found.displacement, found.covariance, T_world_cam[:3, :3],
                        turn_sd(cam))
        record: dict[str, Any] = {
            "displacement": d.round(6).tolist(), "sd_m": np.sqrt(np.diag(c)).round(6).tolist(),
            "edges": {"panel": found.object_fit.inliers, "slot": goal.inliers if goal else 0},
            "rms_px": {"panel": round(found.object_fit.rms_px, 3),
                       "slot": round(goal.rms_px, 3) if goal else None}}
        if via is not None:
            record["via"] = via.target
        return found, record, (d, c), T_world_cam @ found.object_fit.pose

    def step(self, cameras: list[Camera], pairs: dict[str, tuple[Images, Masks, Seen | None]],
             panel: PanelBelief, prediction: tuple[np.ndarray, np.ndarray] | None = None
             ) -> Measurement:
        """Every camera's measurement of this step from its pair, the panel's pixels and
        the pair's disparity, fused (``prediction``, the displacement
        expected from the last step and its covariance, world frame, arbitrates where the
        cameras disagree: ``fuse_robust``); the panel's orientation belief takes in every
        fit the fusion kept."""
        records: dict[str, dict[str, Any]] = {}
        fits: dict[str, Relative] = {}
        world: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        poses: dict[str, np.ndarray] = {}
        turns: dict[str, np.ndarray] = {}  # what each fit says of the panel's rotation
        for cam in cameras:
            name = cam.robot.name
            images, masks, seen = pairs[name]
            found, records[name], in_w, pose = self.measure(cam, images, masks, panel, seen)
            if found is not None:
                fits[name] = found
            if in_w is not None and pose is not None and found is not None \
                    and found.object_fit is not None:
                world[name], poses[name] = in_w, pose
                R = opencv_pose(cam.believed)[:3, :3]
                information = R @ found.object_fit.rotation_information() @ R.T
                spread = turn_sd(cam) ** 2  # the camera's own rotation error
                if spread > 0:
                    information = np.linalg.pinv(np.linalg.pinv(information) + spread * np.eye(3))
                turns[name] = information
        fused = fuse_robust(world, prediction)
        kept = [n for n in world if fused is None or n not in fused.dropped]
        for name in kept:
            panel.observe_rotation(poses[name][:3, :3], turns[name])
        if fused is not None:
            for name, why in fused.dropped.items():
                records[name]["dropped"] = why
        best = min(kept, key=lambda n: float(np.trace(world[n][1])), default=None)
        return Measurement(fused, None if best is None else poses[best], records, fits)
