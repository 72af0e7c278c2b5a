"""Arms that really move: planned paths, physics, positioning errors, many robots."""

from __future__ import annotations

import copy
import math

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

from taskcam.sim.config.scenario import load_scenario, parse_scenario
from taskcam.sim.config.stages import MotionConfig
from taskcam.sim.stages.scene_record import SceneGeometry, body_path, geom_path
from taskcam.sim.world.motion import ARM_MOUNT, ErrorModel, MoveError, Mover
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.scene import build_scene

CLEARANCE_M = 0.03


def random_scene(rng: np.random.Generator):
    """Two robots on opposite sides at random, 0-2 random boxes near the work-piece."""
    a = rng.uniform(0, 2 * np.pi)
    angles = [a, a + rng.uniform(0.6 * np.pi, 1.4 * np.pi)]
    bases = []
    for angle in angles:
        r = rng.uniform(1.6, 2.0)
        bases.append({"x": r * math.cos(angle), "y": r * math.sin(angle),
                      "yaw_deg": math.degrees(angle + math.pi)})
    obstacles = []
    for _ in range(rng.integers(0, 3)):
        angle, r = rng.uniform(0, 2 * np.pi), rng.uniform(0.55, 0.8)
        obstacles.append({"shape": "box", "position": [r * math.cos(angle), r * math.sin(angle),
                                                       rng.uniform(0.3, 1.0)],
                          "size": rng.uniform(0.04, 0.12, 3).tolist(),
                          "yaw_deg": rng.uniform(0, 90)})
    return build_scene(parse_scenario({"robots": {"count": 2, "bases": bases},
                                       "obstacles": obstacles,
                                       "search": {"clearance_m": CLEARANCE_M}}))


def camera_goal(rng: np.random.Generator, scene, robot) -> np.ndarray:
    """A camera position 0.5-0.9 m from the target, on the robot's side of it."""
    target = scene.primary.position
    base = scene.start_qpos[robot.qpos_adr[:2]]
    azimuth = math.atan2(base[1] - target[1], base[0] - target[0]) + rng.uniform(-0.7, 0.7)
    elevation, d = rng.uniform(0.5, 1.2), rng.uniform(0.5, 0.9)
    return target + d * np.array([math.cos(azimuth) * math.cos(elevation),
                                  math.sin(azimuth) * math.cos(elevation), math.sin(elevation)])


def within_limits(model, joints: np.ndarray, adr: np.ndarray) -> bool:
    """Are a robot's joint values (k, 9), at qpos addresses ``adr``, in their ranges?"""
    ids = [int(np.flatnonzero(model.jnt_qposadr == a)[0]) for a in adr]
    lo, hi = model.jnt_range[ids].T
    limited = model.jnt_limited[ids].astype(bool)
    inside = (joints >= lo - 1e-6) & (joints <= hi + 1e-6)
    return bool(np.all(inside[..., limited]))


@pytest.mark.slow
def test_100_random_two_robot_scenes_move_without_collision():
    rng = np.random.default_rng(2024)
    moved = refused = 0
    for _ in range(100):
        scene = random_scene(rng)
        world, belief = copy.deepcopy(scene.model), scene.make_data()
        data = scene.make_data()
        mover = Mover(world, data, scene.robots, MotionConfig(settle_s=0.5))
        planner = ArmPlanner(scene, belief, CLEARANCE_M, CLEARANCE_M + 0.02, drive_m=1.0,
                             checks=5000, rng=rng)
        for robot in scene.robots:  # robot by robot: the first is in the second's way
            plan = planner.plan(robot, scene.primary.position, camera_goal(rng, scene, robot))
            if plan.reason is not None:
                refused += 1
                assert plan.reason in ("no place to stand", "no goal configuration",
                                       "no path within the budget", "no path within the drive")
                continue
            assert within_limits(scene.model, plan.path, robot.qpos_adr)
            result = mover.follow(robot, plan.path, MoveError(np.zeros(9), (0.0, 0.0)))
            moved += 1
            assert result.contact_steps == 0
            assert result.closest.others >= CLEARANCE_M - 2e-3, result.closest
            assert result.closest.own > 0.0
            assert within_limits(world, np.array([q for _, q in result.samples]),
                                 robot.qpos_adr)
            # and it ends where it was sent
            assert np.abs(data.qpos[robot.qpos_adr] - plan.path[-1]).max() < 2e-3
    assert moved >= 120, (moved, refused)  # most random goals are reachable


