"""Stage 2 for one robot: place its camera (sec. 2.3).

The placement method (placement/methods.py, by name) gives the candidates in the order
they are tried: the rating function's, searched over known-free voxels in the robot's
region (the robots placed before count as occluders, at their commanded poses), or
others. They are tried in turn (where the method asks it, only those from which the hole
detector can find the target, taskcam.placement.detectable, and that hold the insertion site in
frame) until one is reachable (sim/world/planning.py: a goal configuration by IK,
a path for base and arm by OMPL that keeps clear of everything) and sees its target
with no geometry in the way;
the robot then moves there in the world (sim/stages/move.py) before the next robot
plans. Planning uses the nominal model and the belief, never the world's truth.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from taskcam.mapping import GainModel, Target, region_mask
from taskcam.placement import (
    MethodInput,
    MethodSettings,
    RatingField,
    Region,
    detectable,
    method_named,
    target_points,
)
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.stages.corrector import PoseCorrector
from taskcam.sim.stages.corridor import carry_corridor, sees_site, site_corners
from taskcam.sim.stages.exploration import gain_model
from taskcam.sim.stages.move import move
from taskcam.sim.stages.placement_result import Placement
from taskcam.sim.stages.rating_problem import RatingProblem, target_model
from taskcam.sim.stages.scout import Scouting
from taskcam.sim.stages.world import World
from taskcam.sim.world.base_scanner import scan_into
from taskcam.sim.world.collision import KeepOutBoxes, blocked_rays, robot_points
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.render import camera_pose
from taskcam.sim.world.scene import Robot
from taskcam.sim.world.sensing import DepthSensor

REJECTED_RADIUS_M = 0.08  # after a candidate fails, skip the ones this close to it
# Candidates whose every stand of the capability map is in collision are refused by a
# few validity checks (about 1 ms) and do not count as tried; at most this many are
# passed over, so that a ring of clutter cannot keep the search going forever
MAX_STANDLESS = 500


def region(world: World, robot: Robot, taken: list[np.ndarray]) -> Region:
    """Where ``robot``'s camera may go: the scenario's heights, within the arm's reach of
    where its base may drive (``search.drive_path_m`` from where it stands, as the crow
    flies: the planner measures the way), and apart from the camera positions already
    ``taken`` (m)."""
    s = world.scenario
    q = s.search
    keep_out = tuple((tuple(p), q.robot_separation_m) for p in taken)
    base = world.belief.qpos[robot.qpos_adr[:2]]
    reach = world.arm.reach_m + (q.drive_path_m if s.robots.move_base else 0.0)
    return Region(q.camera_z_m[0], q.camera_z_m[1], keep_out,
                  ((float(base[0]), float(base[1])), reach))


def ranked_field(world: World, problem: RatingProblem, robot: Robot,
                 targets: tuple[Target, ...], taken: list[np.ndarray], method: str,
                 extra: Sequence[np.ndarray] = ()) -> RatingField:
    """The candidates for ``robot``'s camera in the order the placement ``method`` (a
    name taskcam.placement.method_named knows) tries them; ``extra`` are point sets of further
    occluders (the panel during the task), as the other robots are."""
    s = world.scenario
    others = [pts for other in world.scene.robots if other is not robot
              for pts in robot_points(world.nominal, world.belief, other)] + list(extra)
    where = region(world, robot, taken)
    primary = next((k for k, t in enumerate(targets) if t.role == "primary"), 0)

    def rated() -> RatingField:
        return problem.field(robot.name, targets, where, others, world.belief.qpos, world.rng,
                             None)

    def gains() -> GainModel:  # about the primary target, or what is searched for
        interest = region_mask(problem.grid, targets[primary].position,
                               np.array(s.mapping.region_half_m))
        return gain_model(s, problem.grid, world.pinhole, interest)

    given = MethodInput(
        tuple(target_model(t) for t in targets), primary, problem.camera, problem.grid, where,
        world.belief.qpos[robot.qpos_adr[:2]].copy(), world.arm.reach_m, world.rng,
        method_settings(s), rated,
        lambda positions, aims: problem.rated_at(targets, positions, aims, others), gains)
    with world.timer("placement"):
        return method_named(method).choose(given)


def method_settings(s: Scenario) -> MethodSettings:
    """The scenario's settings of the built-in placement methods."""
    q = s.search
    return MethodSettings(s.rating.travel_per_m, q.informed_max_angle_deg,
                          q.biased_random_max_angle_deg, q.gain_samples)


