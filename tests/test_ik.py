"""mink IK on the camera frame: reach, limits, unreachable targets, other robots untouched."""

from __future__ import annotations

import numpy as np
import pytest

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.world.ik import camera_errors, solve_camera_pose
from taskcam.sim.world.scene import build_scene


@pytest.fixture(scope="module")
def scene():
    return build_scene(load_scenario())


def _within_limits(scene, qpos):
    m = scene.model
    limited = m.jnt_limited.astype(bool)
    q = qpos[m.jnt_qposadr[limited]]
    lo, hi = m.jnt_range[limited].T
    return np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)


@pytest.mark.parametrize("offset", [(-0.5, 0.0, 0.4), (-0.3, -0.4, 0.5), (0.0, -0.8, 0.3),
                                    (-0.6, 0.3, 0.2)])
def test_reaches_a_look_at_pose_within_1mm_and_01deg(scene, offset):
    target = scene.primary.position
    goal = target + np.array(offset)
    robot = scene.robots[0]
    result = solve_camera_pose(scene.model, scene.start_qpos, robot, target, goal)
    assert result.converged
    data = scene.make_data(result.qpos)
    pos_err, ang_err = camera_errors(scene.model, data, robot.optical_site, goal, target)
    assert pos_err < 1e-3 and ang_err < 0.1
    # the named camera, not just the site, is where it was asked to be
    assert np.linalg.norm(data.camera(robot.camera).xpos - goal) < 1e-3
    assert _within_limits(scene, result.qpos)
    others = np.setdiff1d(np.arange(scene.model.nq), robot.qpos_adr)
    assert np.array_equal(result.qpos[others], scene.start_qpos[others])
    # the position error falls at every step, and the path it took stays in the limits
    assert len(result.errors) == result.iterations + 1
    assert np.all(np.diff(result.errors[:, 0]) < 0)
    assert result.errors[-1, 1] < 0.1 and result.errors[0, 1] > result.errors[-1, 1]
    for joints in result.path:
        q = scene.start_qpos.copy()
        q[robot.qpos_adr] = joints
        assert _within_limits(scene, q)


def test_gaze_only_with_the_base_frozen(scene):
    robot = scene.robots[1]
    look = scene.primary.position + np.array([0.3, 0.2, 0.0])
    result = solve_camera_pose(scene.model, scene.start_qpos, robot, look, move_base=False)
    assert result.converged and result.orientation_error_deg < 0.1
    base = robot.qpos_adr[:3]
    assert np.array_equal(result.qpos[base], scene.start_qpos[base])


def test_unreachable_target_is_reported_with_its_residual(scene):
    robot = scene.robots[0]
    target = scene.primary.position
    too_high = target + np.array([0.0, 0.0, 3.0])
    result = solve_camera_pose(scene.model, scene.start_qpos, robot, target, too_high)
    assert not result.converged
    assert result.position_error_m > 0.5
    assert _within_limits(scene, result.qpos)
    far = np.array([-1.9 + 4.0, -0.5, 1.0])  # beyond arm reach with the base frozen
    result = solve_camera_pose(scene.model, scene.start_qpos, robot, target, far,
                               move_base=False)
    assert not result.converged and result.position_error_m > 1.0
