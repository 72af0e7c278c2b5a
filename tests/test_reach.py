"""The arm's reach (placement/reach.py, sim/world/arm.py): the chain's forward kinematics
against MuJoCo's, the capability map against mink's IK, inverse reachability against a
search of base poses by IK, the cache, and the drives over the floor."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from taskcam.mapping import drive_lengths
from taskcam.placement.reach import ReachCells, build_reach_map
from taskcam.sim.config.scenario import parse_scenario
from taskcam.sim.world.arm import (
    SelfClear,
    arm_key,
    camera_chain,
    load_reach_map,
    save_reach_map,
    scene_arm,
)
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.scene import build_scene
from taskcam.sim.world.standing import Places

ROOT = Path(__file__).resolve().parent.parent
ARMS = {"taskcam": "taskcam", "ur5e": "menagerie:universal_robots_ur5e",
        "compact": str(ROOT / "models" / "arms" / "compact_arm.xml")}


def scene_of(model: str, **robots: object):
    return build_scene(parse_scenario({"robots": {"count": 1, "model": model, **robots}}))


@pytest.mark.parametrize("arm", ARMS)
def test_the_chain_puts_the_camera_where_mujoco_does(arm):
    import mujoco
    scene = scene_of(ARMS[arm])
    robot = scene.robots[0]
    chain = camera_chain(scene.model, robot)
    rng = np.random.default_rng(5)
    angles = rng.uniform(chain.lower, chain.upper, (40, 6))
    positions, rotations = chain.forward(angles)
    data = scene.make_data()
    for q, p, r in zip(angles, positions, rotations, strict=True):
        data.qpos[robot.qpos_adr] = (0.0, 0.0, 0.0, *q)
        mujoco.mj_kinematics(scene.model, data)
        site = data.site(robot.optical_site)
        assert np.abs(site.xpos - p).max() < 1e-9
        assert np.abs(site.xmat.reshape(3, 3) - r).max() < 1e-9


def test_a_baseline_moves_the_left_camera_along_the_head():
    scene = scene_of("taskcam")
    robot = scene.robots[0]
    angles = np.zeros((1, 6))
    at = {b: camera_chain(scene.model, robot, b).forward(angles) for b in (0.08, 0.16)}
    offset = at[0.08][0][0] - at[0.16][0][0]
    assert math.isclose(float(np.linalg.norm(offset)), 0.04, abs_tol=1e-9)
    assert abs(float(offset @ at[0.08][1][0][:, 0])) == pytest.approx(0.04)  # along x


def random_poses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera positions in a cylinder round the base (1.2 m, 0-2 m high) and directions
    uniform on the sphere."""
    r, a = 1.2 * np.sqrt(rng.random(n)), rng.uniform(-math.pi, math.pi, n)
    positions = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.0, 2.0, n)])
    directions = rng.normal(size=(n, 3))
    return positions, directions / np.linalg.norm(directions, axis=1, keepdims=True)


@pytest.mark.slow
def test_the_capability_map_agrees_with_ik():
    """At least 95 % of the poses the map calls reachable are solved by IK (from the
    map's seeds), and at most 5 % of the poses IK solves (from home and random seeds,
    clear of itself) are called unreachable."""
    scene = scene_of("taskcam")
    robot, arm = scene.robots[0], scene_arm(scene)
    rng = np.random.default_rng(11)
    positions, directions = random_poses(rng, 4000)
    called = arm.reach.reachable(positions, directions)
    base = scene.start_qpos.copy()
    base[robot.qpos_adr[:3]] = 0.0

    clear = SelfClear(scene, robot)  # the map leaves out what collides with itself

    def solved(p: np.ndarray, d: np.ndarray, seeds: list[np.ndarray]) -> bool:
        for joints in seeds:
            q = base.copy()
            q[robot.qpos_adr[3:]] = joints
            ik = solve_camera_pose(scene.model, q, robot, p + d, p, move_base=False)
            if ik.converged and clear(ik.qpos[robot.qpos_adr[3:]]):
                return True
        return False

    chosen = np.flatnonzero(called)[:300]
    hits = sum(solved(positions[i], directions[i], list(arm.reach.seeds(
        positions[i], directions[i], 6)[0])) for i in chosen)
    assert hits >= 0.95 * len(chosen), (hits, len(chosen))

    home = scene.start_qpos[robot.qpos_adr[3:]]
    ik_solved = [i for i in range(400) if solved(positions[i], directions[i], [
        home, *rng.uniform(-math.pi, math.pi, (2, 6))])]
    missed = sum(not called[i] for i in ik_solved)
    assert len(ik_solved) >= 60 and missed <= 0.05 * len(ik_solved), (missed, len(ik_solved))


