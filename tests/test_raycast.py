"""Voxel traversal (3-D DDA) against brute-force slab clipping, and the shared image kernel."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taskcam.mapping import (
    OccupancyGrid,
    Pinhole,
    SensorModel,
    first_hits,
    integrate_depth,
    opencv_pose,
    traverse,
)

SHAPE = (12, 10, 8)


def brute_force(origin: np.ndarray, end: np.ndarray) -> tuple[set[int], set[int]]:
    """Voxels the segment passes through (inside length > 1e-9) and those it touches.
    Voxel i spans [i, i + 1): a segment lying in a face belongs to the voxel above it."""
    d = end - origin
    crossed, touched = set(), set()
    for i, j, k in itertools.product(*(range(n) for n in SHAPE)):
        t0, t1 = 0.0, 1.0
        for axis, cell in enumerate((i, j, k)):
            if d[axis] == 0:
                if not cell <= origin[axis] < cell + 1:
                    t0, t1 = 1.0, 0.0
                continue
            a, b = (cell - origin[axis]) / d[axis], (cell + 1 - origin[axis]) / d[axis]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        inside = (t1 - t0) * np.linalg.norm(d)
        flat = (i * SHAPE[1] + j) * SHAPE[2] + k
        if inside > 1e-9:
            crossed.add(flat)
        if inside > -1e-9:
            touched.add(flat)
    return crossed, touched


def ours(origin: np.ndarray, end: np.ndarray) -> list[int]:
    length = np.linalg.norm(end - origin)
    _, voxels = traverse(SHAPE, origin, ((end - origin) / length)[None], np.array([length]))
    return voxels.tolist()


point = st.tuples(st.floats(0.01, 11.99), st.floats(0.01, 9.99), st.floats(0.01, 7.99))


@settings(max_examples=60, deadline=None)
@given(point, point)
def test_random_segments_match_brute_force(a, b):
    a, b = np.array(a), np.array(b)
    if np.linalg.norm(b - a) < 1e-6:
        return
    found = ours(a, b)
    crossed, touched = brute_force(a, b)
    assert len(found) == len(set(found))  # each voxel once
    assert crossed <= set(found) <= touched


@pytest.mark.parametrize("axis", range(3))
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_axis_aligned_rays_inside_a_row(axis, sign):
    origin = np.array([5.5, 4.5, 3.5])
    d = np.zeros(3)
    d[axis] = sign
    end = origin + 3.0 * d
    found = ours(origin, end)
    crossed, _ = brute_force(origin, end)
    assert set(found) == crossed and len(found) == 4  # start voxel and three more


@pytest.mark.parametrize("direction", [(1, 1, 1), (1, -1, 0), (-1, 1, 1), (1, 1, 0)])
def test_rays_through_voxel_corners_and_edges(direction):
    d = np.array(direction, float)
    origin = np.array([4.0, 4.0, 3.0]) + 0.25 * d  # inside a voxel, then through corners
    end = origin + 3.0 * d
    found = ours(origin, end)
    crossed, touched = brute_force(origin, end)
    assert crossed <= set(found) <= touched
    assert len(found) == len(set(found))


def test_segments_outside_or_leaving_the_grid_are_clipped():
    assert ours(np.array([-5.0, -5.0, -5.0]), np.array([-1.0, -1.0, -1.0])) == []
    found = ours(np.array([-2.5, 5.5, 4.5]), np.array([20.0, 5.5, 4.5]))
    assert len(found) == SHAPE[0]


def test_first_hits_stop_at_blocked_voxels():
    blocked = np.zeros(np.prod(SHAPE), dtype=bool)
    blocked[(6 * SHAPE[1] + 5) * SHAPE[2] + 4] = True
    o = np.array([[0.5, 5.5, 4.5], [0.5, 2.5, 4.5]])
    d = np.array([[1.0, 0, 0], [1.0, 0, 0]])
    assert first_hits(SHAPE, o, d, np.array([10.0, 10.0]), blocked).tolist() == [True, False]
    assert first_hits(SHAPE, o, d, np.array([5.0, 10.0]), blocked).tolist() == [False, False]


def _rendered_frame():
    from taskcam.sim.config.scenario import load_scenario
    from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
    from taskcam.sim.world.scene import build_scene

    scene = build_scene(load_scenario())
    data = scene.make_data()
    robot = scene.robots[0]
    pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        depth = r.depth(data, robot.camera)
    return pinhole, depth, opencv_pose(camera_pose(data, robot.camera))


def test_shared_rays_free_a_subset_of_the_exact_free_space():
    """Sharing traversal between neighbouring rays only ever omits grazed voxels: on a
    rendered frame the shared result is a subset of the exact one, and within 1 %."""
    pinhole, depth, T = _rendered_frame()
    grids = {}
    for share in (0.0, 0.5):
        g = OccupancyGrid.from_bounds(np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 2.0]),
                                      0.02, SensorModel())
        integrate_depth(g, depth, pinhole, T, 4.0, share=share)
        grids[share] = g.states()
    exact, shared = grids[0.0], grids[0.5]
    assert np.array_equal(exact == 1, shared == 1)  # the same end points
    assert np.all(exact[shared == -1] == -1)
    missing = np.sum((exact == -1) & (shared == 0))
    assert missing <= 0.01 * np.sum(exact == -1)


def test_a_corridor_stays_free_and_its_end_occupied():
    """A wall at x = 1.5 with a tunnel; one camera looks down the tunnel."""
    g = OccupancyGrid.from_bounds(np.array([-1.0, -1.0, -1.0]), np.array([2.0, 1.0, 1.0]),
                                  0.1, SensorModel())
    cam = Pinhole.from_fovy(math.radians(10), 8, 8)
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # looks along +x
    T[:3, 3] = [-0.95, 0.05, 0.05]
    depth = np.full((8, 8), 2.5)  # every ray ends at x = 1.55
    integrate_depth(g, depth, cam, T, max_range=5.0)
    hit, miss, _, _ = g.model.stored()
    corridor = g.index(np.array([[x, 0.05, 0.05] for x in np.arange(-0.85, 1.5, 0.1)]))
    assert np.all(g.log_odds[tuple(corridor.T)] == miss)
    end = g.index(np.array([[1.55, 0.05, 0.05]]))[0]
    assert g.log_odds[tuple(end)] == hit
