"""Target field visibility: occlusion expansion, hulls, the sphere, against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taskcam.mapping import OccupancyGrid, SensorModel
from taskcam.placement import (
    CameraModel,
    SearchSettings,
    TargetModel,
    Weights,
    clearance_map,
    expand,
    expanded_hulls,
    grid_occluders,
    hull_depths,
    rate,
    search,
    target_outline,
)
from taskcam.placement.tfv import PackedHulls, sphere

UP = np.array([0.0, 0.0, 1.0])
TARGET = TargetModel("t", np.zeros(3), UP, 0.03)
BOX = np.array([[x, y, z] for x in (0.3, 0.5) for y in (-0.1, 0.1) for z in (0.05, 0.6)])


def test_expanded_hull_contains_the_minkowski_sum():
    hull = expand(BOX, TARGET)
    rng = np.random.default_rng(0)
    inside = rng.uniform(BOX.min(0), BOX.max(0), (500, 3))
    angle = rng.uniform(0, 2 * np.pi, 500)
    radius = TARGET.radius * np.sqrt(rng.uniform(0, 1, 500))
    disc = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(500)])
    assert hull.contains(inside + disc, tol=1e-9).all()
    assert hull.contains(BOX + target_outline(TARGET)[0]).all()
    assert not hull.contains(np.array([[0.0, 0.0, 0.3], [0.4, 0.0, 0.7]])).any()


def test_a_grown_hull_is_the_hull_of_the_scaled_expansion():
    small = expand(BOX, TARGET)
    big = expand(BOX, TargetModel("big", TARGET.position, UP, 0.07))
    grown = small.grown(0.07 / 0.03)
    rng = np.random.default_rng(2)
    probe = rng.uniform(BOX.min(0) - 0.1, BOX.max(0) + 0.1, (20000, 3))
    assert np.array_equal(grown.contains(probe), big.contains(probe))
    assert np.allclose(np.sort(grown.vertices, axis=0), np.sort(big.vertices, axis=0))


def brute_clearance(hulls, offset: np.ndarray, cone: bool, samples: int = 400_000) -> float:
    """Angle from the camera's direction to the nearest direction occluded from its
    distance, by dense random directions: a direction is occluded when some fraction t in
    [0, 1] of the way to the camera lies in the hull with its faces moved in by t reach
    (cone) or not at all (paper)."""
    rng = np.random.default_rng(1)
    u = rng.normal(size=(samples, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    d = np.linalg.norm(offset)
    occluded = np.zeros(samples, dtype=bool)
    for h in hulls:
        rate_ = d * (u @ h.A.T) + (h.reach if cone else 0.0)  # (n, f), per unit of t
        room = np.broadcast_to(h.b, rate_.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = room / rate_
        lo = np.where(rate_ < 0, s, 0.0).max(axis=1, initial=0.0)
        hi = np.where(rate_ > 0, s, 1.0).min(axis=1, initial=1.0)
        occluded |= (lo <= hi) & ~np.any((rate_ == 0) & (room < 0), axis=1)
    if not occluded.any():
        return math.pi
    cos = u[occluded] @ (offset / d)
    return float(np.arccos(np.clip(cos.max(), -1, 1)))


@pytest.mark.parametrize("azimuth_deg", [0.0, 20.0, 40.0, 90.0, 180.0])
@pytest.mark.parametrize("distance", [0.4, 1.0])
@pytest.mark.parametrize("cone", [True, False])
def test_tfv_is_the_angular_clearance(azimuth_deg, distance, cone):
    hulls = expanded_hulls([BOX], TARGET)
    cmap = clearance_map(TARGET.position, hulls, 0.35, 1.5, levels=116, cone=cone)
    a = math.radians(azimuth_deg)
    offset = distance * np.array([math.cos(a) * math.cos(0.5), math.sin(a) * math.cos(0.5),
                                  math.sin(0.5)])
    ours = cmap.tfv(offset[None])[0]
    truth = brute_clearance(hulls, offset, cone) / math.pi
    assert ours == pytest.approx(truth, abs=0.02)  # sphere and distance quantisation


def segments_hit_box(cameras: np.ndarray, points: np.ndarray, lo: np.ndarray,
                     hi: np.ndarray) -> np.ndarray:
    """Per camera: does any segment from it to one of ``points`` cross the box [lo, hi]?
    (slab test)"""
    v = points[None, :, :] - cameras[:, None, :]  # (c, p, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - cameras[:, None, :]) / v
        t2 = (hi - cameras[:, None, :]) / v
    enter = np.nanmax(np.minimum(t1, t2), axis=2).clip(0.0, None)
    leave = np.nanmin(np.maximum(t1, t2), axis=2).clip(None, 1.0)
    return np.any(enter <= leave, axis=1)


def test_cone_expansion_matches_rays_to_the_whole_target():
    """Occluded by the cone-expanded hull <=> some ray from the camera to the target disc
    meets the box; the paper's uniform expansion hides strictly more near the box."""
    rng = np.random.default_rng(5)
    az, el = rng.uniform(-1.0, 1.0, 4000), rng.uniform(0.0, 1.2, 4000)  # toward the box
    u = np.column_stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    d = rng.uniform(0.35, 1.5, 4000)
    angle = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    disc = np.vstack([np.zeros((1, 3))] + [
        np.column_stack([r * np.cos(angle), r * np.sin(angle), 0 * angle])
        for r in TARGET.radius * np.array([0.5, 1.0])])
    truth = segments_hit_box(d[:, None] * u, disc, BOX.min(0), BOX.max(0))
    hulls = expanded_hulls([BOX], TARGET)
    cone = hull_depths(TARGET.position, hulls, u, cone=True) < d
    paper = hull_depths(TARGET.position, hulls, u, cone=False) < d
    assert truth.sum() > 1000  # the box really hides part of the sample
    assert np.all(cone[truth]) and np.all(paper[truth])  # both conservative
    assert np.mean(cone != truth) < 0.003  # the cone errs only by the octagon around the disc
    assert (paper & ~truth).sum() > 5 * max((cone & ~truth).sum(), 1)


