"""Placement that knows the arm's reach, in the robots' own map: scenes nobody tuned for
(a far start behind a wall, a work-piece in an enclosure open on one side), a way held
back only by space never observed that the robot looks at and then takes, and the
refusals a robot gives, each from a scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.stages.episode import Episode
from taskcam.sim.stages.exploration import explore
from taskcam.sim.stages.place import place, ranked_field
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.render import Renderer
from taskcam.sim.world.scene import build_scene
from taskcam.sim.world.sensing import DepthSensor

DATA = Path(__file__).resolve().parent / "data" / "reach"
UNCORRECTED = (0.05, 2.0)  # an uncorrected pose's sd (m, deg): placement does not use it


def run(name: str) -> dict:
    summary, _ = Episode(load_scenario(DATA / f"{name}.toml")).run()
    return summary


def first(summary: dict, robot: str) -> dict:
    return next(r for r in summary["robots"] if r["name"] == robot)["placements"][0]


@pytest.mark.slow
def test_a_robot_starting_behind_a_wall_drives_round_it_and_the_task_is_done():
    s = run("far_wall")
    r1 = first(s, "r1")
    assert r1["placed"], r1.get("refused")
    assert r1["path"]["base_path_m"] > 1.0  # from 2.5 m away, round the wall's end
    assert first(s, "r2")["placed"]
    # the whole loop, the pose correction with it (an uncorrected pose is a few cm off)
    success = s["task"]["success"]
    assert success["0.2"] and success["0.1"], success


@pytest.mark.slow
def test_robots_place_at_a_work_piece_enclosed_on_three_sides_and_the_task_is_done():
    s = run("enclosure")
    for name in ("r1", "r2"):
        p = first(s, name)
        assert p["placed"], p.get("refused")
        # every camera looks in through the open side (-x): the walls hide the rest
        assert p["candidate_position"][0] < 0.0
    # the robot beside a closed wall drove round to the open side
    assert first(s, "r2")["path"]["base_path_m"] > 1.0
    success = s["task"]["success"]
    assert success["0.2"] and success["0.1"], success


@pytest.fixture(scope="module")
def mapped():
    """The default scene (placement alone), mapped; its world, renderer and rating."""
    episode = Episode(load_scenario(DATA / "look.toml"))
    world = episode.world
    renderer = Renderer(world.model, world.pinhole.width, world.pinhole.height)
    explore(world, renderer)
    world.hold()
    yield world, renderer, RatingProblem(world.grid, world.scenario)
    renderer.close()


@pytest.mark.slow
def test_a_way_held_back_only_by_space_never_observed_is_looked_at_and_taken(mapped):
    world, renderer, problem = mapped
    robot, targets = world.scene.robots[0], world.scene.targets
    snapshot = world.snapshot()
    ranked = ranked_field(world, problem, robot, targets, [], "rating")
    sensor = DepthSensor(renderer, world.pinhole, "render", world.scenario.camera.baseline_m,
                         world.scene.robot_geoms())
    known = place(world, problem, robot, [], targets, "rating", None, UNCORRECTED,
                  ranked=ranked, sensor=sensor)
    assert known.placed
    # the same world, its map forgetting what lies round the view the robot took
    world = world.restored(snapshot, np.random.default_rng(0), np.random.default_rng(1))
    centres = world.grid.centers()
    near = np.linalg.norm(centres - known.commanded, axis=-1) < 0.6
    world.grid.log_odds[near] = 0  # never observed
    world.grid.log_odds[tuple(world.grid.index(known.commanded[None])[0])] = -100  # its view
    blocked = ArmPlanner(world.scene, world.belief, 0.03, 0.05, arm=world.arm, room=world.room,
                         drive_m=world.scenario.search.drive_path_m,
                         **world.planner_maps("map"))
    assert blocked.plan(robot, known.target.position, known.commanded).reason is not None
    world.scene.set_robot(world.belief, robot, snapshot.qpos)
    looked = place(world, problem, robot, [], targets, "rating", None, UNCORRECTED,
                   ranked=ranked, sensor=sensor)
    assert looked.placed, looked.refused()
    assert looked.trips and sum(t["looks"] for t in looked.trips) >= 1
    # what it looked at is observed again: most of the space forgotten round the view
    assert sum(t["observed"] for t in looked.trips) > 0
    assert (world.grid.log_odds[near] == 0).mean() < 0.5


@pytest.mark.slow
def test_a_robot_asked_for_views_beyond_its_arm_says_so_with_the_best_of_them():
    summary = run("high")
    p = first(summary, "r1")
    assert not p["placed"] and p["candidates_tried"] == 0  # no IK spent on them
    text = p["refused"]
    assert text.startswith("no reachable candidate with a positive rating")
    assert "out of the arm's reach from every place the base gets to" in text
    best = p["search"]["best_out_of_reach"]
    assert best["height_m"] >= 1.4 and f"RF {best['rating']:.3g}" in text


@pytest.mark.slow
def test_a_robot_with_no_known_free_candidate_in_its_region_says_so(mapped):
    world, _, problem = mapped
    robot, targets = world.scene.robots[0], world.scene.targets
    # camera positions taken all over the grid: none left apart from them
    lo, hi = world.grid.origin, world.grid.origin + np.array(world.grid.shape) * 0.05
    taken = [np.array([x, y, z]) for x in np.arange(lo[0], hi[0], 0.3)
             for y in np.arange(lo[1], hi[1], 0.3) for z in np.arange(0.2, 1.9, 0.3)]
    p = place(world, problem, robot, taken, targets, "rating", None, UNCORRECTED)
    assert not p.placed and p.refused() == "no known-free candidate in the robot's region"


def test_a_goal_whose_arm_would_touch_something_has_no_goal_configuration():
    scene = build_scene(load_scenario(DATA / "look.toml"))
    robot = scene.robots[0]
    planner = ArmPlanner(scene, scene.make_data(), 0.03, 0.05, move_base=False)
    # a camera 1 cm above the beam over the work-piece, looking at the primary hole
    beam_top = np.array([0.05, 0.3, 0.85 + 0.01])
    plan = planner.plan(robot, scene.primary.position, beam_top)
    assert plan.reason in ("no goal configuration", "no place to stand"), plan.summary()
    assert plan.ik is None or not plan.ik.converged or plan.reason == "no goal configuration"


def test_a_path_longer_than_the_drive_is_refused_as_such():
    scene = build_scene(load_scenario(DATA / "look.toml"))
    planner = ArmPlanner(scene, scene.make_data(), 0.03, 0.05, drive_m=1.0)
    path = np.zeros((3, 9))
    path[1, :2], path[2, :2] = (0.6, 0.0), (0.6, 0.6)  # 1.2 m of base travel
    assert planner._refused(path) == "no path within the drive"
    path[2, :2] = (0.6, 0.45)  # 1.05 m: within the drive and a cell
    assert planner._refused(path) is None
    assert planner._refused(None) == "no path within the budget"
