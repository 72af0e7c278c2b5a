"""Occupancy grid, sensor model and depth integration, against hand calculations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taskcam.mapping import OccupancyGrid, Pinhole, SensorModel, integrate_depth, world_to_camera

MODEL = SensorModel(hit=0.7, miss=0.4, clamp_min=0.12, clamp_max=0.97)
HIT, MISS, LO, HI = MODEL.stored()  # log-odds in thousandths: 847, -405, -1992, 3476
QUANTUM = 2e-4  # probability error of one stored log-odds step, and then some


def looking_down(height: float) -> np.ndarray:
    """T_world_cam (OpenCV) of a camera at (0, 0, height) looking straight down."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # x right, y down (-y world), z forward (-z world)
    T[:3, 3] = [0, 0, height]
    return T


def small_grid(shift: float = 0.0) -> OccupancyGrid:
    lo = np.array([-1.0, -1.0, -0.5]) + shift
    return OccupancyGrid.from_bounds(lo, lo + [2.0, 2.0, 3.0], 0.1, MODEL)


def test_from_bounds_shape_and_centres():
    g = small_grid()
    assert g.shape == (20, 20, 30)
    assert np.allclose(g.centers(np.array([[0, 0, 0]])), [[-0.95, -0.95, -0.45]])
    assert np.all(g.probability() == 0.5)
    assert g.entropy().max() == pytest.approx(1.0)


def test_log_odds_update_and_clamping_by_hand():
    assert (HIT, MISS, LO, HI) == (847, -405, -1992, 3476)  # round(1000 logit(p))
    g = small_grid()
    g.update(np.array([0]), np.array([1]))
    p = g.probability().reshape(-1)
    assert p[0] == pytest.approx(0.4, abs=QUANTUM) and p[1] == pytest.approx(0.7, abs=QUANTUM)
    g.update(np.array([0]), np.array([1]))
    expected = 1 / (1 + math.exp(-2 * math.log(0.4 / 0.6)))  # two misses add their log-odds
    assert g.probability().reshape(-1)[0] == pytest.approx(expected, abs=QUANTUM)
    for _ in range(20):
        g.update(np.array([0]), np.array([1]))
    assert g.log_odds.reshape(-1)[:2].tolist() == [LO, HI]  # clamped
    p = g.probability().reshape(-1)
    assert p[0] == pytest.approx(0.12, abs=QUANTUM) and p[1] == pytest.approx(0.97, abs=QUANTUM)


def test_occupied_wins_and_one_update_per_scan():
    g = small_grid()
    g.update(np.array([5, 5, 5, 6]), np.array([6, 6]))
    flat = g.log_odds.reshape(-1)
    assert flat[5] == MISS and flat[6] == HIT
    assert g.nbytes() == 3 * g.size  # int16 log-odds + uint8 stamp


def test_stamp_codes_survive_wrapping():
    g = small_grid()
    for _ in range(300):  # past the 127 codes of the stamp
        g.update(np.array([1]), np.array([], dtype=int))
    g.update(np.array([2]), np.array([], dtype=int))
    assert g.log_odds.reshape(-1)[1] == LO and g.log_odds.reshape(-1)[2] == MISS


def test_sensor_model_rejects_inconsistent_probabilities():
    with pytest.raises(ValueError, match="clamp_min"):
        SensorModel(hit=0.4, miss=0.3)


@given(st.floats(0.1, 5.0), st.floats(-0.5, 0.5), st.floats(-0.4, 0.4))
def test_project_unproject_round_trip(z, x, y):
    cam = Pinhole.from_fovy(math.radians(60), 640, 480)
    point = np.array([[x * z, y * z, z]])
    u, v = cam.project(point)[0]
    ray = np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
    assert np.allclose(ray * z, point[0], atol=1e-9)


def test_pinhole_matches_vertical_field_of_view():
    cam = Pinhole.from_fovy(math.radians(90), 200, 100)
    # a point at 45 deg above the axis projects to the image's top edge (v = -0.5)
    assert cam.project(np.array([[0.0, -1.0, 1.0]]))[0, 1] == pytest.approx(cam.cy - 50)