@pytest.mark.slow
def test_inverse_reachability_matches_a_search_of_base_poses_by_ik():
    """For a camera pose, the base places the map says stand within reach are those
    from which IK (the base held at the place, every yaw of a fine set tried) puts the
    camera there: they agree on at least 90 % of the places round it."""
    scene = scene_of("taskcam")
    robot, arm = scene.robots[0], scene_arm(scene)
    camera, look_at = np.array([0.0, 0.0, 1.0]), np.array([0.3, 0.2, 0.5])
    direction = (look_at - camera) / np.linalg.norm(look_at - camera)
    steps = np.arange(-1.2, 1.21, 0.3)
    places = np.array([(x, y) for x in steps for y in steps])
    ok, yaws, joints = arm.reach.stands(camera, direction, places)
    home = scene.start_qpos[robot.qpos_adr[3:]]
    agree = 0
    for place, says, yaw, seed in zip(places, ok, yaws, joints, strict=True):
        found = False
        for turn in ([yaw] if says else []) + list(np.arange(8) * math.pi / 4):
            q = scene.start_qpos.copy()
            q[robot.qpos_adr] = (*place, turn, *(seed if says else home))
            ik = solve_camera_pose(scene.model, q, robot, look_at, camera, move_base=False)
            if ik.converged:
                found = True
                break
        agree += found == bool(says)
    assert ok.sum() >= 5 and (~ok).sum() >= 5  # both kinds of place are in the test
    assert agree >= 0.9 * len(places), (agree, len(places))


def test_a_small_map_is_seeded_and_round_trips_through_its_file(tmp_path):
    scene = scene_of("taskcam")
    robot = scene.robots[0]
    chain = camera_chain(scene.model, robot)
    cells = ReachCells()
    a, b = (build_reach_map(chain, lambda q: True, np.random.default_rng(3), 20000, cells,
                            batch=5000) for _ in range(2))
    assert np.array_equal(a.keys, b.keys) and np.array_equal(a.joints, b.joints)
    # every cell's seed puts the camera in that cell
    pos, rot = chain.forward(a.joints.astype(float))
    r, bearing = np.hypot(pos[:, 0], pos[:, 1]), np.arctan2(pos[:, 1], pos[:, 0])
    assert np.array_equal(cells.keys(r, pos[:, 2], -rot[:, :, 2], bearing), a.keys)
    path = tmp_path / "map.npz"
    save_reach_map(path, a)
    c = load_reach_map(path)
    assert c is not None and c.cells == a.cells and np.array_equal(c.keys, a.keys)
    assert np.array_equal(c.joints, a.joints) and not list(tmp_path.glob("*.tmp"))
    path.write_bytes(path.read_bytes()[:100])  # cut short: built again, not read
    assert load_reach_map(path) is None


def test_the_maps_key_follows_the_arm_not_the_scene():
    a = scene_of("taskcam")
    b = build_scene(parse_scenario({"robots": {"count": 2}, "camera": {"baseline_m": 0.08},
                                    "obstacles": [{"shape": "sphere", "position": [1, 1, 1],
                                                   "size": [0.1]}]}))
    c = scene_of(ARMS["compact"])
    home = a.start_qpos[a.robots[0].qpos_adr[3:]]
    key = {n: arm_key(s.model, s.robots[0], home, ReachCells(), 100) for n, s in
           (("a", a), ("b", b), ("c", c))}
    assert key["a"] == key["b"] != key["c"]
    assert arm_key(a.model, a.robots[0], home + 0.1, ReachCells(), 100) != key["a"]


def test_each_arm_reaches_as_far_as_its_links_allow():
    """The map's reach, against the arm's own lengths: the compact arm's about 0.64 m of
    links reach less far than the UR5e's 0.85 m; neither beyond the links' sum plus the
    mount's and head's offsets."""
    reach = {n: scene_arm(scene_of(m)).reach_m for n, m in ARMS.items() if n != "ur5e"}
    assert 0.95 <= reach["taskcam"] <= 1.2
    assert 0.6 <= reach["compact"] < reach["taskcam"] - 0.15


def test_drives_are_the_shortest_ways_round_what_blocks():
    clear = np.ones((6, 6), bool)
    clear[2, :5] = False  # a wall with a gap at the end
    drive = drive_lengths(clear, (0, 0), 0.1, 10.0)
    # by hand: along row 0-1 to column 5, through the gap, back along row 3
    assert drive[1, 5] == pytest.approx(0.1 * (4 + math.sqrt(2)))
    assert drive[3, 0] == pytest.approx(drive[3, 5] + 0.5)
    assert np.isinf(drive[2, 0])  # the wall itself
    # no corner cut: (1, 4) to (2, 5) to (3, 4) is a diagonal each, both beside a wall
    assert drive[3, 4] == pytest.approx(drive[2, 5] + 0.2)
    # a limit leaves what lies beyond it unreached
    assert np.isinf(drive_lengths(clear, (0, 0), 0.1, 0.5)[3, 0])


def test_a_place_is_reached_on_a_cell_got_to_or_beside_one():
    """Places.reached against its definition, point by point: the cell the base is in,
    or the next one up in x, in y or both, is one it gets to (inside the raster)."""
    rng = np.random.default_rng(3)
    drive = np.where(rng.random((7, 5)) < 0.3, 1.0, np.inf)
    places = Places(np.array([-0.3, 0.2]), 0.1, drive)
    for xy in rng.uniform([-0.6, -0.1], [0.6, 0.8], (2000, 2)):
        i, j = (math.floor(v) for v in (xy - places.origin) / places.cell_m)
        near = [drive[a, b] for a in (i, i + 1) for b in (j, j + 1)
                if 0 <= a < drive.shape[0] and 0 <= b < drive.shape[1]]
        assert places.reached(xy) == any(np.isfinite(near))