def test_a_refused_plan_leaves_the_commanded_configuration_alone():
    scene = build_scene(load_scenario())
    belief = scene.make_data()
    planner = ArmPlanner(scene, belief, CLEARANCE_M, CLEARANCE_M + 0.02, move_base=False)
    robot = scene.robots[0]
    before = belief.qpos.copy()
    plan = planner.plan(robot, scene.primary.position,
                        scene.primary.position + np.array([0.0, 0.0, 3.0]))
    assert plan.reason == "no goal configuration" and not plan.ik.converged
    assert plan.ik.position_error_m > 1.0  # the residual is reported
    assert np.array_equal(belief.qpos, before)


@pytest.fixture(scope="module")
def default_scene():
    return build_scene(load_scenario())


def _moves(scene, cfg: MotionConfig, count: int, seed: int = 7):
    """``count`` short moves of robot r1 with errors drawn by ``cfg``: per move the
    world's joints minus the commanded, and the arm mount's tilt (roll, pitch)."""
    rng = np.random.default_rng(seed)
    world, data = copy.deepcopy(scene.model), scene.make_data()
    robot = scene.robots[0]
    mover = Mover(world, data, scene.robots, cfg)
    errors = ErrorModel(cfg, scene.robots, rng)
    home = scene.start_qpos[robot.qpos_adr]
    joint_errors, tilts = [], []
    mount = world.body(f"{robot.name}/{ARM_MOUNT}").id
    nominal = Rotation.from_quat(scene.model.body_quat[mount], scalar_first=True)
    for _ in range(count):
        goal = home + rng.uniform(-0.05, 0.05, 9)
        mover.follow(robot, np.vstack([data.qpos[robot.qpos_adr], goal]), errors.draw(robot))
        joint_errors.append(data.qpos[robot.qpos_adr] - goal)
        tilt = Rotation.from_quat(world.body_quat[mount], scalar_first=True) * nominal.inv()
        tilts.append(tilt.as_euler("xyz")[:2])
    return np.array(joint_errors), np.array(tilts), errors.offsets[robot.name]


@pytest.mark.slow
def test_achieved_minus_commanded_matches_the_configured_errors(default_scene):
    cfg = MotionConfig(settle_s=1.5, joint_offset_deg=0.5, joint_noise_deg=0.1,
                       base_offset_m=0.02, base_yaw_deg=0.8, suspension_deg=1.0)
    n = 150
    errors, tilts, offsets = _moves(default_scene, cfg, n)
    # within 4 standard errors of the sample standard deviation (sigma / sqrt(2n))
    band = 4 / math.sqrt(2 * n)
    assert errors[:, :2].std(axis=0) == pytest.approx([0.02, 0.02], rel=band)
    assert errors[:, 2].std() == pytest.approx(math.radians(0.8), rel=band)
    arm = errors[:, 3:]
    noise = math.radians(0.1)
    assert arm.std(axis=0) == pytest.approx(np.full(6, noise), rel=band)
    # the constant offsets are the arm's mean error, to within the noise's standard error
    assert np.abs(arm.mean(axis=0) - offsets).max() < 4 * noise / math.sqrt(n)
    assert tilts.std(axis=0) == pytest.approx([math.radians(1.0)] * 2, rel=band)
    # the camera ends up off its commanded pose by the error, not by the controller
    perfect, _, _ = _moves(default_scene, MotionConfig(settle_s=1.5), 10)
    assert np.abs(perfect).max() < 1e-3


@pytest.mark.slow
def test_the_world_moves_on_the_simulated_timeline(default_run):
    """The recording replays the episode: every drawn geom of the scene is in it, and
    every moving body (the robots' links, the panel) has poses over ``sim_time``."""
    out, summary = default_run
    model = build_scene(load_scenario()).model
    drawn = SceneGeometry.of(model)
    times: dict[str, set[int]] = {}
    for chunk in RrdReader(out / "run.rrd").store().stream():
        if "sim_time" in chunk.timeline_names:
            batch = chunk.to_record_batch()
            times.setdefault(str(chunk.entity_path), set()).update(
                batch.column("sim_time").cast(pa.int64()).to_pylist())
    paths = set(RrdReader(out / "run.rrd").store().schema().entity_paths())
    for g in drawn.geoms:
        assert f"/{geom_path(model, g)}" in paths, model.geom(g).name
    for b in drawn.moving:
        assert len(times.get(f"/{body_path(model, b)}", ())) > 10, model.body(b).name
    for r in summary["robots"]:
        assert r["placed"] and r["motion"]["duration_s"] > 0
