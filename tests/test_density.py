"""Occlusion density: analytic rays against MuJoCo's, a sphere's cap by hand, generated
scenes holding the request at every radius, and the room clutter has."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.placement.density import (
    Primitive,
    elevation_bands,
    first_hits,
    hemisphere,
    occlusion_density,
    ray_hits,
)
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.scene import ObstacleConfig
from taskcam.sim.experiments.clutter_room import Boxes, ClutterRoom
from taskcam.sim.experiments.generate import (
    TOLERANCE,
    Clutter,
    clutter_target,
    extent_z,
    footprint,
    generate,
    primitive,
    scenario_clutter,
)
from taskcam.sim.world.scene import build_scene

UP = np.array([0.0, 0.0, 1.0])


def test_hemisphere_directions_are_even_and_above_the_rim():
    d = hemisphere(UP, 5000, math.radians(10))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert d[:, 2].min() >= math.sin(math.radians(10)) - 1e-9
    assert np.abs(d[:, :2].mean(axis=0)).max() < 0.01  # no side favoured
    # uniform in solid angle: the share above 45 deg is the share of its z range
    expected = (1 - math.sin(math.radians(45))) / (1 - math.sin(math.radians(10)))
    assert np.mean(d[:, 2] > math.sin(math.radians(45))) == pytest.approx(expected, abs=0.002)


def test_a_sphere_blocks_its_cap_by_hand():
    r, distance = 0.1, 0.5
    centre = np.array([0.0, 0.0, 0.0]) + distance * np.array([0.6, 0.0, 0.8])
    density = occlusion_density(np.zeros(3), UP, [Primitive("sphere", centre, (r,))], 2.0,
                                count=20000)
    cap = 2 * math.pi * (1 - math.sqrt(1 - (r / distance) ** 2))
    band = 2 * math.pi * (1 - math.sin(math.radians(10)))
    assert density == pytest.approx(cap / band, rel=0.02)
    # beyond the radius it hides nothing
    assert occlusion_density(np.zeros(3), UP, [Primitive("sphere", centre, (r,))], 0.3) == 0.0


@pytest.mark.parametrize("shape,size", [("box", (0.1, 0.2, 0.3)), ("cylinder", (0.08, 0.25)),
                                        ("sphere", (0.15,))])
def test_analytic_rays_agree_with_mujoco(shape, size):
    rng = np.random.default_rng(len(size))
    spec = mujoco.MjSpec()
    centre = np.array([0.3, -0.2, 0.4])
    yaw = 0.7
    kind = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
            "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}[shape]
    spec.worldbody.add_geom(type=kind, size=[*size, *([0.0] * (3 - len(size)))],
                            pos=centre.tolist(), quat=[math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    origin = np.array([0.0, 0.0, 0.1])
    directions = rng.normal(size=(3000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ours = ray_hits(origin, directions, Primitive(shape, centre, size, yaw), 0.9)
    geomid = np.zeros(1, np.int32)
    theirs = np.array([0 <= mujoco.mj_ray(model, data, origin, d, None, 1, -1, geomid) <= 0.9
                       for d in directions])
    assert ours.sum() > 50
    assert np.mean(ours == theirs) > 0.999


@pytest.mark.parametrize("request_", [0.05, 0.2, 0.35])
def test_generated_scenes_hold_the_requested_density_from_the_near_to_the_far_limit(request_):
    """Three scenes a density: the share blocked within the near limit and within the far
    limit (so at every radius between) is within the tolerance of the request, counted
    again with MuJoCo's rays through the built scene; every obstacle is in the grid, clear
    of the robots' starts, the work-piece, the panel's way and the holes' mouths."""
    s = load_scenario()
    origin, normal, room = clutter_target(s)
    assert np.allclose(origin, build_scene(s).make_data().site("workpiece/slot").xpos)
    for seed in range(3):
        clutter = scenario_clutter(s, request_, np.random.default_rng(seed))
        obstacles = clutter.obstacles
        radii = [r for r, _ in clutter.by_radius()]
        assert radii[0] == s.camera.near_m and radii[-1] == s.camera.far_m
        for _, share in clutter.by_radius():
            assert abs(share - request_) <= TOLERANCE + 1e-12
        low, high = np.asarray(s.grid.bounds_min), np.asarray(s.grid.bounds_max)
        for o in obstacles:
            bottom, top = extent_z(o)
            assert low[2] - 1e-9 <= bottom and top <= high[2]
            assert (low[:2] <= np.asarray(o.position[:2]) - footprint(o)).all()
            assert (np.asarray(o.position[:2]) + footprint(o) <= high[:2]).all()
            for b in s.base_poses():
                assert math.hypot(o.position[0] - b.x, o.position[1] - b.y) >= footprint(o) + 0.7
            assert room.clear(o)
        # the real geometry agrees: MuJoCo's rays through the built scene
        built = build_scene(dataclasses.replace(s, obstacles=obstacles))
        data = built.make_data()
        directions = hemisphere(normal, 1500, math.radians(10))
        ids = {built.model.geom(f"obstacle{i}/{o.shape}").id for i, o in enumerate(obstacles)}
        geomid = np.zeros(1, np.int32)
        distance = np.full(len(directions), np.inf)
        for k, d in enumerate(directions):  # the first obstacle along the ray, if any
            start = origin + 1e-4 * normal
            while True:
                hit = mujoco.mj_ray(built.model, data, start, d, None, 1, -1, geomid)
                if hit < 0:
                    break
                if int(geomid[0]) in ids:
                    distance[k] = float(np.linalg.norm(start + hit * d - origin))
                    break
                start = start + (hit + 1e-4) * d  # through the work-piece's own geoms
        for radius in (s.camera.near_m, s.camera.far_m):
            measured = occlusion_density(origin, normal, [primitive(o) for o in obstacles],
                                         radius, 1500)
            assert np.mean(distance <= radius) == pytest.approx(measured, abs=0.01)