def test_a_slot_is_expanded_by_its_rectangle():
    """A slot target 0.2 m long (along x + y, given a little out of its plane) and 14 mm
    wide: its outline is the rectangle's four corners, by hand; and occluded by the
    cone-expanded hull <=> some ray from the camera to the slot (its outline and
    inside, sampled) meets the box."""
    slot = TargetModel("s", np.zeros(3), UP, 0.007, half_length=0.1,
                       axis=np.array([1.0, 1.0, 0.3]))
    a = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    b = np.array([-1.0, 1.0, 0.0]) / math.sqrt(2)  # up x a
    corners = [0.1 * i * a + 0.007 * j * b for i, j in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    assert np.allclose(target_outline(slot), corners)
    rng = np.random.default_rng(7)
    az, el = rng.uniform(-1.2, 1.2, 4000), rng.uniform(0.0, 1.2, 4000)
    u = np.column_stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    d = rng.uniform(0.35, 1.5, 4000)
    ii, jj = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 5))
    points = 0.1 * ii.reshape(-1, 1) * a + 0.007 * jj.reshape(-1, 1) * b
    truth = segments_hit_box(d[:, None] * u, points, BOX.min(0), BOX.max(0))
    cone = hull_depths(slot.position, expanded_hulls([BOX], slot), u, cone=True) < d
    assert truth.sum() > 1000 and (~truth).sum() > 1000
    assert np.all(cone[truth])  # conservative
    assert np.mean(cone != truth) < 0.003  # exact but for the sampling of the rectangle


def test_tfv_is_zero_behind_the_occluder_and_grows_away_from_it():
    cmap = clearance_map(TARGET.position, expanded_hulls([BOX], TARGET), 0.35, 1.5)
    arc = np.radians(np.arange(0, 181, 10))
    offsets = 1.0 * np.column_stack([np.cos(arc), np.sin(arc), np.full(len(arc), 0.3)])
    tfv = cmap.tfv(offsets)
    assert tfv[0] == 0.0  # straight behind the box
    assert np.all(np.diff(tfv) >= -1e-9) and tfv[-1] > tfv[3] > 0


def test_nothing_in_the_way_means_full_visibility():
    cmap = clearance_map(TARGET.position, [], 0.35, 1.5)
    assert np.all(cmap.tfv(np.array([[0.5, 0.0, 0.5], [0.0, -1.0, 0.2]])) == 1.0)


