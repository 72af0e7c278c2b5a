"""Rendering: metric depth and the pinhole model agree with ray casting in the scene."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.mapping import Pinhole, camera_to_world, opencv_pose, world_to_camera
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.world.gl import resolve_gl_backend
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene


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


def without_multisampling(samples: int = 0
                          ) -> tuple[mujoco.MjModel, mujoco.MjData, str, int, Pinhole]:
    """The default scene without MSAA (or with ``samples``): model, data, the first
    robot's camera, its id and pinhole."""
    s = load_scenario()
    scene = build_scene(dataclasses.replace(s, camera=dataclasses.replace(s.camera,
                                                                          samples=samples)))
    camera = scene.robots[0].camera
    model = scene.model
    return model, scene.make_data(), camera, model.camera(camera).id, camera_pinhole(model,
                                                                                   camera)


def test_colour_and_depth_from_one_render_equal_two_renders():
    """Without multisampling, colour and depth read from one shaded render are, to the
    bit, what a colour render and a depth render give: for views of the scene, of the
    sky (the sky box lies beyond the farthest geometry) and from below the floor (two
    renders then: a render does not show a plane's back)."""
    model, data, camera, cam, pinhole = without_multisampling()
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


@pytest.mark.parametrize("samples", [0, 4])
def test_a_window_renders_as_the_whole_image_does_there(samples):
    """A window of a view, rendered alone through its part of the frustum, is the whole
    render's: depth to float rounding (inf at the same pixels), colour to four grey levels
    where textures are sampled (under one on average; multisampled, a few pixels of its
    border may differ more). The whole image as a window is the whole render, to the
    bit; so is it, multisampled, when colour and depth come from two renders."""
    model, data, camera, cam, pinhole = without_multisampling(samples)
    h, w = pinhole.height, pinhole.width
    rng = np.random.default_rng(1)
    rendered = 0
    with Renderer(model, w, h) as r:
        for k in range(12):
            model.cam_pos[cam] = rng.uniform(-1.5, 1.5, 2).tolist() + [rng.uniform(0.3, 1.5)]
            model.cam_quat[cam] = Rotation.random(random_state=k).as_quat(scalar_first=True)
            mujoco.mj_forward(model, data)
            rgb, depth = r.rgb_and_depth(data, camera)
            if samples:
                assert np.array_equal(rgb, r.rgb(data, camera))
                assert np.array_equal(depth, r.depth(data, camera))
            whole = r.rgb_and_depth(data, camera, (slice(0, h), slice(0, w)))
            assert np.array_equal(whole[0], rgb) and np.array_equal(whole[1], depth)
            r0, c0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
            window = (slice(r0, r0 + rng.integers(8, h // 2)),
                      slice(c0, c0 + rng.integers(8, w // 2)))
            part_rgb, part_depth = r.rgb_and_depth(data, camera, window)
            assert part_rgb.shape == rgb[window].shape and part_depth.shape == depth[window].shape
            seen = np.isfinite(depth[window])
            # the sky box's texture may round differently: only the scene's geometry
            grey = np.where(seen, np.abs(part_rgb.astype(int) - rgb[window]).max(axis=-1), 0)
            inner = grey[1:-1, 1:-1] if samples else grey
            assert inner.max() <= 4 and np.mean(grey) < 1.0
            assert np.sum(grey > 4) <= 4
            assert np.array_equal(np.isfinite(part_depth), seen)
            assert np.allclose(part_depth[seen], depth[window][seen], rtol=1e-4, atol=0)
            rendered += int(seen.mean() > 0.5)
    assert rendered >= 6


def test_a_coarse_segmentation_sees_what_the_whole_one_sees_in_each_block(rendered):
    """At 1/2 and 1/4 of the resolution each value is the geom at its block's centre: one
    of the block's pixels' ids (all but a few along edges), the same geoms seen."""
    scene, data, camera, pinhole, _, _, seg = rendered
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        for k in (2, 4):
            coarse = r.segmentation(data, camera, downscale=k)
            h, w = pinhole.height // k, pinhole.width // k
            assert coarse.shape == (h, w)
            blocks = seg[:h * k, :w * k].reshape(h, k, w, k).transpose(0, 2, 1, 3)
            among = (blocks == coarse[:, :, None, None]).any(axis=(2, 3))
            assert among.mean() > 0.995
            assert set(np.unique(coarse)) <= set(np.unique(seg))
            assert len(np.unique(coarse)) >= 0.8 * len(np.unique(seg))


def test_a_surface_looks_as_bright_whichever_way_the_camera_turns(rendered):
    """The scene's lights are fixed in the world (the cameras carry no lamp): a camera
    turned in place by 12 degrees sees the table's top as bright as before, point for
    point (a light moving with the camera shaded it by the camera's direction: 5-7 %)."""
    scene, data, camera, pinhole, depth, rgb, seg = rendered
    table = scene.model.geom("workpiece/table").id
    T = opencv_pose(camera_pose(data, camera))
    v, u = np.nonzero((seg == table) & np.isfinite(depth))
    pick = np.random.default_rng(0).choice(len(u), min(len(u), 3000), replace=False)
    u, v = u[pick], v[pick]
    rays = np.column_stack([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy,
                            np.ones(len(u))])
    points = camera_to_world(T, rays * depth[v, u][:, None])
    model, cam = scene.model, scene.model.camera(camera).id
    quat = model.cam_quat[cam].copy()
    turn = Rotation.from_euler("x", 12.0, degrees=True)  # about the camera's own x axis
    model.cam_quat[cam] = (Rotation.from_quat(quat, scalar_first=True) * turn).as_quat(
        scalar_first=True)
    try:
        turned_data = scene.make_data()
        turned_data.qpos[:] = data.qpos
        mujoco.mj_forward(model, turned_data)
        with Renderer(model, pinhole.width, pinhole.height) as r:
            turned = r.rgb(turned_data, camera)
        T2 = opencv_pose(camera_pose(turned_data, camera))
    finally:
        model.cam_quat[cam] = quat
    pixel = np.rint(pinhole.project(world_to_camera(T2, points))).astype(int)
    inside = ((pixel[:, 0] >= 2) & (pixel[:, 0] < pinhole.width - 2)
              & (pixel[:, 1] >= 2) & (pixel[:, 1] < pinhole.height - 2))
    assert inside.sum() > 500
    before = rgb[v[inside], u[inside]].astype(float).mean()
    after = turned[pixel[inside, 1], pixel[inside, 0]].astype(float).mean()
    assert abs(after / before - 1) < 0.01, (before, after)
