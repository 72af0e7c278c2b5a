"""Stage 4 over the world: the insertion task run with the placed cameras
(sim/stages/task.py), toward the slot where the measured target frame puts it; a camera
that keeps losing the panel is placed again on the updated map. Not attempted when no
camera located a target (the primary, or a secondary one standing in for it): there is
no slot to go to."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from taskcam.calibration.target_frame import Sighting, in_measured_frame
from taskcam.mapping import LyingPose, Target, lying_pose
from taskcam.sim.stages.corrector import PoseCorrector
from taskcam.sim.stages.panel_model import panel_model
from taskcam.sim.stages.place import place, ranked_field
from taskcam.sim.stages.placement_result import Placement
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.stages.relative import (
    SlotBelief,
    StandIn,
    believed_slot,
    slot_half_width,
    slot_outer_half_width,
    stand_in,
)
from taskcam.sim.stages.replacement import Replacement
from taskcam.sim.stages.site_view import SITE, SiteWatch, box_corners
from taskcam.sim.stages.slot_target import nominal_panel, nominal_slot, stereo_rig
from taskcam.sim.stages.task import InsertionTask
from taskcam.sim.stages.task_result import Camera, TaskResult
from taskcam.sim.stages.world import World
from taskcam.sim.world.optics import Lens
from taskcam.sim.world.render import Renderer


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
             frame: dict[str, Any], sightings: tuple[Sighting, ...], targets: tuple[Target, ...],
             method: str, corrector: PoseCorrector | None, prior_sd: tuple[float, float]
             ) -> Insertion:
    """Guide the panel into its slot with the robots' current placements; ``frame`` is
    the target frame their ``sightings`` of ``targets`` measured; a camera placed for a
    secondary target measures the panel against it (:func:`stand_ins`). A re-placement searches
    the map as the task left it, with the placement ``method``; ``prior_sd`` is an
    uncorrected pose's standard deviation (m, deg)."""
    s = world.scenario
    histories = {name: list(h) for name, h in placements.items()}
    at = {name: current(h) for name, h in histories.items()}
    cameras = [p.camera(prior_sd) for p in at.values() if p.placed]
    lens = Lens(s.camera.near_m, s.camera.far_m, s.camera.coc_px)
    task = InsertionTask(world.scene, world.model, world.data, renderer, world.pinhole,
                         s.camera.baseline_m, lens, world.grid, s.task, world.task_rng,
                         world.recorder)

    def done(result: TaskResult) -> Insertion:
        return Insertion(result, {name: tuple(h) for name, h in histories.items()})

    if frame.get("frame") is None:
        return done(task.not_attempted(cameras, "no camera located a target"))
    slot = slot_belief(world, targets, frame)

    # the site watched with the panel as the one occluder that moves; the robots stand
    # still during the task and were accounted for when the cameras were placed
    watch = SiteWatch(world.grid, s, slot.position, task.model, slot.pose[:3, 1],
                      slot_half_width(task.slot_boxes))
    # found, as the slot target is (sim/stages/slot_target.py), by the walls beside it
    site = Target(SITE, "site", "", watch.site.position, watch.site.normal,
                  watch.site.radius, 0.0, watch.site.half_length, watch.site.axis,
                  detect_radius=slot_outer_half_width(task.slot_boxes))

    def replace(cam: Camera, step: int, reason: str, current: float | None,
                panel: np.ndarray) -> Replacement | None:
        """Place a camera again on the updated map, for the best view of the insertion
        site (the task's target is the displacement), the panel where it was
        measured as one more occluder. One whose view of the site fell (``current``, its
        rating now) moves there unless that view is not worth the move; one that lost
        the panel (``current`` None) moves to the best view somewhere else than where it
        lost it. Where no view of the site rates (the panel covers it from everywhere),
        the camera stays."""
        if not s.task.replace:
            return None
        name = cam.robot.name
        history = histories[name]
        taken = [p.commanded for other, p in at.items()
                 if other != name and p.commanded is not None]
        problem = RatingProblem(world.grid, s)
        extra = [box_corners(task.model, panel)]  # the panel where it is
        ranked = ranked_field(world, problem, cam.robot, (site,), taken, method, extra)
        best = float(ranked.ratings.total.max()) if len(ranked.ratings.total) else 0.0
        record: dict[str, Any] = {"step": step, "robot": name, "reason": reason,
                                  "best_rating": round(best, 6)}
        if current is not None:
            record["site_rating"] = round(current, 6)
            if not watch.trigger.worth_the_move(name, current, best):
                return Replacement({**record, "placed": False, "worth_the_move": False}, None)
        elif best == 0.0:
            return Replacement({**record, "placed": False}, None)
        here = at[name].commanded
        avoid = [here] if current is None and here is not None else []
        again = place(world, problem, cam.robot, taken, (site,), method, corrector, prior_sd,
                      index=len(history), step=step, reason=reason, extra=extra, avoid=avoid,
                      ranked=ranked)
        history.append(again)
        record.update(placed=again.placed, placement=again.index)
        if not again.placed:
            return Replacement(record, None)
        at[name] = again
        return Replacement(record, again.camera(prior_sd))

    frame_robots = sorted({f.robot for f in sightings
                           if f.target in (frame["frame"] or {}).get("from", [])})
    with world.meter("task", "step", s.task.max_steps) as task.on_step:
        return done(task.run(cameras, slot, lying_panel(world), replace, frame_robots, watch,
                             stand_ins(world, at, sightings, targets, frame, slot, prior_sd)))


def slot_belief(world: World, targets: tuple[Target, ...], frame: dict[str, Any]) -> SlotBelief:
    """Where the measured target frame puts the slot (:func:`believed_slot`)."""
    return believed_slot(nominal_slot(world), targets, frame,
                         world.scenario.workpiece.yaw_error_deg)


def stand_ins(world: World, at: dict[str, Placement], sightings: tuple[Sighting, ...],
              targets: tuple[Target, ...], frame: dict[str, Any], slot: SlotBelief,
              prior_sd: tuple[float, float]) -> dict[str, list[StandIn]]:
    """Per placed camera, where each secondary target it sighted from where it stands
    puts the slot (the target frame's turn of the CAD model relating them); the target
    it was placed for first."""
    by_name = {t.name: t for t in targets}
    rig = stereo_rig(world)
    out: dict[str, list[StandIn]] = {}
    for name, p in at.items():
        placed_for = None if p.target is None else p.target.name
        mine = [f for f in sightings if f.robot == name and f.placement == p.index
                and f.target in by_name and by_name[f.target].role == "secondary"]
        mine.sort(key=lambda f: f.target != placed_for)  # the one it was placed for first
        for seen in mine:
            t = by_name[seen.target]
            offset = slot.position - in_measured_frame(t.position, targets, frame)
            out.setdefault(name, []).append(stand_in(p.camera(prior_sd), seen, t, offset,
                                                     slot.sd[1], rig, seen.target == placed_for))
    return out


def lying_panel(world: World) -> LyingPose:
    """The panel's pose where it lies as the robots perceived it (its CAD model fitted to
    the mapped voxels around where the scenario puts it), with its covariance; the
    scenario's pose, with the misplacement's uncertainty, where the map cannot say."""
    return lying_pose(world.grid, panel_model(world.nominal), nominal_panel(world))
