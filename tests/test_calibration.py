"""Hole detection by LoG and template matching, on drawn and on rendered images."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taskcam.calibration import detect_holes, disk_template, locate_hole, log_response, to_gray
from taskcam.calibration.target_frame import projected_disk
from taskcam.mapping import Pinhole, opencv_pose, world_to_camera
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.scene import TargetConfig
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import HOLE_LIFT, build_scene


def _disk_image(u: float, v: float, r: float, shape=(240, 320), noise: float = 0.0,
                seed: int = 0) -> np.ndarray:
    img = np.full(shape, 190, np.uint8)
    cv2.circle(img, (round(u * 256), round(v * 256)), round(r * 256), 15, -1,
               lineType=cv2.LINE_AA, shift=8)
    if noise:
        rng = np.random.default_rng(seed)
        img = np.clip(img + rng.normal(0, noise, shape), 0, 255).astype(np.uint8)
    return img


@settings(max_examples=30, deadline=None)
@given(st.floats(60, 260), st.floats(60, 180), st.floats(4, 20))
def test_subpixel_centre_of_a_drawn_disk(u, v, r):
    found = detect_holes(_disk_image(u, v, r), r)
    assert found, "no detection"
    assert math.hypot(found[0].u - u, found[0].v - v) < 0.25


def test_several_disks_and_noise():
    img = _disk_image(80, 60, 10, noise=8.0)
    cv2.circle(img, (240, 170), 10, 15, -1, lineType=cv2.LINE_AA)
    found = detect_holes(img, 10)
    centres = sorted((round(d.u), round(d.v)) for d in found[:2])
    assert centres == [(80, 60), (240, 170)]
    assert all(d.score > 0.8 for d in found[:2])


def test_log_is_positive_on_dark_blobs_and_template_is_dark_inside():
    gray = to_gray(_disk_image(100, 100, 8))
    response = log_response(gray, 8 / math.sqrt(2))
    assert response[100, 100] > 0 and response[100, 100] == response.max()
    t = disk_template(5.0)
    c = t.shape[0] // 2
    assert t[c, c] == 0.0 and t[0, 0] == 1.0


def test_locate_hole_ignores_far_detections():
    img = _disk_image(80, 60, 10)
    assert locate_hole(img, (82, 61), 10, search_px=10) is not None
    assert locate_hole(img, (250, 200), 10, search_px=10) is None


def test_rendered_target_found_where_the_camera_model_projects_it():
    """World point -> pixel by the pinhole model; the image detection must agree."""
    scene = build_scene(load_scenario())
    robot, target = scene.robots[0], scene.primary
    goal = target.position + np.array([-0.35, -0.1, 0.45])
    ik = solve_camera_pose(scene.model, scene.start_qpos, robot, target.position, goal)
    data = scene.make_data(ik.qpos)
    pinhole: Pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as renderer:
        rgb = renderer.rgb(data, robot.camera)
    in_cam = world_to_camera(opencv_pose(camera_pose(data, robot.camera)), target.position[None])
    expected = pinhole.project(in_cam)[0]
    radius_px = pinhole.fy * target.radius / in_cam[0, 2]
    disk = projected_disk(target, opencv_pose(camera_pose(data, robot.camera)), pinhole)
    assert disk is not None and np.allclose(disk[0], expected)
    found = locate_hole(rgb, tuple(expected), radius_px, search_px=3 * radius_px, shape=disk[1])
    assert found is not None
    assert math.hypot(found.u - expected[0], found.v - expected[1]) < 0.5
    assert found.score > 0.7
    secondary = next(t for t in scene.targets if t.role == "secondary")
    other = pinhole.project(world_to_camera(opencv_pose(camera_pose(data, robot.camera)),
                                            secondary.position[None]))[0]
    assert math.hypot(found.u - other[0], found.v - other[1]) > 2 * radius_px


def test_an_oblique_hole_is_found_by_its_ellipse():
    """A circle seen obliquely is an ellipse; the shaped template finds its centre."""
    u, v, a, b, angle = 160.37, 118.81, 14.0, 5.0, 30.0
    img = np.full((240, 320), 190, np.uint8)
    cv2.ellipse(img, (round(u * 256), round(v * 256)), (round(a * 256), round(b * 256)),
                angle, 0, 360, 15, -1, lineType=cv2.LINE_AA, shift=8)
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    shape = np.array([[c, -s], [s, c]]) @ np.diag([a, b])  # unit circle -> rim offsets
    template = disk_template(0.0, shape=shape)
    centre = template.shape[0] // 2
    assert template[centre, centre] == 0.0 and template[0, 0] == 1.0
    assert template[centre + 6, centre + 10] == 0.0  # 12 px along the major axis: inside
    assert template[centre + 6, centre - 4] == 1.0  # 7 px along the minor axis: outside
    found = locate_hole(img, (u + 3, v - 2), math.sqrt(a * b), search_px=10, shape=shape)
    assert found is not None and math.hypot(found.u - u, found.v - v) < 0.25


def test_a_hole_on_a_fixture_is_found_where_the_camera_model_projects_it():
    """A secondary target on a fixture of its own (a post beside the table carrying a
    small steel plate): the scene puts its hole at the fixture's top, and a rendered
    view finds it there, as it finds the plate's."""
    base = load_scenario()
    far = TargetConfig("far", "secondary", (-0.65, -0.45), 0.02, 0.001, "fixture", 0.75)
    s = dataclasses.replace(base, workpiece=dataclasses.replace(
        base.workpiece, targets=(*base.workpiece.targets, far)))
    scene = build_scene(s)
    target = next(t for t in scene.targets if t.name == "far")
    assert np.allclose(target.position, [-0.65, -0.45, 0.75 + HOLE_LIFT])
    robot = scene.robots[0]
    goal = target.position + np.array([-0.35, -0.1, 0.45])
    ik = solve_camera_pose(scene.model, scene.start_qpos, robot, target.position, goal)
    data = scene.make_data(ik.qpos)
    # the fixture's top is flush with the hole's face, its post stands on the floor
    top = scene.model.geom("workpiece/fixture_far")
    assert data.geom_xpos[top.id][2] + top.size[2] == pytest.approx(0.75)
    post = scene.model.geom("workpiece/fixture_far_post")
    assert data.geom_xpos[post.id][2] - post.size[2] == pytest.approx(0.0)
    pinhole: Pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as renderer:
        rgb = renderer.rgb(data, robot.camera)
    pose = opencv_pose(camera_pose(data, robot.camera))
    disk = projected_disk(target, pose, pinhole)
    assert disk is not None
    in_cam = world_to_camera(pose, target.position[None])
    radius_px = pinhole.fy * target.radius / in_cam[0, 2]
    found = locate_hole(rgb, tuple(disk[0]), radius_px, search_px=3 * radius_px, shape=disk[1])
    assert found is not None and found.score > 0.7
    assert math.hypot(found.u - disk[0][0], found.v - disk[0][1]) < 0.5


def test_a_fixture_below_what_it_stands_on_is_refused():
    base = load_scenario()
    low = TargetConfig("low", "secondary", (0.1, -0.1), 0.02, 0.001, "fixture", 0.53)
    s = dataclasses.replace(base, workpiece=dataclasses.replace(
        base.workpiece, targets=(*base.workpiece.targets, low)))
    with pytest.raises(ScenarioError, match="height_m"):
        build_scene(s)
