"""Views from which the hole detector can find a target: the limit function by hand, and
against the detector on rendered, defocused stereo views."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

# isort: split
import mujoco
from scipy.spatial.transform import Rotation

from taskcam.calibration.target_frame import projected_disk, sight
from taskcam.mapping import opencv_pose
from taskcam.placement import CameraModel, DetectorLimits, TargetModel, detectable
from taskcam.placement.detectability import focal_px, projected_radius, worst_partner
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.world.optics import Lens, defocus
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene

CAMERA = CameraModel(fov=math.radians(60.0), pixels=480, near=0.35, far=1.5)
F = 240 / math.tan(math.radians(30.0))  # 415.69 px
TARGET = TargetModel("hole", np.array([0.1, -0.2, 0.5]), np.array([0.0, 0.0, 1.0]), 0.02)


def at(angle_deg: float, distance: float, target: TargetModel = TARGET,
       azimuth_deg: float = 0.0) -> np.ndarray:
    """A camera position ``distance`` from the target, ``angle_deg`` off its normal
    (+z here), toward ``azimuth_deg`` from +x."""
    a, b = math.radians(angle_deg), math.radians(azimuth_deg)
    return target.position + distance * np.array(
        [math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])


def test_focal_length_and_projected_radius_by_hand():
    assert focal_px(CAMERA) == pytest.approx(415.692, abs=1e-3)
    positions = np.array([at(0, 1.0), at(60, 0.5, azimuth_deg=30), at(0, 2.0)])
    radius, angle = projected_radius(positions, TARGET, CAMERA)
    # straight above: f r / d; 60 deg off: halved by cos 60 (at half the distance)
    assert radius == pytest.approx([F * 0.02 / 1.0, F * 0.02 * 0.5 / 0.5, F * 0.02 / 2.0])
    assert np.degrees(angle) == pytest.approx([0.0, 60.0, 0.0], abs=1e-9)


def test_the_limits_hold_at_their_boundaries():
    limits = DetectorLimits(min_radius_px=2.0, max_off_normal_deg=60.0)
    edge = F * 0.02 / 2.0  # the distance straight above at which the radius is 2 px
    positions = np.array([
        at(0, edge * 0.999),  # just over the smallest radius
        at(0, edge * 1.001),  # just under it
        at(59.99, 1.0),  # just inside the angle (radius 4.2 px)
        at(60.01, 1.0),  # just outside it
        at(45, edge * math.cos(math.radians(45)) * 0.999),  # foreshortened to just over 2 px
        at(45, edge * math.cos(math.radians(45)) * 1.001),  # ... and just under
    ])
    assert detectable(positions, TARGET, CAMERA, limits).tolist() == [
        True, False, True, False, True, False]


def test_behind_the_plate_at_the_target_and_any_orientation():
    limits = DetectorLimits(1.0, 70.0)
    behind = TARGET.position - np.array([0.0, 0.0, 0.5])
    assert not detectable(np.array([behind, TARGET.position]), TARGET, CAMERA, limits).any()
    # the same geometry about a tilted, unnormalised normal gives the same verdicts
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    tilted = TargetModel("t", np.array([1.0, 2.0, 0.3]), 5.0 * R[:, 2], 0.02)
    views = [(0, 0.5), (65, 0.8), (75, 0.8), (0, 9.0)]
    plain = np.array([at(a, d) for a, d in views])
    turned = tilted.position + (plain - TARGET.position) @ R.T
    expected = [True, True, False, False]  # 9 m: 0.92 px
    assert detectable(plain, TARGET, CAMERA, limits).tolist() == expected
    assert detectable(turned, tilted, CAMERA, limits).tolist() == expected


def test_the_stereo_partner_at_its_worst_roll():
    b, d = 0.12, 0.5
    positions = np.array([at(0, d), at(40, d, azimuth_deg=70)])
    partner = worst_partner(positions, TARGET, b)
    for p, q, angle in zip(positions, partner, (0.0, 40.0), strict=True):
        assert np.linalg.norm(q - p) == pytest.approx(b)
        assert (q - p) @ (TARGET.position - p) == pytest.approx(0.0, abs=1e-12)  # across
        seen = q - TARGET.position
        off = math.degrees(math.acos(seen[2] / np.linalg.norm(seen)))
        assert off == pytest.approx(angle + math.degrees(math.atan(b / d)))
    # straight above, 13.5 deg for the partner: refused only when the pair must see it
    limits = DetectorLimits(1.0, 10.0)
    assert detectable(positions[:1], TARGET, CAMERA, limits).tolist() == [True]
    assert detectable(positions[:1], TARGET, CAMERA, limits, baseline_m=b).tolist() == [False]


def test_limits_are_validated_and_the_defaults_are_no_looser_than_measured():
    with pytest.raises(ValueError, match="min_radius_px"):
        DetectorLimits(min_radius_px=0.0)
    with pytest.raises(ValueError, match="max_off_normal_deg"):
        DetectorLimits(max_off_normal_deg=90.0)
    results = Path(__file__).resolve().parent.parent / "bench" / "results"
    measured = json.loads((results / "detector_limits.json").read_text())["measured"]
    limits = DetectorLimits()
    assert limits.min_radius_px >= measured["min_radius_px"]
    assert limits.max_off_normal_deg <= measured["max_off_normal_deg"]


# ---------------------------------------------------------------- rendered views


@pytest.fixture(scope="module")
def probe():
    """The default scene at 320 x 240 without obstacles, its one robot under the floor."""
    s = load_scenario()
    s = dataclasses.replace(
        s, obstacles=(), robots=dataclasses.replace(s.robots, count=1, bases=s.robots.bases[:1]),
        camera=dataclasses.replace(s.camera, width=320, height=240, samples=0))
    scene = build_scene(s)
    scene.model.body_pos[scene.model.body("r1/base").id, 2] = -3.0
    with Renderer(scene.model, 320, 240) as renderer:
        yield scene, scene.make_data(), renderer


def _look(scene, data, renderer, position: np.ndarray):
    """Put the stereo pair's left camera at ``position`` looking at the primary hole (its
    baseline level); returns the defocused left and right images and both positions."""
    model, robot, target = scene.model, scene.robots[0], scene.primary
    forward = target.position - position
    forward /= np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    x = np.cross(forward, up)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(x, forward), -forward])  # MuJoCo: -z forward
    right = position + scene.scenario.camera.baseline_m * x
    for camera, where in ((robot.camera, position), (robot.right_camera, right)):
        cam = model.camera(camera).id
        body = model.cam_bodyid[cam]
        Rb = data.xmat[body].reshape(3, 3)
        model.cam_pos[cam] = Rb.T @ (where - data.xpos[body])
        model.cam_quat[cam] = Rotation.from_matrix(Rb.T @ R).as_quat(scalar_first=True)
    mujoco.mj_forward(model, data)
    c = scene.scenario.camera
    lens = Lens(c.near_m, c.far_m, c.coc_px)
    images = [defocus(*renderer.rgb_and_depth(data, cam), lens)
              for cam in (robot.camera, robot.right_camera)]
    return images, np.array([position, right])


@pytest.mark.parametrize(("angle", "distance", "inside"), [
    (30.0, 0.8, True),  # clearly inside
    (67.0, 0.6, True),  # just inside the angle (both cameras, 2.7 px)
    (0.0, 3.2, True),  # just inside the radius: 1.3 px straight above
    (88.0, 0.5, False),  # far beyond the angle
    (0.0, 16.0, False),  # far below the radius: 0.26 px
])
def test_the_detector_agrees_with_the_limits(probe, angle, distance, inside):
    scene, data, renderer = probe
    target = scene.primary
    model_target = TargetModel(target.name, target.position, target.normal, target.radius)
    c = scene.scenario.camera
    camera = CameraModel(math.radians(c.fovy_deg), c.height, c.near_m, c.far_m)
    (left, right), cameras = _look(scene, data, renderer,
                                   at(angle, distance, model_target, azimuth_deg=-90.0))
    assert detectable(cameras, model_target, camera).tolist() == [inside, inside]
    robot = scene.robots[0]
    T = camera_pose(data, robot.camera)
    pinhole = camera_pinhole(scene.model, robot.camera)
    centre = projected_disk(target, opencv_pose(T), pinhole)[0]  # type: ignore[index]
    found = sight(robot.name, left, right, target, T, pinhole, c.baseline_m,
                  position_sd_m=0.0, rotation_sd_deg=0.0)  # the pose is exact
    error = None if found is None else math.hypot(*(np.array(found.pixel) - centre))
    if inside:
        assert error is not None and error < 1.0
    else:
        assert error is None or error > 1.0
