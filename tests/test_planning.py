"""The move planner (sim/world/planning.py): goals by IK, paths by OMPL around the
clutter, in MuJoCo's nominal world."""

from __future__ import annotations

import numpy as np
import pytest

from sim.config.scenario import ScenarioError, load_scenario, parse_scenario
from sim.world.collision import Proximity
from sim.world.motion import dense_path
from sim.world.planning import ArmPlanner
from sim.world.scene import build_scene

CLEARANCE_M = 0.03
WALL_HALF_Y = 0.9  # m: the wall's half length across the robot's way


def scene_with(obstacles: list[dict], robot_x: float = -2.2):
    """One robot at (robot_x, 0) facing the work-piece at the origin, and ``obstacles``."""
    return build_scene(parse_scenario({
        "robots": {"count": 1, "bases": [{"x": robot_x, "y": 0.0, "yaw_deg": 0.0}]},
        "obstacles": obstacles, "search": {"clearance_m": CLEARANCE_M}}))


def wall_scene():
    """A tall wall across the straight way from the robot to the work-piece."""
    return scene_with([{"shape": "box", "position": [-1.3, 0.0, 0.8],
                        "size": [0.05, WALL_HALF_Y, 0.8]}])


def planner(scene, seed: int = 3, checks: int = 20000) -> ArmPlanner:
    return ArmPlanner(scene, scene.make_data(), CLEARANCE_M, CLEARANCE_M + 0.02, drive_m=2.0,
                      checks=checks, rng=np.random.default_rng(seed))


def clear_along(scene, robot, path: np.ndarray) -> bool:
    """Every point of the path, densely, keeps the clearance (checked afresh)."""
    data = scene.make_data()
    near = Proximity(scene.model, robot, scene.robots)
    for joints in dense_path(path, 0.005, 0.005):
        scene.set_robot(data, robot, _full(scene, robot, joints))
        c = near.measure(data)
        if c.own <= 0 or c.others < CLEARANCE_M - 1e-6:
            return False
    return True


def _full(scene, robot, joints: np.ndarray) -> np.ndarray:
    q = scene.start_qpos.copy()
    q[robot.qpos_adr] = joints
    return q


GOAL = np.array([-0.8, 0.0, 1.1])  # beyond the wall, 1.0 m from the primary hole


def test_a_base_drives_around_a_wall_to_reach_a_view():
    scene = wall_scene()
    robot = scene.robots[0]
    p = planner(scene)
    plan = p.plan(robot, scene.primary.position, GOAL)
    assert plan.reason is None, plan.summary()
    assert len(plan.path) >= 3  # not the straight way: that crosses the wall
    # the base went past the wall's end, and the path keeps its clearance throughout
    assert np.abs(plan.path[:, 1]).max() > WALL_HALF_Y
    assert clear_along(scene, robot, plan.path)
    # the camera ends where it was sent
    data = scene.make_data()
    scene.set_robot(data, robot, _full(scene, robot, plan.path[-1]))
    assert np.linalg.norm(data.site(robot.optical_site).xpos - GOAL) < 1e-3
    # and the straight way was indeed blocked
    straight = np.array([plan.path[0], plan.path[-1]])
    assert not clear_along(scene, robot, straight)


def test_the_same_seed_plans_the_same_path():
    scene = wall_scene()
    robot = scene.robots[0]
    a = planner(scene, seed=11).plan(robot, scene.primary.position, GOAL)
    b = planner(scene, seed=11).plan(robot, scene.primary.position, GOAL)
    assert a.reason is None and b.reason is None
    assert np.array_equal(a.path, b.path) and a.checks == b.checks


def test_an_enclosed_goal_is_reported_unreachable_with_the_reason():
    # a pen of tall walls around the work-piece: the robot can stand inside it (a goal
    # exists) but cannot get in
    half, walls = 1.3, []
    for x, y, sx, sy in ((half, 0, 0.05, half + 0.05), (-half, 0, 0.05, half + 0.05),
                         (0, half, half + 0.05, 0.05), (0, -half, half + 0.05, 0.05)):
        walls.append({"shape": "box", "position": [x, y, 1.0], "size": [sx, sy, 1.0]})
    scene = scene_with(walls)
    robot = scene.robots[0]
    p = planner(scene, checks=3000)
    before = p.belief.qpos.copy()
    plan = p.plan(robot, scene.primary.position, GOAL)
    assert plan.reason == "no path within the budget", plan.summary()
    assert plan.checks >= 3000 and len(plan.path) == 0
    assert np.array_equal(p.belief.qpos, before)  # the commanded configuration stays


@pytest.mark.parametrize("goal", [np.array([-0.4, 0.0, 3.0])])
def test_a_goal_out_of_reach_has_no_goal_configuration(goal):
    scene = wall_scene()
    plan = planner(scene).plan(scene.robots[0], scene.primary.position, goal)
    assert plan.reason == "no goal configuration" and not plan.ik.converged
    assert plan.ik.position_error_m > 1.0


def test_the_retired_reach_key_names_its_successor(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[search]\nreach_m = 1.0\n")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    text = str(caught.value)
    assert "search.reach_m" in text and "search.drive_m" in text and "\n" not in text
