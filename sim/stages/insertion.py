"""Stage 4 over the world: the insertion task run with the placed cameras
(sim/stages/task.py), toward the slot where the measured target frame puts it; a camera
that keeps losing the panel is placed again on the updated map. Not attempted when no
camera located the primary target: there is no slot to go to."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.target_frame import in_measured_frame
from calibration.targets import Target
from sim.stages.corrector import PoseCorrector
from sim.stages.place import place
from sim.stages.placement_result import Placement
from sim.stages.rating_problem import RatingProblem
from sim.stages.task import InsertionTask, Replacement
from sim.stages.task_result import Camera, TaskResult
from sim.stages.world import World
from sim.world.optics import Lens
from sim.world.render import Renderer


@dataclass(frozen=True)
class Insertion:
    """The task's outcome, and every robot's placements in order, the re-placements
    made during the task included."""

    result: TaskResult
    placements: dict[str, tuple[Placement, ...]]

    def summary(self) -> dict[str, Any]:
        return self.result.summary()


def current(history: tuple[Placement, ...] | list[Placement]) -> Placement:
    """The placement a robot is at: its last successful one, else its first."""
    return next((p for p in reversed(history) if p.placed), history[0])


def run_task(world: World, renderer: Renderer, placements: dict[str, tuple[Placement, ...]],
             frame: dict[str, Any], frame_robots: list[str], targets: tuple[Target, ...],
             method: str, corrector: PoseCorrector | None, prior_sd: tuple[float, float]
             ) -> Insertion:
    """Guide the panel into its slot with the robots' current placements; ``frame`` is
    the target frame their sightings of ``targets`` measured (``frame_robots`` those of
    the primary target). A re-placement searches the map as the task left it, with the
    placement ``method``; ``prior_sd`` is an uncorrected pose's standard deviation
    (m, deg)."""
    s = world.scenario
    histories = {name: list(h) for name, h in placements.items()}
    at = {name: current(h) for name, h in histories.items()}
    cameras = [p.camera(prior_sd) for p in at.values() if p.placed]
    lens = Lens(s.camera.near_m, s.camera.far_m, s.camera.coc_px)
    task = InsertionTask(world.scene, world.model, world.data, renderer, world.pinhole,
                         s.camera.baseline_m, lens, world.grid, s.task, world.rng,
                         world.recorder)

    def done(result: TaskResult) -> Insertion:
        return Insertion(result, {name: tuple(h) for name, h in histories.items()})

    if frame.get("frame") is None:
        return done(task.not_attempted(cameras, "no camera located the primary target"))
    nominal_slot = np.array(world.belief.site("workpiece/slot").xpos)  # in the CAD model
    slot = in_measured_frame(nominal_slot, targets, frame)

    def replace(cam: Camera, step: int, lost: int) -> Replacement | None:
        if not s.task.replace:
            return None
        name = cam.robot.name
        history = histories[name]
        others = [p.commanded for other, p in at.items()
                  if other != name and p.commanded is not None]
        reason = f"lost the panel {lost} steps running"
        again = place(world, RatingProblem(world.grid, s), cam.robot, others, targets, method,
                      corrector, prior_sd, index=len(history), step=step, reason=reason)
        history.append(again)
        record: dict[str, Any] = {"step": step, "robot": name, "reason": reason,
                                  "placed": again.placed, "placement": again.index}
        if not again.placed:
            return Replacement(record, None)
        at[name] = again
        return Replacement(record, again.camera(prior_sd))

    return done(task.run(cameras, slot, replace, frame_robots))