def test_plane_integration_marks_surface_occupied_and_space_free_once():
    g = small_grid()
    cam = Pinhole.from_fovy(math.radians(40), 64, 48)
    depth = np.full((48, 64), 2.0, dtype=np.float32)  # floor z = 0 seen from z = 2
    n_free, n_occ = integrate_depth(g, depth, cam, looking_down(2.0), max_range=5.0)
    p = g.probability()
    centre = g.index(np.array([[0.0, 0.0, 0.0]]))[0]  # the voxel holding the floor point
    L = g.log_odds
    assert L[tuple(centre)] == HIT
    above = g.index(np.array([[0.0, 0.0, 1.0]]))[0]
    assert L[tuple(above)] == MISS  # one miss, however many rays crossed it
    below = g.index(np.array([[0.0, 0.0, -0.3]]))[0]
    assert L[tuple(below)] == 0 and p[tuple(below)] == 0.5  # behind the surface: unknown
    assert set(np.unique(L).tolist()) <= {MISS, 0, HIT}
    assert n_free == int((L == MISS).sum()) and n_occ == int((L == HIT).sum())
    # every occupied voxel holds the floor
    occ_z = g.centers(np.argwhere(L == HIT))[:, 2]
    assert np.allclose(occ_z, 0.05)


def test_sky_and_nan_never_mark_occupied():
    g = small_grid()
    cam = Pinhole.from_fovy(math.radians(40), 32, 24)
    depth = np.full((24, 32), np.inf, dtype=np.float32)
    depth[:, :8] = np.nan
    depth[:, 8:12] = -1.0
    integrate_depth(g, depth, cam, looking_down(2.0), max_range=1.0)
    assert not np.any(g.log_odds > 0)
    assert g.probability_at(np.array([[0.0, 0.0, 1.5]]))[0] == pytest.approx(0.4, abs=QUANTUM)
    assert g.probability_at(np.array([[0.0, 0.0, 0.5]]))[0] == 0.5  # beyond max range


def _overlaps(g: OccupancyGrid, origin: np.ndarray, end: np.ndarray) -> dict[int, float]:
    """Length (in voxels) of the segment inside each voxel of its bounding box; negative
    where it misses. Brute force, one voxel box at a time."""
    a, b = (origin - g.origin) / g.resolution, (end - g.origin) / g.resolution
    lo = np.maximum(np.floor(np.minimum(a, b)).astype(int) - 1, 0)
    hi = np.minimum(np.floor(np.maximum(a, b)).astype(int) + 1, np.array(g.shape) - 1)
    out = {}
    d = b - a
    for i in range(lo[0], hi[0] + 1):
        for j in range(lo[1], hi[1] + 1):
            for k in range(lo[2], hi[2] + 1):
                t0, t1 = 0.0, 1.0
                for axis, cell in enumerate((i, j, k)):
                    if d[axis] == 0:
                        if not cell <= a[axis] <= cell + 1:
                            t0, t1 = 1.0, 0.0
                        continue
                    u, v = (cell - a[axis]) / d[axis], (cell + 1 - a[axis]) / d[axis]
                    t0, t1 = max(t0, min(u, v)), min(t1, max(u, v))
                out[(i * g.shape[1] + j) * g.shape[2] + k] = (t1 - t0) * np.linalg.norm(d)
    return out


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(0.5, 1.9))
def test_free_voxels_are_exactly_those_the_ray_crosses(x, y, z):
    """A single-pixel scan frees every voxel the ray passes through (brute force), and
    no voxel it does not at least touch; the end voxel is occupied. The grid is shifted
    off round numbers so that no ray runs inside a voxel face."""
    g = small_grid(shift=0.01234)
    T = looking_down(2.0)
    end_world = np.array([x, y, 2.0 - z])
    end_cam = world_to_camera(T, end_world[None])[0]
    direction = end_cam / end_cam[2]
    cam = Pinhole(1, 1, 1.0, 1.0, -direction[0], -direction[1])
    integrate_depth(g, np.array([[end_cam[2]]]), cam, T, max_range=5.0)
    flat = g.log_odds.reshape(-1)
    ours = set(np.flatnonzero(flat == MISS).tolist())
    end_voxel = int(np.ravel_multi_index(tuple(g.index(end_world[None])[0]), g.shape))
    overlap = _overlaps(g, T[:3, 3], end_world)
    crossed = {v for v, length in overlap.items() if length > 1e-6} - {end_voxel}
    touched = {v for v, length in overlap.items() if length > -1e-9}
    assert crossed <= ours <= touched
    assert flat[end_voxel] == HIT


def test_invalid_pixels_change_nothing():
    g = small_grid()
    cam = Pinhole.from_fovy(math.radians(40), 32, 24)
    depth = np.full((24, 32), np.nan)
    depth[:, :10] = -1.0
    depth[:, 10:20] = 0.0
    assert integrate_depth(g, depth, cam, looking_down(2.0), max_range=5.0) == (0, 0)
    assert not g.log_odds.any()
