"""Rendering: metric depth and the pinhole model agree with ray casting in the scene."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mapping import camera_to_world, opencv_pose, world_to_camera
from sim import Renderer, build_scene, camera_pinhole, camera_pose, load_scenario
from sim.gl import resolve_gl_backend


@pytest.fixture(scope="module")
def rendered():
    scene = build_scene(load_scenario())
    data = scene.make_data()
    camera = scene.robots[0].camera
    pinhole = camera_pinhole(scene.model, camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        depth = r.depth(data, camera)
        rgb = r.rgb(data, camera)
        seg = r.segmentation(data, camera)
    return scene, data, camera, pinhole, depth, rgb, seg


def test_world_point_to_pixel_to_world_within_1mm(rendered):
    """Cast a ray through pixels with mj_ray: the hit point projects back to the pixel,
    and unprojecting the rendered depth at that pixel returns the hit point."""
    scene, data, camera, pinhole, depth, _, _ = rendered
    T = opencv_pose(camera_pose(data, camera))
    rng = np.random.default_rng(0)
    geomid = np.zeros(1, np.int32)
    checked = 0
    for u, v in zip(rng.integers(0, pinhole.width, 60), rng.integers(0, pinhole.height, 60),
                    strict=True):
        ray_cam = np.array([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy, 1.0])
        direction = T[:3, :3] @ ray_cam
        direction /= np.linalg.norm(direction)
        dist = mujoco.mj_ray(scene.model, data, T[:3, 3], direction, np.array([1, 1, 1, 0, 0, 0],
                             np.uint8), 1, -1, geomid)
        if geomid[0] < 0:
            continue
        world = T[:3, 3] + dist * direction
        pixel = pinhole.project(world_to_camera(T, world[None]))[0]
        assert np.allclose(pixel, [u, v], atol=1e-6)
        back = camera_to_world(T, ray_cam * depth[v, u])
        assert np.linalg.norm(back - world) < 1e-3, (u, v, np.linalg.norm(back - world))
        checked += 1
    assert checked > 40


def test_images_have_the_scenario_size_and_content(rendered):
    scene, _, _, pinhole, depth, rgb, seg = rendered
    assert rgb.shape == (pinhole.height, pinhole.width, 3) and rgb.dtype == np.uint8
    assert depth.shape == (pinhole.height, pinhole.width) and depth.dtype == np.float32
    assert np.all(depth[np.isfinite(depth)] > 0)
    assert rgb.std() > 10  # not a blank frame
    table = scene.model.geom("workpiece/table").id
    assert (seg == table).any()


def test_renderer_is_closed_after_use(rendered):
    scene, data, camera, pinhole, *_ = rendered
    r = Renderer(scene.model, pinhole.width, pinhole.height)
    r.close()
    with pytest.raises(RuntimeError, match="closed"):
        r.rgb(data, camera)


def test_gl_backend_respects_an_explicit_choice():
    env = {"MUJOCO_GL": "osmesa"}
    assert resolve_gl_backend(env) == "osmesa"
    assert resolve_gl_backend(dict()) in ("egl", "osmesa")


def test_colour_and_depth_from_one_render_equal_two_renders():
    """Without multisampling, colour and depth read from one shaded render are, to the
    bit, what a colour render and a depth render give: for views of the scene, of the
    sky (the sky box lies beyond the farthest geometry) and from below the floor (two
    renders then: a render does not show a plane's back)."""
    s = load_scenario()
    scene = build_scene(dataclasses.replace(s, camera=dataclasses.replace(s.camera, samples=0)))
    model, data = scene.model, scene.make_data()
    camera = scene.robots[0].camera
    cam = model.camera(camera).id
    pinhole = camera_pinhole(model, camera)
    rng = np.random.default_rng(0)
    skies = below = 0
    with Renderer(model, pinhole.width, pinhole.height) as r:
        for k in range(24):
            model.cam_pos[cam] = rng.uniform(-1.5, 1.5, 3)
            model.cam_quat[cam] = Rotation.random(random_state=k).as_quat(scalar_first=True)
            mujoco.mj_forward(model, data)
            rgb, depth = r.rgb_and_depth(data, camera)
            assert np.array_equal(rgb, r.rgb(data, camera))
            assert np.array_equal(depth, r.depth(data, camera))
            skies += bool(np.isinf(depth).any())
            below += bool(data.cam_xpos[cam][2] < 0)
    assert skies >= 5 and below >= 3
