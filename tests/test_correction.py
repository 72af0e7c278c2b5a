"""Pose correction from natural fiducials on rendered images: stereo keypoints
against the renderer's depth, the whole corrector through a rendered move whose joints
err, and the episode's reported errors against the simulator's truth."""

from __future__ import annotations

import contextlib
import dataclasses
import math

import mujoco
import numpy as np
import pytest
from rerun.chunk import RrdReader

from taskcam.calibration.pose import rotation_deg
from taskcam.calibration.stereo_features import FeatureFinder
from taskcam.calibration.tracker_settings import TrackerSettings
from taskcam.calibration.tracking import Frame
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.stages.corrector import PoseCorrector
from taskcam.sim.stages.placement_result import pose_error
from taskcam.sim.stages.world import new_grid
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene

TARGET_M, TARGET_DEG = 0.003, 0.2


@pytest.fixture(scope="module")
def scene():
    return build_scene(load_scenario())


def test_stereo_keypoints_agree_with_the_rendered_depth(scene):
    robot = scene.robots[0]
    data = scene.make_data()
    pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        left, right = r.rgb(data, robot.camera), r.rgb(data, robot.right_camera)
        depth = r.depth(data, robot.camera)
        seen = r.segmentation(data, robot.camera)
    own = (seen >= 0) & scene.robot_geoms()[np.maximum(seen, 0)]
    found = FeatureFinder(TrackerSettings()).stereo(left, right, own)
    assert len(found) >= 100  # the painted surfaces give plenty of natural fiducials
    u, v = np.rint(found.z[:, 0]).astype(int), np.rint(found.z[:, 1]).astype(int)
    expected = pinhole.fx * load_scenario().camera.baseline_m / depth[v, u]
    flat = np.array([np.ptp(depth[max(b - 2, 0):b + 3, max(a - 2, 0):a + 3]) < 0.01
                     for a, b in zip(u, v, strict=True)])  # away from depth edges
    error = np.abs(found.z[flat, 2] - expected[flat])
    assert np.median(error) < 0.3
    assert np.mean(error < 1.0) > 0.9
    assert not own[v, u].any()  # nothing on the robots' own bodies


def _kinematic_move(corrector, scene, belief, world, robot, start, goal, erred_from, erred_to,
                    known=None):
    """Move ``robot`` from ``start`` to ``goal`` (commanded joints) without physics, the
    world's joints off the commanded by ``erred_from`` at the start turning into
    ``erred_to`` at the goal; the corrector sees the rendered frames and the commanded
    joints, and starts from ``known`` (believed pose, sd) if given. The correction."""
    corrector.begin(robot, np.array([start, goal]), known)
    sample = corrector.on_sample(robot)
    for k, tau in enumerate(np.linspace(0, 1, 150)):
        progress = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
        commanded = start + (goal - start) * progress
        world.qpos[robot.qpos_adr] = commanded + erred_from + tau * (erred_to - erred_from)
        mujoco.mj_forward(scene.model, world)
        sample(0.04 * k, commanded)
    belief.qpos[robot.qpos_adr] = goal
    mujoco.mj_forward(scene.model, belief)
    return corrector.finish(robot)


def _goal(scene, robot, qpos, offset):
    target = scene.primary.position
    return solve_camera_pose(scene.model, qpos, robot, target, target + offset).qpos[
        robot.qpos_adr]


@contextlib.contextmanager
def _resting_corrector(scene, correction, goal_yaw_deg=0.0):
    """A corrector begun at the first robot's resting pose, the move's goal its base
    turned by ``goal_yaw_deg``; yields it and ``turned(yaw_deg)``: the camera pose (as
    the joints put it) with the base turned so far, the arm as it was."""
    s = load_scenario()
    robot = scene.robots[0]
    belief, world = scene.make_data(), scene.make_data()
    joints = belief.qpos[robot.qpos_adr].copy()
    pinhole = camera_pinhole(scene.model, robot.camera)

    def turned_joints(yaw_deg: float) -> np.ndarray:
        q = joints.copy()
        q[2] += math.radians(yaw_deg)
        return q

    with Renderer(scene.model, pinhole.width, pinhole.height) as renderer:
        corrector = PoseCorrector(scene, belief, world, renderer, pinhole,
                                  s.camera.baseline_m, new_grid(s), correction)
        corrector.begin(robot, np.array([joints, turned_joints(goal_yaw_deg)]))
        yield corrector, lambda yaw_deg: corrector.nominal_pose(robot, turned_joints(yaw_deg))


