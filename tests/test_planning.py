"""The move planner (sim/world/planning.py): goals by IK, paths by OMPL around the
clutter, in MuJoCo's nominal world."""

from __future__ import annotations

import numpy as np
import pytest

from taskcam.placement import travel_weighed
from taskcam.placement.rating import Ratings
from taskcam.placement.search import RatingField
from taskcam.sim.config.scenario import ScenarioError, load_scenario, parse_scenario
from taskcam.sim.world.collision import KeepOutBoxes, Proximity
from taskcam.sim.world.motion import dense_path
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.scene import build_scene

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
    return ArmPlanner(scene, scene.make_data(), CLEARANCE_M, CLEARANCE_M + 0.02, drive_m=4.0,
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
    # a pen of tall walls around the work-piece: a base could stand inside it, but no
    # place inside is connected to where the robot stands
    half, walls = 1.3, []
    for x, y, sx, sy in ((half, 0, 0.05, half + 0.05), (-half, 0, 0.05, half + 0.05),
                         (0, half, half + 0.05, 0.05), (0, -half, half + 0.05, 0.05)):
        walls.append({"shape": "box", "position": [x, y, 1.0], "size": [sx, sy, 1.0]})
    scene = scene_with(walls)
    robot = scene.robots[0]
    p = planner(scene)
    before = p.belief.qpos.copy()
    plan = p.plan(robot, scene.primary.position, GOAL)
    assert plan.reason == "no place to stand", plan.summary()
    assert len(plan.path) == 0 and plan.ik is None  # refused before any IK
    assert np.array_equal(p.belief.qpos, before)  # the commanded configuration stays
    # the places the base can get to are all outside the pen
    places = p.places(robot).xy
    assert len(places) > 0 and np.all(np.abs(places).max(axis=1) > half)


def test_a_path_not_found_within_the_budget_says_so():
    scene = wall_scene()  # the way round the wall takes a search: 200 checks do not do
    p = planner(scene, checks=200)
    before = p.belief.qpos.copy()
    plan = p.plan(scene.robots[0], scene.primary.position, GOAL)
    assert plan.reason == "no path within the budget", plan.summary()
    assert plan.checks >= 200 and len(plan.path) == 0
    assert np.array_equal(p.belief.qpos, before)


@pytest.mark.parametrize("goal", [np.array([-0.4, 0.0, 3.0])])
def test_a_goal_out_of_the_arms_reach_is_refused_before_any_ik(goal):
    scene = wall_scene()
    p = planner(scene)
    assert goal[2] > p.arm.reach.cells.z_low + p.arm.reach.cells.n_z * p.arm.reach.cells.z_step
    plan = p.plan(scene.robots[0], scene.primary.position, goal)
    assert plan.reason == "no place to stand" and plan.ik is None


@pytest.mark.parametrize("key", ["reach_m", "drive_m"])
def test_the_retired_drive_keys_name_their_successor(tmp_path, key):
    path = tmp_path / "s.toml"
    path.write_text(f"[search]\n{key} = 1.0\n")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    text = str(caught.value)
    assert f"search.{key}" in text and "search.drive_path_m" in text and "\n" not in text


def test_travel_weighing_prefers_what_the_base_drives_less_to():
    positions = np.array([[3.0, 0.0, 1.0], [1.5, 0.0, 1.0], [0.5, 0.0, 1.0]])
    ones = np.ones(3)
    field = RatingField(Ratings(positions, ones, ones, ones, ones, ones,
                                np.array([1.0, 0.9, 0.5])), np.zeros(3, int))
    assert list(field.ranked()) == [0, 1, 2]  # by rating alone
    # drives beyond the arm's 1 m: 2.0, 0.5, 0 m; at 1/m: 0.135, 0.546, 0.5
    weighed = travel_weighed(field, np.zeros(2), 1.0, reach_m=1.0)
    assert list(weighed.ranked()) == [1, 2, 0]
    assert np.array_equal(weighed.ratings.total, field.ratings.total)  # terms unchanged


def test_the_keep_out_distance_is_the_distance_to_the_nearest_box():
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    boxes = KeepOutBoxes(np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]), np.stack([np.eye(3), turn]),
                    np.array([[1.0, 0.5, 0.5], [1.0, 0.5, 0.5]]))
    points = np.array([[0.5, 0.2, 0.0],   # inside the first
                       [2.0, 0.0, 0.0],   # 1 m beyond the first's end along x
                       [5.0, 2.0, 0.0],   # the second is turned: its long side along y
                       [0.0, 1.5, 1.5]])  # off the first's edge: (1, 1) away
    assert boxes.distance(points) == pytest.approx([0.0, 1.0, 1.0, np.sqrt(2.0)])


def test_a_robot_keeps_out_of_the_insertion_corridor():
    scene = wall_scene()
    robot = scene.robots[0]
    free = planner(scene)
    plan = free.plan(robot, scene.primary.position, GOAL)
    assert plan.reason is None
    # a keep-out box around where the free plan put the camera refuses the candidate
    box = KeepOutBoxes(GOAL[None], np.eye(3)[None], np.full((1, 3), 0.1))
    kept = ArmPlanner(scene, scene.make_data(), CLEARANCE_M, CLEARANCE_M + 0.02, drive_m=4.0,
                      rng=np.random.default_rng(3), keep_out=box)
    assert kept.plan(robot, scene.primary.position, GOAL).reason is not None


def test_the_corridor_holds_the_panel_where_it_lies_above_its_slot_and_in_it():
    from taskcam.sim.config.stages import TaskConfig
    from taskcam.sim.stages.corridor import carry_corridor

    scene = build_scene(parse_scenario({}))
    data = scene.make_data()
    cfg = TaskConfig(approach_m=0.15, carry_error_m=0.01)
    corridor = carry_corridor(scene.model, data, cfg)
    panel = data.geom("panel/panel").xpos.copy()  # its centre, where it lies
    slot = data.site("workpiece/slot").xpos
    up = panel - data.body("panel/panel").xpos  # bottom edge to centre
    inside = np.array([panel, slot + up, slot + up + [0, 0, cfg.approach_m]])
    assert np.all(corridor.distance(inside) == 0.0)
    # the boxes are the panel's (10 mm thick) grown by 3 cm: 35 mm from its centre
    # across its face, nothing beyond (the carry runs along the panel's plane here)
    across = data.geom("panel/panel").xmat.reshape(3, 3)[:, 0]
    assert corridor.distance((slot + up + 0.03 * across)[None])[0] == 0.0
    assert corridor.distance((slot + up + 0.05 * across)[None])[0] == pytest.approx(0.015,
                                                                                 abs=1e-6)
