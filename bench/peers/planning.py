"""How many of the views the rating function wants a robot can get to: the planner
(sim/world/planning.py: IK goal from stand-off seeds, OMPL path for base and arm) against
IK-as-path (the earlier planner: mink's collision-avoiding IK from where the
robot stands, its iterates the path, checked densely) on the same candidates.

Run from the repository root: ``python -m bench.peers.planning`` (``--scenes N`` per density,
default 8; ``--top K`` candidates, default 25). Scenes are Table 1's
(scenarios/table1.toml's sweep: its seeds, densities 5 / 20 / 35 %, its generated
obstacles), mapped by the episode's mapping stage. For the first robot, the rating
function's candidates over the map (with the primary target, as optimal placement
rates them) are taken best first, skipping those from which the detector cannot find
the target, those with no clear place for the base within the arm's reach and those
within 8 cm of one tried (as placement skips them), until K
(Table 1's ``ik_candidates``, 25) with a place for the base to stand were tried, as
placement counts them (those without are passed over, at most 500). Each is planned
from where mapping left the robot, by both planners, in the same nominal world with
the same clearance; a candidate is reached when the planner returns a path (the
planner's paths are clear by construction; IK-as-path's path is checked at 1 cm /
0.01 rad as before). Both are given the same candidates, from the same region
(``search.drive_path_m`` and the arm's reach). ``--world`` sets the planner's world
(``search.planner_world``: Table 1's "model" by default; "map" plans around what the
robots mapped, never-observed space blocked), IK-as-path's being the scene as it is.

Prints per density the candidates reached (all, and those with a place to stand),
the share of those nearer than 0.9 m to the target that are reached, the planning
time per candidate (median and 95th percentile) for both, and the reasons the planner
refused; writes bench/results/planning.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from typing import Any

import mujoco
import numpy as np

from bench.common import SCENARIOS, print_table, write_results
from taskcam.placement import detectable
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments.runner import trial_specs
from taskcam.sim.experiments.trial import trial_scenario
from taskcam.sim.stages.exploration import explore
from taskcam.sim.stages.place import MAX_STANDLESS, REJECTED_RADIUS_M, ranked_field
from taskcam.sim.stages.rating_problem import RatingProblem, target_model
from taskcam.sim.stages.timer import Timer
from taskcam.sim.stages.world import build_world
from taskcam.sim.world.base_scanner import scan_into
from taskcam.sim.world.collision import Proximity
from taskcam.sim.world.ik import IKSettings, solve_camera_pose
from taskcam.sim.world.motion import dense_path
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.render import Renderer
from taskcam.sim.world.scene import Robot, Scene

TABLE1 = SCENARIOS / "table1.toml"


def ik_as_path(scene: Scene, belief: mujoco.MjData, robot: Robot, look_at: np.ndarray,
               position: np.ndarray, clearance_m: float, margin_m: float) -> bool:
    """The earlier planner: collision-avoiding IK from the commanded
    configuration, its iterates the path, every point of it (1 cm / 0.01 rad apart)
    keeping the clearance. True if it reaches the candidate."""
    near = Proximity(scene.model, robot, scene.robots)
    ik = solve_camera_pose(scene.model, belief.qpos.copy(), robot, look_at, position, True,
                           IKSettings(), near.avoid, margin_m)
    if not ik.converged:
        return False
    data = mujoco.MjData(scene.model)
    data.qpos[:] = belief.qpos
    for joints in dense_path(ik.path):
        data.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(scene.model, data)
        c = near.measure(data)
        if c.own <= 0.0 or c.others < clearance_m:
            return False
    return True


def scene_rows(spec: Any, top: int, world_kind: str) -> list[dict[str, Any]]:
    """One scene: map it, rank the first robot's candidates, plan the top ``top`` both
    ways, ours in the planner's world ``world_kind`` (``search.planner_world``); one
    record per candidate."""
    scenario, clutter = trial_scenario(spec)
    world = build_world(scenario, Timer())
    with Renderer(world.model, world.pinhole.width, world.pinhole.height) as renderer:
        explore(world, renderer)
    world.hold()
    scan_into(world.floor, world.model, world.data, world.belief, world.scene.robots,
              world.scene.robot_geoms())
    problem = RatingProblem(world.grid, scenario)
    robot, target = world.scene.robots[0], world.scene.primary
    ranked = ranked_field(world, problem, robot, (target,), [], "rating")
    q = scenario.search
    margin = q.clearance_m + scenario.motion.ik_margin_m
    planner = ArmPlanner(world.scene, world.belief, q.clearance_m, margin, True,
                         drive_m=q.drive_path_m, room=world.room, arm=world.arm,
                         checks=q.planning_checks, rng=world.rng,
                         **world.planner_maps(world_kind))
    start = world.belief.qpos.copy()
    rows: list[dict[str, Any]] = []
    tried: list[np.ndarray] = []
    order = ranked.ranked()
    room = planner.may_stand(robot, ranked.ratings.positions[order])
    for i in order[room]:  # as placement: out of the arm's reach, not tried
        if sum(r["why"] != "no place to stand" for r in rows) >= top or len(rows) >= (
                MAX_STANDLESS + top):
            break
        position = ranked.ratings.positions[i]
        if any(np.linalg.norm(position - p) < REJECTED_RADIUS_M for p in tried):
            continue  # as placement does: next to a candidate tried, try elsewhere
        if not detectable(position[None], target_model(target), problem.camera,
                          baseline_m=scenario.camera.baseline_m)[0]:
            continue
        tried.append(position)
        t0 = time.perf_counter()
        plan = planner.plan(robot, target.position, position)
        ours_s = time.perf_counter() - t0
        world.scene.set_robot(world.belief, robot, start)
        t0 = time.perf_counter()
        peer = ik_as_path(world.scene, world.belief, robot, target.position, position,
                          q.clearance_m, margin)
        peer_s = time.perf_counter() - t0
        rows.append({"density": spec.density, "achieved": clutter.density, "trial": spec.trial,
                     "distance_m": float(np.linalg.norm(position - target.position)),
                     "ours": plan.reason is None, "why": plan.reason, "checks": plan.checks,
                     "ours_s": ours_s, "peer": peer, "peer_s": peer_s})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8, help="scenes per density")
    parser.add_argument("--top", type=int, default=25,
                        help="candidates per scene (Table 1's ik_candidates)")
    parser.add_argument("--world", choices=("model", "map_seen", "map"),
                        help="the planner's world (default: Table 1's search.planner_world)")
    args = parser.parse_args()
    sweep = load_sweep(TABLE1)
    world_kind = args.world or sweep.scenario.search.planner_world
    specs = trial_specs(sweep)
    started = time.perf_counter()
    records: list[dict[str, Any]] = []
    for density in sweep.config.densities:
        chosen = [s for s in specs if s.density == density][:args.scenes]
        for spec in chosen:
            t0 = time.perf_counter()
            records += scene_rows(spec, args.top, world_kind)
            print(f"density {density:.0%} scene {spec.trial}: {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr, flush=True)
    rows = []
    for density in sweep.config.densities:
        cell = [r for r in records if r["density"] == density]
        if not cell:
            continue
        ours = float(np.mean([r["ours"] for r in cell]))
        peer = float(np.mean([r["peer"] for r in cell]))
        ours_s = [r["ours_s"] for r in cell]
        peer_s = [r["peer_s"] for r in cell]
        near = [r for r in cell if r["distance_m"] < 0.9]
        stand = [r for r in cell if r["why"] != "no place to stand"]
        rows.append({
            "case": f"{density:.0%} density: candidates reached", "density": density,
            "candidates": len(cell), "ours": sum(r["ours"] for r in cell),
            "peer": sum(r["peer"] for r in cell),
            "ratio": None if peer == 0 else round(ours / peer, 2), "unit": "candidates reached",
            "share": {"ours": round(ours, 3), "peer": round(peer, 3)},
            "with_a_place_to_stand": {
                "candidates": len(stand), "ours": sum(r["ours"] for r in stand),
                "peer": sum(r["peer"] for r in stand)},
            "nearer_than_0_9_m": {"candidates": len(near),
                                  "ours": round(float(np.mean([r["ours"] for r in near])), 3)
                                  if near else None,
                                  "peer": round(float(np.mean([r["peer"] for r in near])), 3)
                                  if near else None},
            "seconds_per_candidate": {
                "ours_p50": round(float(np.median(ours_s)), 4),
                "ours_p95": round(float(np.percentile(ours_s, 95)), 4),
                "peer_p50": round(float(np.median(peer_s)), 4),
                "peer_p95": round(float(np.percentile(peer_s, 95)), 4)},
            "refused": dict(Counter(r["why"] for r in cell if not r["ours"]))})
    seconds = time.perf_counter() - started
    print_table(rows)
    for r in rows:
        t = r["seconds_per_candidate"]
        print(f"{r['density']:.0%}: {r['candidates']} candidates; planning s/candidate p50/p95 "
              f"ours {t['ours_p50']}/{t['ours_p95']}, IK-as-path {t['peer_p50']}/{t['peer_p95']}; "
              f"nearer than 0.9 m: {r['nearer_than_0_9_m']}; refused: {r['refused']}")
    print(f"{len(records)} candidates in {seconds:.0f} s")
    name = "planning" if args.world is None else f"planning_{world_kind}"
    path = write_results(name, rows, scenes_per_density=args.scenes, top=args.top,
                         planner_world=world_kind, seconds=round(seconds, 1),
                         candidates=records)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
