"""Stage 3: the placed cameras look (sec. 2.2).

The scene is rendered from the reached poses; each camera locates its own target in
the left image (for the evaluation: the truth says how much of it is in view), and
looks in stereo for every target where its believed pose puts it
(calibration/target_frame.py), except where its map has seen something in the way.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from taskcam.calibration import locate_hole
from taskcam.calibration.target_frame import Sighting, projected_disk, sight
from taskcam.mapping import OccupancyGrid, Pinhole, Target, opencv_pose
from taskcam.placement import line_of_sight
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.stages.placement_result import Placement
from taskcam.sim.stages.rating_problem import target_model
from taskcam.sim.stages.relative import SLOT_REFIT_SD, SLOT_WALLS, SlotBelief, slot_model
from taskcam.sim.stages.slot_target import is_slot, nominal_slot, sight_slot, stereo_rig
from taskcam.sim.stages.task_images import pair_seen
from taskcam.sim.stages.world import Bodies, State, World
from taskcam.sim.world.render import Renderer, camera_pose
from taskcam.sim.world.scene import Robot

# A line of sight to a target is checked in the map up to this many voxels short of it:
# the plate around the hole fills the last voxels (about 3 along a line 70 deg oblique).
SIGHT_STOP_VOXELS = 3


@dataclass(frozen=True)
class Look:
    """What the placed cameras saw: per robot, ``summary.json``'s ``seen``, ``pixel``,
    ``sightings`` and the placement it looked from; every stereo sighting; and the world
    when they looked (for ``look.xml``)."""

    rows: dict[str, dict[str, Any]]
    sightings: tuple[Sighting, ...]
    state: State
    bodies: Bodies

    def summary(self, robot: str) -> dict[str, Any]:
        return self.rows[robot]


def find_target(rgb: np.ndarray, seg: np.ndarray, target: Target, target_geom: int,
                T_world_mjcam: np.ndarray, pinhole: Pinhole) -> dict[str, Any]:
    """Locate the target in the image by LoG and template matching, near where the camera
    pose puts it; the segmentation image says how much of it is really in view."""
    visible_px = int((seg == target_geom).sum())
    disk = projected_disk(target, opencv_pose(T_world_mjcam), pinhole)
    if disk is None:
        return {"seen": False, "pixel": None, "target_pixels": visible_px}
    expected, shape = disk
    full_area = math.pi * abs(float(np.linalg.det(shape)))
    radius_px = math.sqrt(full_area / math.pi)
    found = locate_hole(rgb, (float(expected[0]), float(expected[1])), radius_px,
                        search_px=max(3 * radius_px, 10.0), shape=shape)
    seen = found is not None and visible_px >= 0.5 * full_area
    return {"seen": seen,
            "pixel": None if found is None else [found.u, found.v],
            "expected_pixel": expected.tolist(),
            "detection_score": None if found is None else found.score,
            "target_pixels": visible_px, "expected_target_pixels": round(full_area, 1)}


def found_slot(seg: np.ndarray, model: mujoco.MjModel, slot: Target,
               sightings: list[Sighting]) -> dict[str, Any]:
    """A camera placed for the slot saw it when it fitted the rails in stereo; the
    segmentation says how many of the rails' pixels are in view."""
    rails = [model.geom(name).id for name in SLOT_WALLS]
    mine = next((f for f in sightings if f.target == slot.name), None)
    return {"seen": mine is not None, "pixel": None if mine is None else list(mine.pixel),
            "target_pixels": int(np.isin(seg, rails).sum())}


def target_sd(s: Scenario, t: Target) -> float:
    """Standard deviation (m, root of the covariance's trace) of a target's true place
    about its nominal one: the work-piece's misplacement, x and y, and its yaw error
    swinging the target about the work-piece's origin."""
    w = s.workpiece
    lever = float(np.linalg.norm(t.position[:2] - np.asarray(w.position, float)))
    return math.sqrt(2 * w.position_error_m ** 2 + (lever * math.radians(w.yaw_error_deg)) ** 2)