def test_a_camera_faces_the_share_blocked_within_its_distance():
    """A sphere 0.5 m up the normal: a camera 0.4 m away faces none of it, one 0.6 m
    away its whole cap (by hand), at every radius recorded from there on."""
    r, distance = 0.1, 0.5
    sphere = ObstacleConfig("sphere", (0.0, 0.0, distance), (r,))
    room = ClutterRoom(Boxes.of([], [], []), Boxes.of([], [], []), ())
    cap = (1 - math.sqrt(1 - (r / distance) ** 2)) / (1 - math.sin(math.radians(10)))
    directions, _ = elevation_bands(UP)
    first = first_hits(np.zeros(3), directions, [primitive(sphere)])
    clutter = Clutter((sphere,), np.zeros(3), UP, first, 0.35, 1.5)
    assert clutter.faced(np.array([0.4, 0.0, 0.0])) == 0.0
    assert clutter.faced(np.array([0.0, 0.6, 0.0])) == pytest.approx(cap, rel=0.05)
    assert [radius for radius, _ in clutter.by_radius()] == [0.35, 0.6, 0.8, 1.0, 1.5]
    assert [share for _, share in clutter.by_radius()][1:] == [round(clutter.density, 6)] * 4
    assert room.clear(sphere)


def test_box_overlap_agrees_with_points_sampled_inside_both():
    """The separating axis test against brute force: boxes overlap exactly when a
    point lies inside both (checked on a fine grid of points)."""
    rng = np.random.default_rng(4)
    agree = 0
    for _ in range(60):
        yaw_a, yaw_b = rng.uniform(0, np.pi, 2)
        tilt = Rotation.from_rotvec(rng.normal(size=3) * 0.5).as_matrix()
        ra = Rotation.from_euler("z", yaw_a).as_matrix()
        rb = tilt @ Rotation.from_euler("z", yaw_b).as_matrix()
        ca, cb = np.zeros(3), rng.uniform(-0.4, 0.4, 3)
        ha, hb = rng.uniform(0.05, 0.25, 3), rng.uniform(0.05, 0.25, 3)
        g = np.linspace(-1, 1, 31)
        local = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3) * ha
        points = ca + local @ ra.T  # inside A
        inside_b = np.all(np.abs((points - cb) @ rb) <= hb, axis=1)
        overlaps = Boxes.of([cb], [rb], [hb]).overlaps(ca, ra, ha)
        if inside_b.any():
            assert overlaps
        agree += overlaps == inside_b.any()
    assert agree >= 57  # a sliver thinner than the sampling's step may be missed by it


def test_clutter_stands_on_the_table_or_the_floor():
    s = load_scenario()
    _, _, room = clutter_target(s)
    assert room.support(0.0, 0.0) == pytest.approx(0.52)  # the plate's top
    assert room.support(0.35, 0.25) == pytest.approx(0.5)  # the table's, beside the plate
    assert room.support(0.6, 0.0) == 0.0  # the floor
    # standing through the table, or on a hole, or in the panel's way: refused
    assert not room.clear(ObstacleConfig("box", (0.3, 0.0, 0.3), (0.05, 0.05, 0.3)))
    assert not room.clear(ObstacleConfig("box", (0.05, 0.0, 0.57), (0.03, 0.03, 0.05)))
    assert not room.clear(ObstacleConfig("box", (-0.15, 0.05, 0.6), (0.03, 0.03, 0.05)))
    assert room.clear(ObstacleConfig("box", (0.2, -0.15, 0.57), (0.03, 0.03, 0.05)))


def test_an_impossible_request_is_refused():
    room = ClutterRoom(Boxes.of([], [], []), Boxes.of([], [], []), ((0.0, 0.0, 3.0, math.inf),))
    with pytest.raises(ValueError, match="not in"):
        generate(0.95, np.zeros(3), UP, 0.35, 1.5, room, np.random.default_rng(0))
    with pytest.raises(ValueError, match="could not reach"):  # no room for any obstacle
        generate(0.2, np.zeros(3), UP, 0.35, 1.5, room, np.random.default_rng(0))