def test_occluders_from_the_grid_are_above_the_plane_and_split_in_blocks():
    g = OccupancyGrid.from_bounds(np.array([-1.0, -1.0, -0.5]), np.array([1.0, 1.0, 1.0]),
                                  0.05, SensorModel())
    g.set_probability(0.01)
    c = g.centers()
    g.set_probability(0.99, c[..., 2] < 0)  # the table under the target
    g.set_probability(0.99, (np.abs(c[..., 0] - 0.4) < 0.1) & (np.abs(c[..., 1]) < 0.1)
                      & (c[..., 2] > 0.05) & (c[..., 2] < 0.6))  # a block beside it
    pieces = grid_occluders(g, TARGET, block=4)
    points = np.vstack(pieces)
    assert points[:, 2].min() >= 0.0  # nothing below the target's plane
    assert all(np.ptp(p, axis=0).max() <= 4 * 0.05 + 1e-9 for p in pieces)
    g.set_probability(0.5, (np.abs(c[..., 0] + 0.5) < 0.1) & (c[..., 2] > 0.2) & (c[..., 2] < 0.4))
    assert len(grid_occluders(g, TARGET)) > len(pieces)  # unknown voxels occlude
    assert len(grid_occluders(g, TARGET, unknown_occludes=False)) == len(pieces)


def test_rating_is_zero_whenever_a_factor_is():
    camera = CameraModel(math.radians(60), 480, 0.4, 1.5)
    pos = np.array([[0.3, 0.0, 0.5], [0.0, 0.0, 2.0], [0.5, 0.0, -0.1], [0.3, 0.0, 0.5]])
    r = rate(pos, TARGET, camera, np.array([0.0, 1.0, 1.0, 1.0]), np.array([0, 0, 0, 1.0]))
    assert r.tfv[0] == 0 and r.dof[1] == 0 and r.tav[2] == 0 and r.free[3] == 0
    assert np.all(r.total == 0)
    w = rate(pos[:1], TARGET, camera, np.array([0.0]), np.zeros(1), Weights(gamma=0.0))
    assert w.total[0] > 0  # with gamma = 0, TFV no longer matters


def test_random_search_covering_every_candidate_equals_exhaustive():
    g = OccupancyGrid.from_bounds(np.array([-0.8, -0.8, -0.2]), np.array([0.8, 0.8, 1.0]),
                                  0.1, SensorModel())
    g.set_probability(0.01)
    c = g.centers()
    g.set_probability(0.99, c[..., 2] < 0)
    g.set_probability(0.99, (np.abs(c[..., 0]) < 0.15) & (c[..., 2] > 0.4) & (c[..., 2] < 0.5))
    camera = CameraModel(math.radians(60), 480, 0.3, 1.2)
    full = search(g, [TARGET], camera)
    rnd = search(g, [TARGET], camera, settings=SearchSettings("random", samples=10**6),
                 rng=np.random.default_rng(3))
    assert rnd.evaluated == full.evaluated
    assert np.allclose(full.ratings.positions[full.ranked()[0]],
                       rnd.ratings.positions[rnd.ranked()[0]])
    coarse = search(g, [TARGET], camera, settings=SearchSettings("coarse", coarse_step=2))
    bounded = search(g, [TARGET], camera, settings=SearchSettings("bounded", max_distance=0.6))
    assert 0 < coarse.evaluated < full.evaluated and 0 < bounded.evaluated < full.evaluated
    assert np.all(np.linalg.norm(bounded.ratings.positions, axis=1) <= 0.6)


@pytest.mark.parametrize("cone", [True, False])
def test_hidden_directions_are_those_every_direction_finds(cone):
    """Testing only the directions facing a hull's bounding sphere finds exactly the
    directions testing all 16384 does: boxes near and far, several at once, and a target
    inside one's bounding sphere (every direction is then tested)."""
    rng = np.random.default_rng(11)
    dirs, _ = sphere(16384)
    cases = [[BOX], [BOX + [0.9, 0.4, 0.2]], [BOX, BOX * [-1, 1, 1] + [0, 0.5, 0.1]],
             [BOX - [0.4, 0.0, 0.3]]]  # the last around the target
    for boxes in cases:
        packed = PackedHulls.of(expanded_hulls(boxes, TARGET))
        for distance in rng.uniform(0.2, 2.0, 3):
            every = np.flatnonzero(packed.occluded(TARGET.position, distance * dirs, cone))
            found = packed.hidden_directions(TARGET.position, distance, 16384, cone)
            assert np.array_equal(found, every)
        facing = packed.facing(TARGET.position, 16384)
        assert len(facing) < 16384 or boxes is cases[-1]
    assert len(every) > 100