def hidden_in_map(grid: OccupancyGrid, camera: np.ndarray, targets: tuple[Target, ...]
                  ) -> dict[str, bool]:
    """Per target, whether the map has seen something occupied (a voxel at the
    probability one hit gives, or above) on the line from ``camera`` (world, m) to it.
    A camera outside the map's bounds has no evidence."""
    g = grid
    if not g.inside(g.index(camera[None]))[0]:
        return {t.name: False for t in targets}
    points = np.array([target_model(t).position for t in targets])  # as the rating saw them
    seen = line_of_sight(g, camera, points, stop_short=SIGHT_STOP_VOXELS * g.resolution,
                         blocked=g.probability() >= g.model.hit)[0]
    inside = g.inside(g.index(points))
    return {t.name: bool(i and not v) for t, i, v in zip(targets, inside, seen, strict=True)}


def look(world: World, renderer: Renderer, placements: list[Placement],
         targets: tuple[Target, ...], prior_sd: tuple[float, float]) -> Look:
    """Render from the reached poses; per robot, find its target in the image and every
    one of ``targets`` in stereo. ``prior_sd`` is an uncorrected pose's standard
    deviation (m, deg)."""
    timer, recorder, pinhole = world.timer, world.recorder, world.pinhole
    rows: dict[str, dict[str, Any]] = {}
    sightings: list[Sighting] = []
    truth = {t.name: t.position for t in targets}
    state, bodies = world.state(), world.bodies()
    recorder.tick()
    for p in placements:
        robot = p.robot
        with timer("render"):
            rgb, depth = renderer.rgb_and_depth(world.data, robot.camera)
            right = renderer.rgb(world.data, robot.right_camera)
            seg = renderer.segmentation(world.data, robot.camera)
        achieved = camera_pose(world.data, robot.camera)  # the truth, for evaluation
        recorder.camera(robot.name, achieved, pinhole, rgb, depth)
        row: dict[str, Any] = {"seen": False, "pixel": None, "seen_from_placement": p.index}
        if p.target is not None:
            found = _sight(world, robot, rgb, right, p, targets, prior_sd)
            if is_slot(p.target):
                row.update(found_slot(seg, world.model, p.target, found))
            else:
                row.update(find_target(rgb, seg, p.target, world.model.geom(p.target.geom).id,
                                       achieved, pinhole))
            sightings += found
            row["sightings"] = [f.summary(truth[f.target]) for f in found]
        rows[robot.name] = row
    return Look(rows, tuple(sightings), state, bodies)


def _sight(world: World, robot: Robot, left: np.ndarray, right: np.ndarray, p: Placement,
           targets: tuple[Target, ...], prior_sd: tuple[float, float]) -> list[Sighting]:
    """Every target the camera finds in stereo, placed through its believed pose (the
    corrected one, else the commanded one), with that pose's uncertainty carried to
    the target."""
    found_all: list[Sighting] = []
    if p.commanded_pose is None:
        return found_all
    s = world.scenario
    believed = p.believed_pose()
    position_sd, rotation_sd = p.believed_sd(prior_sd)
    hidden = hidden_in_map(world.grid, believed[:3, 3], targets)
    camera = p.camera(prior_sd)
    for t in targets:
        if hidden[t.name]:
            continue  # whatever is seen there, it is not the target
        if is_slot(t):
            # no closer than a fit repeats: a scenario may place the work-piece exactly
            belief = SlotBelief(nominal_slot(world), (
                max(target_sd(s, t), SLOT_REFIT_SD[0]),
                max(math.radians(s.workpiece.yaw_error_deg), SLOT_REFIT_SD[1])))
            found = sight_slot(camera, (left, right), t, belief, stereo_rig(world),
                               slot_model(world.nominal),
                               pair_seen(left, right, world.pinhole, s.camera.baseline_m))
        else:
            found = sight(robot.name, left, right, t, believed, world.pinhole,
                          s.camera.baseline_m,
                          position_sd_m=math.hypot(position_sd, target_sd(s, t)),
                          rotation_sd_deg=rotation_sd,
                          others=tuple(o for o in targets if o is not t and not is_slot(o)))
        if found is not None:
            reach = float(np.linalg.norm(found.position - believed[:3, 3]))
            pose_sd = math.hypot(position_sd, reach * math.radians(rotation_sd))
            found_all.append(dataclasses.replace(found, sd_m=pose_sd, placement=p.index,
                                                 pose_status=p.pose_status))
    return found_all

