"""One episode: map cooperatively, place each camera, move there, look, do the task.

The stages, in order, each a function over the episode's world (sim/stages/world.py):
1. the robots map the target region into the occupancy grid, choosing views by
   expected information (sim/stages/exploration.py);
2. robot by robot, a camera is placed by searching the rating function over the map,
   and the robot moves there in physics, with its positioning errors, its pose
   corrected from natural fiducials when correction is on (sim/stages/place.py);
3. the scene is re-rendered from the reached poses, and each camera locates the
   targets; their sightings establish the common target frame (sim/stages/look.py);
4. the placed cameras guide the panel into its slot (sim/stages/insertion.py).

A sweep's trial (sim/experiments/trial.py) runs stages 2-4 once per placement method
from one mapped world: :func:`place_look_do` is that part.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from taskcam.calibration.target_frame import common_frame
from taskcam.mapping import Pinhole
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.run_screen import (
    look_line,
    mapping_line,
    placed_line,
    placement_line,
    replacement_line,
    task_line,
)
from taskcam.sim.screen import Meter
from taskcam.sim.stages.correction import prior_pose_sd
from taskcam.sim.stages.corrector import PoseCorrector
from taskcam.sim.stages.exploration import explore
from taskcam.sim.stages.insertion import run_task
from taskcam.sim.stages.look import Look, look
from taskcam.sim.stages.overview import eye_position, framed_points
from taskcam.sim.stages.place import place
from taskcam.sim.stages.placement_result import Placement, pose_dict, pose_error
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.slot_target import panel_over_slot, task_targets
from taskcam.sim.stages.timer import Timer
from taskcam.sim.stages.world import World, build_world
from taskcam.sim.world.render import Renderer, camera_pose
from taskcam.sim.world.sensing import DepthSensor

VERSION = "0.1.0"
# the recording's 3-D view is framed for a field of view this wide (deg), its picture
# about 1.6 times as wide as high (the layout's world view): about what rerun's viewer
# shows (its eye's field of view cannot be set), so that the robots and the work-piece
# fill the view as they open
EYE_FOVY_DEG = 60.0


@dataclass(frozen=True)
class Outcome:
    """Stages 2-4 on a mapped world: every robot's placements in order, what the cameras
    saw, the target frame they measured (``summary.json``'s ``target_frame``) and the
    task's outcome (None when the task is off)."""

    placements: dict[str, tuple[Placement, ...]]
    look: Look
    frame: dict[str, Any]
    task: dict[str, Any] | None

    def robots(self, world: World) -> list[dict[str, Any]]:
        """``summary.json``'s ``robots``, the world as it is now being where each robot
        ended."""
        return [robot_summary(world, h, self.look.summary(name))
                for name, h in self.placements.items()]


def place_look_do(world: World, renderer: Renderer, problem: RatingProblem, method: str,
                  secondary: bool = True) -> Outcome:
    """Stages 2-4 on the mapped ``world``: place every robot in turn by the placement
    ``method`` (a name taskcam.placement.method_named knows) to view one of the
    targets (with the task on, the slot, and with ``secondary`` the holes that stand in
    for it: :func:`task_targets`), searching ``problem`` (the rating over the map), look,
    and with the task on, do it."""
    s = world.scenario
    targets = task_targets(world, secondary)
    # beyond the map and the other robots, the panel the task will hang over the slot
    extra = [panel_over_slot(world)] if s.task.enabled else []
    prior_sd = prior_pose_sd(s.motion, world.arm.reach_m)  # of a camera pose not corrected
    corrector = None
    if s.correction.enabled:
        corrector = PoseCorrector(world.scene, world.belief, world.data, renderer, world.pinhole,
                                  s.camera.baseline_m, world.grid, s.correction)
    sensor = DepthSensor(renderer, world.pinhole, s.mapping.depth_source, s.camera.baseline_m,
                         world.scene.robot_geoms())  # for scouting's looks
    placements: dict[str, tuple[Placement, ...]] = {}
    taken: list[np.ndarray] = []
    for robot in world.scene.robots:
        world.recorder.tick()
        p = place(world, problem, robot, taken, targets, method, corrector, prior_sd,
                  extra=extra, sensor=sensor)
        world.progress(placement_line(robot.name, p.summary()))
        placements[robot.name] = (p,)
        if p.commanded is not None:
            taken.append(p.commanded)
    world.progress(placed_line([{"name": n, "placed": h[0].placed}
                                for n, h in placements.items()]))
    seen = look(world, renderer, [h[0] for h in placements.values()], targets, prior_sd)
    frame = common_frame(list(seen.sightings), targets)
    world.progress(look_line(seen.rows, frame))
    task = None
    if s.task.enabled:
        with world.timer("task"):
            done = run_task(world, renderer, placements, frame, seen.sightings, targets,
                            method, corrector, prior_sd)
            task = done.summary()
        placements = done.placements
        world.progress(task_line(task))
        for record in task.get("replacements", []):
            history = placements[record["robot"]]
            world.progress(replacement_line(
                record, {"placements": [p.summary() for p in history]}))
    return Outcome(placements, seen, frame, task)


def robot_summary(world: World, placements: tuple[Placement, ...], look: dict[str, Any]
                  ) -> dict[str, Any]:
    """``summary.json``'s record of one robot: where its camera and base ended (``pose``
    and ``base``: x, y in m and yaw in rad, on the floor; the truth, as in ``scene.xml``'s
    keyframe ``final``) and the placement it ended at,
    every placement in order, and what it saw from the placement it looked from."""
    robot = placements[0].robot
    mujoco.mj_forward(world.model, world.data)  # poses where the joints now are
    final = camera_pose(world.data, robot.camera)
    ended = next((p for p in reversed(placements) if p.placed), None)
    now = (ended or placements[-1]).summary()
    for key in ("index", "step", "reason", "pose"):
        now.pop(key, None)
    if ended is not None and ended.commanded_pose is not None:
        now["positioning_error"] = pose_error(ended.commanded_pose, final)
    x, y, yaw = (float(v) for v in world.data.qpos[robot.qpos_adr[:3]])
    return {"name": robot.name, "camera": robot.camera, **now,
            "placed": ended is not None, "pose": pose_dict(final),
            "base": {"x_m": x, "y_m": y, "yaw_rad": yaw},  # as the keyframe "final" has it
            "placement": None if ended is None else ended.index,
            **look, "placements": [p.summary() for p in placements]}


def placed_count(robots: list[dict[str, Any]]) -> dict[str, Any]:
    """``summary.json``'s ``placed``: how many robots ended placed (``count``) of how
    many (``of``), and which (``robots``; ``not_placed``)."""
    names = [r["name"] for r in robots if r["placed"]]
    return {"count": len(names), "of": len(robots), "robots": names,
            "not_placed": [r["name"] for r in robots if not r["placed"]]}


class Episode:
    """The stages of one episode on one scenario, composed."""

    def __init__(self, scenario: Scenario) -> None:
        """Builds the world: raises ScenarioError for geometry the scenario cannot hold."""
        self.scenario = scenario
        self.timer = Timer()
        self.world = build_world(scenario, self.timer)

    @property
    def model(self) -> mujoco.MjModel:
        """The simulated world's model (a renderer is made for it)."""
        return self.world.model

    @property
    def pinhole(self) -> Pinhole:
        """The robots' cameras' intrinsics."""
        return self.world.pinhole

    def map(self, renderer: Renderer) -> dict[str, Any]:
        """Stage 1 alone: ``summary.json``'s ``mapping``."""
        return explore(self.world, renderer).summary()

    def run(self, recorder: Recorder | None = None,
            progress: Callable[[str], None] | None = None, meter: Meter | None = None
            ) -> tuple[dict[str, Any], dict[str, tuple[str, dict[str, bytes]]]]:
        """All stages; returns ``summary.json``'s content and the scenes to save, by file
        name (their MJCF and the files it reads): ``scene.xml``, the world as it ended
        (keyframes ``start`` and ``final``), and ``look.xml``, the world when the targets
        were looked for (keyframe ``look``; the arms' mounts tilted as they were then)."""
        t0 = time.perf_counter()
        world = self.world if recorder is None else replace(self.world, recorder=recorder)
        world = world if progress is None else replace(world, progress=progress)
        world = world if meter is None else replace(world, meter=meter)
        targets = world.scene.targets
        world.recorder.step(0)
        framed = framed_points(world.model, world.data, [r.body_ids for r in world.scene.robots])
        world.recorder.scene(world.model, world.data, [r.name for r in world.scene.robots],
                             self.scenario.task.enabled, eye_position(framed, EYE_FOVY_DEG, 1.6),
                             size_m=float(np.ptp(framed, axis=0).max()),
                             image=(world.pinhole.width, world.pinhole.height))
        world.recorder.targets([t.name for t in targets], np.array([t.position for t in targets]),
                               [t.radius for t in targets])
        with Renderer(world.model, world.pinhole.width, world.pinhole.height) as renderer:
            mapping = explore(world, renderer).summary()
            world.progress(mapping_line(mapping))
            world.hold()
            problem = RatingProblem(world.grid, self.scenario)
            outcome = place_look_do(world, renderer, problem, self.scenario.search.method)
        robots = outcome.robots(world)
        scenes = {"scene.xml": world.to_xml("final"),
                  "look.xml": world.to_xml("look", outcome.look.state, outcome.look.bodies)}
        self.timer.set("total", time.perf_counter() - t0)
        summary = {
            "version": VERSION, "scenario": self.scenario.name, "seed": self.scenario.seed,
            "placed": placed_count(robots), "robots": robots, "mapping": mapping,
            "target_frame": outcome.frame,
            "task": outcome.task, "timings_s": self.timer.rounded(4),
        }
        return summary, scenes