def test_a_lost_track_takes_a_frame_only_where_it_expects_to_be_located_again(scene):
    """After a frame that was not located: at the fixed step, a frame where the prediction
    expects at least ``min_inliers`` of the last located frame's fiducials (the camera
    still facing them), none where it turned away from them (it knows nothing there)."""
    with _resting_corrector(scene, load_scenario().correction) as (corrector, turned):
        tracker = corrector._tracker
        assert tracker is not None and len(tracker.frames[0].observations) >= 100
        tracker.frames.append(Frame(tracker.frames[0].g01, {}, located=False))
        assert not corrector._due(turned(0.0))  # not the fixed step yet
        assert corrector._due(turned(4.0)) == "track"  # a step on, still facing them
        assert not corrector._due(turned(120.0))  # turned away: none of them in view
        settings = corrector.settings
        corrector.settings = dataclasses.replace(settings, min_inliers=10_000)
        assert not corrector._due(turned(4.0))  # too few to be located, however many


@pytest.mark.parametrize("frames", ["overlap", "track"])
def test_only_the_overlap_rule_adds_views_near_the_goal(scene, frames):
    """A fixed step on, the view still sharing most of its fiducials with the last
    frame's and the goal's: ``frames = "overlap"`` takes a frame there (the estimate's
    fiducials are measured from many views), ``"track"`` does not; turned away from
    them, both do (the track needs one)."""
    correction = dataclasses.replace(load_scenario().correction, frames=frames)
    with _resting_corrector(scene, correction, goal_yaw_deg=5.0) as (corrector, turned):
        tracker = corrector._tracker
        assert tracker is not None
        size = (corrector.pinhole.width, corrector.pinhole.height)
        near = turned(4.0)
        assert tracker.overlap(corrector._predict(near), size) >= correction.frame_overlap
        assert corrector._due(near) == ("goal view" if frames == "overlap" else "")
        far = turned(60.0)
        assert tracker.overlap(corrector._predict(far), size) < correction.frame_overlap
        assert corrector._due(far) == "track"


@pytest.mark.slow
def test_corrector_recovers_a_camera_whose_joints_erred_along_a_rendered_move(scene):
    """Kinematic move (no physics): the world's joints drift from the commanded ones by
    up to 0.8 degrees each and the base by 3 cm (the issue's case: at least 2 cm and 1
    degree); the corrector sees only the rendered frames and the commanded joints. A
    second move starts where the first left the camera, its error still there: started
    from the first correction it holds the accuracy again; started from where the
    joints say (as if no error had been made) it is off by that error."""
    s = load_scenario()
    robot = scene.robots[0]
    belief = scene.make_data()
    world = scene.make_data()
    start = belief.qpos[robot.qpos_adr].copy()
    goal = _goal(scene, robot, scene.start_qpos, np.array([-0.55, -0.25, 0.55]))
    offset = np.zeros(len(start))
    offset[:2] = [0.025, -0.02]  # base x, y (m)
    offset[3:] = np.radians([0.8, -0.6, 0.7, -0.8, 0.6, 0.5])  # arm joints
    second = offset.copy()
    second[:2], second[2] = [0.01, 0.02], math.radians(0.5)  # new odometry errors
    pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as renderer:
        corrector = PoseCorrector(scene, belief, world, renderer, pinhole,
                                  s.camera.baseline_m, new_grid(s), s.correction)
        result = _kinematic_move(corrector, scene, belief, world, robot, start, goal,
                                 np.zeros(len(start)), offset)
        truth = camera_pose(world, robot.camera)
        before = pose_error(camera_pose(belief, robot.camera), truth)
        assert before["position_m"] > 0.02 and before["orientation_deg"] > 1.0
        assert result.pose is not None, result.reason
        after = pose_error(result.pose, truth)
        assert after["position_m"] < TARGET_M and after["orientation_deg"] < TARGET_DEG, after
        assert result.status == "corrected" and result.start_sd == (0.0, 0.0)
        assert result.estimate is not None and result.estimate.count >= 8
        assert result.located >= 0.8 * result.frames
        _assert_frames_accounted(result.summary())
        assert all(f.covariance.shape == (3, 3) and len(f.track) >= 2 for f in result.used)

        goal2 = _goal(scene, robot, belief.qpos, np.array([-0.35, -0.5, 0.5]))
        outcomes = {}
        for known in ((result.pose, result.sd), None):
            world.qpos[robot.qpos_adr] = goal + offset
            belief.qpos[robot.qpos_adr] = goal
            mujoco.mj_forward(scene.model, belief)
            again = _kinematic_move(corrector, scene, belief, world, robot, goal, goal2,
                                    offset, second, known)
            outcomes[known is None] = (again, None if again.pose is None else pose_error(
                again.pose, camera_pose(world, robot.camera)))
    again, error = outcomes[False]
    assert error is not None, again.reason
    assert error["position_m"] < TARGET_M and error["orientation_deg"] < TARGET_DEG, error
    assert again.status == "corrected" and again.start_sd == result.sd
    assert again.sd[0] >= result.sd[0]  # the start's uncertainty is carried
    _, blind = outcomes[True]  # the first move's error unseen: lost, or that far off
    assert blind is None or blind["position_m"] > 0.01


