"""Occlusion density: analytic rays against MuJoCo's, a sphere's cap
by hand, and generated scenes within 3 points of the request."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from placement.density import (
    Primitive,
    band_shares,
    elevation_bands,
    hemisphere,
    occlusion_density,
    ray_hits,
)
from sim.config.scenario import load_scenario
from sim.experiments.generate import (
    ClutterKeepOut,
    extent_z,
    footprint,
    generate,
    primitive,
    scenario_clutter,
)
from sim.world.scene import build_scene

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
def test_generated_scenes_reach_the_requested_density(request_):
    s = load_scenario()
    scene = build_scene(s)
    target = scene.primary
    for seed in range(3):
        clutter = scenario_clutter(s, request_, np.random.default_rng(seed))
        obstacles = clutter.obstacles
        assert abs(clutter.density - request_) <= 0.03
        low, high = np.asarray(s.grid.bounds_min), np.asarray(s.grid.bounds_max)
        for o in obstacles:  # inside the map's grid, clear of the robots at every height
            bottom, top = extent_z(o)
            assert low[2] - 1e-9 <= bottom and top <= high[2]
            assert (low[:2] <= np.asarray(o.position[:2]) - footprint(o)).all()
            assert (np.asarray(o.position[:2]) + footprint(o) <= high[:2]).all()
            for b in s.base_poses():
                assert math.hypot(o.position[0] - b.x, o.position[1] - b.y) >= footprint(o) + 0.7
            # the work-piece's column is clear up to the panel's way
            near = math.hypot(o.position[0] - s.workpiece.position[0],
                              o.position[1] - s.workpiece.position[1]) < footprint(o) + 0.55
            assert not near or bottom >= target.position[2] + s.task.approach_m + 0.2
        # the real geometry agrees: MuJoCo's rays through the built scene
        built = build_scene(dataclasses.replace(s, obstacles=obstacles))
        data = built.make_data()
        directions = hemisphere(target.normal, 1500, math.radians(10))
        ids = {built.model.geom(f"obstacle{i}/{o.shape}").id for i, o in enumerate(obstacles)}
        geomid = np.zeros(1, np.int32)
        hits = 0
        for d in directions:
            dist = mujoco.mj_ray(built.model, data, target.position + 1e-4 * target.normal, d,
                                 None, 1, -1, geomid)
            hits += bool(0 <= dist <= s.camera.far_m and int(geomid[0]) in ids)
        measured = occlusion_density(target.position, target.normal,
                                     [primitive(o) for o in obstacles], s.camera.far_m, 1500)
        assert hits / len(directions) == pytest.approx(measured, abs=0.01)


def test_clutter_blocks_every_elevation_as_much_as_requested():
    """Over 40 generated 35 % scenes the mean blocked share of every 10 deg band
    from 10 to 70 deg is within 10 points of 35 %, counted again here by brute force
    (MuJoCo's rays through the built scenes, every fourth scene); the bands' shares,
    weighted by their solid angle, are the density."""
    s = load_scenario()
    target = build_scene(s).primary
    shares = []
    for seed in range(40):
        clutter = scenario_clutter(s, 0.35, np.random.default_rng([seed, 0]))
        directions, band = elevation_bands(target.normal)
        weights = np.bincount(band) / len(band)
        assert float(weights @ clutter.band_shares) == pytest.approx(clutter.density, abs=1e-9)
        if seed % 4 == 0:
            built = build_scene(dataclasses.replace(s, obstacles=clutter.obstacles))
            data = built.make_data()
            geomid = np.zeros(1, np.int32)
            obstacle = {built.model.geom(f"obstacle{i}/{o.shape}").id
                        for i, o in enumerate(clutter.obstacles)}
            picked = np.arange(len(directions))
            hit = np.array([0 <= mujoco.mj_ray(built.model, data, target.position
                                               + 1e-4 * target.normal, directions[k], None, 1,
                                               -1, geomid) <= s.camera.far_m
                            and int(geomid[0]) in obstacle for k in picked])
            brute = band_shares(hit, band[picked])
            assert np.abs(brute - clutter.band_shares).max() < 0.01
        shares.append(clutter.band_shares)
    mean = np.mean(shares, axis=0)
    assert (np.abs(mean[:6] - 0.35) <= 0.10).all(), mean


def test_an_impossible_request_is_refused():
    with pytest.raises(ValueError, match="not in"):
        generate(0.95, np.zeros(3), UP, 1.5, [], np.random.default_rng(0))
    with pytest.raises(ValueError, match="could not reach"):  # no room for any obstacle
        generate(0.2, np.zeros(3), UP, 1.5, [ClutterKeepOut(0.0, 0.0, 3.0)],
                 np.random.default_rng(0))


def test_a_scene_that_reaches_the_upper_bound_is_kept():
    """Table 1's 5 % scene 85 (its seed 2823833693): drawing held it to at most 7 %, where
    it ended, and the final check then refused 7 % itself (|0.07 - 0.05| > 0.02 in
    floating point), which stopped the full sweep there."""
    s = load_scenario()
    clutter = scenario_clutter(s, 0.05, np.random.default_rng([2823833693, 0]))
    assert clutter.density == pytest.approx(0.07, abs=1e-12)
    assert abs(clutter.density - 0.05) > 0.02  # the float gap the old check tripped on
    assert clutter.density <= 0.05 + 0.02