def _findable(ranked: RatingField, candidates: np.ndarray, targets: tuple[Target, ...],
              problem: RatingProblem, baseline_m: float) -> np.ndarray:
    """Per candidate of ``ranked`` (bool; only the indices ``candidates`` are computed):
    can the hole detector find the candidate's target from there, in both stereo images
    (:func:`detectable`, the target as large as what the detector finds of it)?"""
    out = np.zeros(len(ranked.ratings.positions), dtype=bool)
    for t in np.unique(ranked.target[candidates]):
        mine = candidates[ranked.target[candidates] == t]
        target = targets[int(t)]
        seen_as = dataclasses.replace(target_model(target),
                                      radius=max(target.radius, target.detect_radius))
        out[mine] = detectable(ranked.ratings.positions[mine], seen_as, problem.camera,
                               baseline_m=baseline_m)
    return out


def place(world: World, problem: RatingProblem, robot: Robot, taken: list[np.ndarray],
          targets: tuple[Target, ...], method: str, corrector: PoseCorrector | None,
          prior_sd: tuple[float, float], *, index: int = 0, step: int | None = None,
          reason: str = "initial", extra: Sequence[np.ndarray] = (),
          avoid: Sequence[np.ndarray] = (), ranked: RatingField | None = None,
          sensor: DepthSensor | None = None) -> Placement:
    """Search, plan and move ``robot`` to view one of ``targets``, given the camera
    positions already ``taken`` (m) and the placement ``method``. ``index``, ``step`` and
    ``reason`` say which of the robot's placements this is (a re-placement during the
    task has a step); ``prior_sd`` is an uncorrected pose's standard deviation (m, deg);
    ``extra``: further occluders (:func:`ranked_field`); candidates within
    REJECTED_RADIUS_M of a position in ``avoid`` (m) are skipped as a failed one's are;
    ``ranked``: the candidates :func:`ranked_field` gives for these arguments, if the
    caller has them already. In the robots' map, a candidate the arm would reach only
    through space never observed sends the robot scouting (sim/stages/scout.py); with a
    depth ``sensor`` it looks as well as scans."""
    s, belief = world.scenario, world.belief
    q = s.search
    if ranked is None:
        ranked = ranked_field(world, problem, robot, targets, taken, method, extra)
    world.recorder.candidates(robot.name, ranked.ratings.positions, ranked.ratings.total)
    counts: dict[str, Any] = {"strategy": ranked.strategy, "evaluated": ranked.evaluated,
                              "rated": len(ranked.ranked()), "reach_m": world.arm.reach_m}
    tried = undetectable = out_of_frame = 0
    rejections: dict[str, int] = defaultdict(int)
    unreachable: list[dict[str, Any]] = []
    start = belief.qpos.copy()
    corridor = carry_corridor(world.nominal, belief, s.task) if s.task.enabled else None
    # the rating function's target is the displacement (sec. 3): its candidates must hold
    # the insertion site in focus and in frame; other methods choose as they do
    checks = method_named(method)
    corners = None if corridor is None or not checks.site_in_frame else site_corners(corridor)
    # the bases scan the floor where they stand; the planner knows the clutter as mapped
    # (or, as an oracle, as it is: the scans are then not needed)
    if q.planner_world != "model":
        scan_into(world.floor, world.model, world.data, belief, world.scene.robots,
                  world.scene.robot_geoms())
    planner = _planner(world, corridor, q.planner_world)
    # in the robots' map, what was never observed is looked at when it holds them back
    scouting = Scouting(world, robot, lambda kind: _planner(world, corridor, kind), prior_sd,
                        sensor, on=q.planner_world != "model" and s.robots.move_base,
                        drive=step is None)
    rejected = [np.asarray(p, float) for p in avoid]
    standless = 0  # candidates whose every stand was in collision: cheap, not counted
    out_of_reach = 0  # candidates the arm reaches from no place the base gets to
    farthest: dict[str, Any] | None = None  # the best of them
    order = ranked.ranked()
    with world.timer("ik"):
        maybe = planner.may_stand(robot, ranked.ratings.positions[order])
    out_of_reach = int((~maybe).sum())
    if out_of_reach:
        farthest = _out_of_reach(ranked, int(order[np.argmax(~maybe)]))
    findable = (_findable(ranked, order[maybe], targets, problem, s.camera.baseline_m)
                if checks.detectable_only else np.ones(len(ranked.ratings.positions), bool))
    for i in order[maybe]:
        if tried >= q.ik_candidates or standless >= MAX_STANDLESS:
            break
        target = targets[int(ranked.target[i])]
        position = ranked.ratings.positions[i]
        if any(np.linalg.norm(position - p) < REJECTED_RADIUS_M for p in rejected):
            continue  # next to a candidate that failed: try somewhere else
        model = target_model(target)  # the point the camera aims at, as the rating rates it
        if not findable[i]:
            undetectable += 1  # too far or too oblique for the hole detector
            continue  # (in either stereo image: sightings need both)
        if corners is not None and not sees_site(position, model.position, corners,
                                                 math.radians(s.camera.fovy_deg),
                                                 s.camera.near_m, s.camera.far_m):
            out_of_frame += 1  # the insertion it is to measure would not be in focus and
            continue  # in frame
        if s.robots.move_base:
            planner, reachable = scouting.stands(planner, model.position, position)
            if not reachable:
                out_of_reach += 1  # from no place the base gets to does the arm reach it
                if farthest is None or ranked.ratings.total[i] > farthest["rating"]:
                    farthest = _out_of_reach(ranked, int(i))
                continue
        start = belief.qpos.copy()

        tried += 1
        rejected.append(position)
        with world.timer("ik"):
            plan = planner.plan(robot, model.position, position)
        if plan.reason is not None:
            planner, plan = scouting.plan(planner, plan, model.position, position, start)
        why = plan.reason
        if why == "no place to stand":
            tried -= 1
            standless += 1
        if why is None and q.check_sight and blocked_rays(
                world.nominal, belief, robot, target_points(model)):
            why = "occluded"
            world.scene.set_robot(belief, robot, start)
        if why is not None:
            rejections[why] += 1
            if plan.ik is not None and plan.reason is not None and len(unreachable) < 5:
                unreachable.append({
                    "position": position.round(4).tolist(), "why": plan.reason,
                    "position_error_m": round(plan.ik.position_error_m, 5),
                    "orientation_error_deg": round(plan.ik.orientation_error_deg, 4),
                    "validity_checks": plan.checks})
            continue
        commanded_pose = camera_pose(belief, robot.camera)
        world.recorder.chosen(robot.name, position, model.position, target.name)
        world.recorder.hulls(robot.name, ranked.hulls[target.name])
        world.recorder.planned_path(robot.name, plan.path[:, :2],
                                    planner.camera_path(robot, plan.path))
        motion, correction = move(world, robot, plan.path, corrector, prior_sd)
        return Placement(robot, index, step, reason, target, position, commanded_pose,
                         camera_pose(world.data, robot.camera), ranked.ratings.terms(int(i)),
                         plan.ik, motion, correction, plan=plan, candidates_tried=tried,
                         undetectable=undetectable, site_unseen=out_of_frame,
                         out_of_reach=out_of_reach, farthest=farthest, trips=scouting.trips,
                         rejections=dict(rejections), unreachable=unreachable, **counts)
    return Placement(robot, index, step, reason, candidates_tried=tried,
                     undetectable=undetectable, site_unseen=out_of_frame,
                     out_of_reach=out_of_reach, farthest=farthest, trips=scouting.trips,
                     rejections=dict(rejections), unreachable=unreachable, **counts)


def _planner(world: World, corridor: KeepOutBoxes | None, kind: str) -> ArmPlanner:
    """A planner for the world's robots in the planner's world ``kind``
    (``search.planner_world``), as the maps now are."""
    s = world.scenario
    q = s.search
    return ArmPlanner(world.scene, world.belief, q.clearance_m,
                      q.clearance_m + s.motion.ik_margin_m, s.robots.move_base,
                      drive_m=q.drive_path_m, room=world.room, arm=world.arm,
                      checks=q.planning_checks, rng=world.rng, keep_out=corridor,
                      places=world.places, **world.planner_maps(kind))


def _out_of_reach(ranked: RatingField, i: int) -> dict[str, Any]:
    """A candidate the arm cannot reach, as a refusal names it."""
    position = ranked.ratings.positions[i]
    return {"rating": float(ranked.ratings.total[i]), "position": position.round(3).tolist(),
            "height_m": round(float(position[2]), 3)}