def _assert_frames_accounted(c: dict) -> None:
    """A correction's frames by kind: one first frame, a final one per try at the goal,
    every frame counted once (a wider search tracks the final frame again, taking none),
    their time a share of the move's render, feature and tracking time."""
    kinds = c["frames_by_kind"]
    assert kinds["first"]["count"] == 1 and kinds["final"]["count"] >= 1
    assert set(kinds) <= {"first", "track", "goal view", "final", "wider search"}
    taken = sum(k["count"] for name, k in kinds.items() if name != "wider search")
    assert taken == c["frames"]
    parts = c["timings_s"]
    framing = parts["render"] + parts["features"] + parts["track"]
    assert 0.5 * framing < sum(k["time_s"] for k in kinds.values()) <= 1.05 * framing


def test_rotation_between_poses_by_hand():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = np.array([[math.cos(0.1), -math.sin(0.1), 0], [math.sin(0.1), math.cos(0.1), 0],
                          [0, 0, 1]])
    assert rotation_deg(a, b) == pytest.approx(math.degrees(0.1))
    assert rotation_deg(b, b) == 0.0


@pytest.mark.slow
def test_episode_reports_the_correction_against_the_truth(default_run):
    out, summary = default_run
    for robot in summary["robots"]:
        c = robot["correction"]
        before, after = c["error_before"], c["error_after"]
        assert before["position_m"] > 0.01 or before["orientation_deg"] > 0.5
        assert after["position_m"] < TARGET_M and after["orientation_deg"] < TARGET_DEG, c
        assert c["estimator"] == "sqpnp" and c["fiducials"] >= 8
        assert len(c["used"]) == c["fiducials"]
        assert robot["estimated_pose"]["position"] != robot["commanded_pose"]["position"]
        assert set(c["other_estimators_error"]) <= {"linear", "kabsch"}
        assert c["frames_located"] >= 0.8 * c["frames"]
        _assert_frames_accounted(c)
    paths = set(RrdReader(out / "run.rrd").store().schema().entity_paths())
    for name in ("r1", "r2"):
        assert f"/world/{name}/fiducials" in paths
        assert f"/world/{name}/camera/rgb/found/fiducial_tracks" in paths
        assert f"/world/{name}/corrected_camera" in paths


@pytest.mark.slow
def test_targets_are_triangulated_into_a_common_frame(default_run):
    _, summary = default_run
    frame = summary["target_frame"]
    primary = frame["targets"]["wide"]  # the default scenario's primary hole
    assert primary["error_m"] < 0.01
    assert frame["frame"] is not None
    z = np.array(frame["frame"]["z_axis"])
    x = np.array(frame["frame"]["x_axis"])
    assert abs(x @ z) < 1e-6 and np.linalg.norm(x) == pytest.approx(1.0)
    for robot in summary["robots"]:
        for seen in robot["sightings"]:
            assert seen["disparity_px"] > 0 and seen["error_m"] < 0.02
