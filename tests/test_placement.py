"""Rating function terms (eq. 1-4), lines of sight and search, against hand calculations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taskcam.mapping import GainModel, OccupancyGrid, Pinhole, View, region_mask
from taskcam.placement import (
    METHODS,
    CameraModel,
    MethodInput,
    MethodSettings,
    Region,
    TargetModel,
    Weights,
    angular_visibility,
    biased_random,
    depth_of_field,
    information_gain,
    informed_random,
    line_of_sight,
    look_at,
    method_named,
    method_problem,
    rate,
    rate_positions,
    resolution,
    search,
    target_points,
)

CAMERA = CameraModel(fov=math.radians(60), pixels=480, near=0.4, far=1.5)
UP = np.array([0.0, 0.0, 1.0])


def free_grid(lo=(-1.0, -1.0, 0.0), hi=(1.0, 1.0, 2.0), res=0.1) -> OccupancyGrid:
    g = OccupancyGrid.from_bounds(np.array(lo), np.array(hi), res)
    g.set_probability(0.01)
    return g


def occupy(g: OccupancyGrid, lo, hi, p: float = 0.99) -> None:
    """Set voxels whose centres lie in the box [lo, hi] to probability ``p``."""
    c = g.centers()
    inside = np.all((c >= np.array(lo)) & (c <= np.array(hi)), axis=-1)
    g.set_probability(p, inside)


def test_resolution_eq2_and_eq4_by_hand():
    d = np.array([1.0])
    R = 2 * 1.0 * math.tan(math.radians(30)) / 480  # 0.0024056 m per pixel
    assert resolution(d, CAMERA)[0] == pytest.approx(1 / R)
    assert resolution(d, CAMERA, st_error=0.001)[0] == pytest.approx(1 / (R + 0.001))
    assert resolution(np.array([2.0]), CAMERA)[0] == pytest.approx(0.5 / R)


def test_depth_of_field_is_binary_and_inclusive():
    d = np.array([0.39, 0.4, 1.0, 1.5, 1.51])
    assert depth_of_field(d, CAMERA).tolist() == [0, 1, 1, 1, 0]


def test_angular_visibility_eq3():
    t = TargetModel("t", np.zeros(3), UP, 0.02)
    above = np.array([[0, 0, 1.0]])
    sixty = np.array([[math.sin(math.radians(60)), 0, math.cos(math.radians(60))]])
    below = np.array([[0.3, 0, -0.1]])
    grazing = np.array([[1.0, 0, 0]])
    assert angular_visibility(above, t)[0] == pytest.approx(1.0)
    assert angular_visibility(sixty, t)[0] == pytest.approx(0.5)
    assert angular_visibility(below, t)[0] == 0.0
    assert angular_visibility(grazing, t)[0] == pytest.approx(0.0, abs=1e-12)


def test_rate_is_the_weighted_product():
    t = TargetModel("t", np.zeros(3), UP, 0.02)
    pos = np.array([[0.3, 0.0, 0.4], [0.0, 0.0, 2.0]])
    tfv, occ = np.array([0.8, 1.0]), np.array([0.02, 0.0])
    r = rate(pos, t, CAMERA, tfv, occ, Weights(1, 2, 0.5, 3))
    d = np.linalg.norm(pos, axis=1)
    expected0 = 1 * resolution(d, CAMERA)[0] ** 2 * 0.8 ** 0.5 * (0.4 / 0.5) ** 3 * 0.98
    assert r.total[0] == pytest.approx(expected0)
    assert r.total[1] == 0.0  # 2 m is beyond the depth of field
    unweighted = rate(pos, t, CAMERA, tfv, occ, Weights(0, 0, 0, 0))
    assert unweighted.total.tolist() == pytest.approx([0.98, 1.0])


def test_line_of_sight_through_a_wall():
    g = free_grid()
    occupy(g, (-0.05, -1, 0), (0.05, 1, 2))  # a wall in the plane x = 0
    cams = np.array([[-0.5, 0.0, 1.0], [0.5, 0.3, 1.0]])
    points = np.array([[0.5, 0.0, 0.5], [-0.5, 0.2, 0.5]])
    seen = line_of_sight(g, cams, points)
    assert seen.tolist() == [[False, True], [True, False]]


def test_line_of_sight_unknown_blocks_and_outside_is_unknown():
    g = free_grid()
    occupy(g, (0.2, -0.2, 0.9), (0.4, 0.2, 1.1), p=0.5)  # an unknown pocket
    cam, point = np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 1.0]])
    assert not line_of_sight(g, cam, point)[0, 0]
    assert line_of_sight(g, cam, point, occluding=0.6)[0, 0]
    assert not line_of_sight(g, cam, np.array([[0.0, 0.0, 3.0]]))[0, 0]  # leaves the grid


def test_line_of_sight_matches_brute_force_on_random_clutter():
    """Against slab clipping of every line with every blocked voxel's box."""
    rng = np.random.default_rng(4)
    g = free_grid(res=0.1)
    blocked = rng.random(g.shape) < 0.04
    g.set_probability(0.9, blocked)
    box_lo = g.origin + np.argwhere(blocked) * g.resolution
    box_hi = box_lo + g.resolution
    cams = rng.uniform([-0.9, -0.9, 0.1], [0.9, 0.9, 1.9], (300, 3))
    points = rng.uniform([-0.9, -0.9, 0.1], [0.9, 0.9, 1.9], (3, 3))
    ours = line_of_sight(g, cams, points)
    for i, c in enumerate(cams):
        for k, p in enumerate(points):
            d = p - c
            with np.errstate(divide="ignore"):
                ta, tb = (box_lo - c) / d, (box_hi - c) / d
            t0 = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
            t1 = np.minimum(np.maximum(ta, tb).min(axis=1), 1.0)
            overlap = (t1 - t0).max() * np.linalg.norm(d)  # metres inside a blocked voxel
            if abs(overlap) > 1e-9:  # not merely touching an edge or corner
                assert ours[i, k] == (overlap < 0), (i, k, overlap)


def test_search_avoids_the_occluded_optimum():
    """Unoccluded, the best view of a target facing up is straight above at the near
    limit; a block over it moves the best view aside, to a visible position."""
    target = TargetModel("t", np.array([0.0, 0.0, 0.2]), UP, 0.02)
    g = free_grid(res=0.05)
    occupy(g, (-1, -1, 0), (1, 1, 0.2))  # the table top
    clear = search(g, [target], CAMERA)
    best = clear.ratings.positions[clear.ranked()[0]]
    assert best[:2] == pytest.approx([0, 0], abs=0.05)
    assert np.linalg.norm(best - target.position) == pytest.approx(0.4, abs=0.05)
    occupy(g, (-0.15, -1, 0.5), (0.15, 1, 0.6))  # a beam over the target
    field = search(g, [target], CAMERA)
    i = field.ranked()[0]
    best = field.ratings.positions[i]
    assert abs(best[0]) > 0.1
    assert 0 < field.ratings.tfv[i] < 1  # in sight, with the beam some way off
    pts = target_points(target)
    assert line_of_sight(g, best[None], pts, stop_short=0.08).all()
    # the best is the true maximum of RF over all candidates (brute force)
    assert field.ratings.total[i] == field.ratings.total.max()


def test_search_switches_to_a_secondary_target():
    primary = TargetModel("p", np.array([0.0, 0.0, 0.2]), UP, 0.02)
    secondary = TargetModel("s", np.array([0.5, 0.0, 0.2]), UP, 0.02, st_error=0.0005)
    g = free_grid(res=0.05)
    occupy(g, (-1, -1, 0), (1, 1, 0.2))
    open_field = search(g, [primary, secondary], CAMERA)
    assert open_field.target[open_field.ranked()[0]] == 0  # primary wins: no ST error
    occupy(g, (-0.2, -0.2, 0.25), (0.2, 0.2, 1.6))  # a cover over the primary only
    covered = search(g, [primary, secondary], CAMERA)
    i = covered.ranked()[0]
    assert covered.target[i] == 1
    d = np.linalg.norm(covered.ratings.positions[i] - secondary.position)
    R = 2 * d * math.tan(CAMERA.fov / 2) / CAMERA.pixels + 0.0005
    assert covered.ratings.resolution[i] == pytest.approx(1 / R)


def test_informed_random_placement_ignores_occlusion_within_its_bounds():
    """The rating function's candidates in the depth of field and within the angle bound,
    occluded or not, in a random order; the same generator, the same order."""
    target = TargetModel("t", np.array([0.0, 0.0, 0.2]), UP, 0.02)
    g = free_grid(res=0.05)
    occupy(g, (-1, -1, 0), (1, 1, 0.2))
    occupy(g, (-0.15, -1, 0.5), (0.15, 1, 0.6))  # a beam over the target
    rated = search(g, [target], CAMERA)
    field = informed_random(rated, [target], CAMERA, np.random.default_rng(3), 45.0)
    order = field.ranked()
    view = rated.ratings.positions - target.position
    distance = np.linalg.norm(view, axis=1)
    angle = np.degrees(np.arccos(view[:, 2] / distance))
    allowed = np.flatnonzero((distance >= CAMERA.near) & (distance <= CAMERA.far)
                             & (angle <= 45.0))
    assert sorted(order) == sorted(allowed) and len(order) > 100
    assert not np.array_equal(order, np.sort(order))  # shuffled
    assert np.array_equal(order, informed_random(rated, [target], CAMERA,
                                                 np.random.default_rng(3), 45.0).ranked())
    assert (rated.ratings.tfv[order] < 1).any()  # it tries views the beam (partly) hides
    assert field.strategy == "informed_random" and (field.target[order] == 0).all()


def _brute_force_views(g: OccupancyGrid, region: Region, targets: list[TargetModel],
                       max_angle_deg: float) -> dict[tuple[float, ...], int]:
    """Every voxel centre of ``g`` in ``region`` that sees a target within the angle
    bound, with the first such target, by a loop over the voxels."""
    out = {}
    for c in g.centers().reshape(-1, 3):
        if not region.z_min <= c[2] <= region.z_max:
            continue
        if region.within is not None and np.hypot(*(c[:2] - region.within[0])) > region.within[1]:
            continue
        if any(np.linalg.norm(c - np.array(p)) < r for p, r in region.keep_out):
            continue
        for k, t in enumerate(targets):
            v = c - t.position
            d = np.linalg.norm(v)
            if d > 0 and math.degrees(math.acos(min(1.0, v @ t.normal / d))) <= max_angle_deg:
                out[tuple(np.round(c, 9))] = k
                break
    return out


def test_biased_random_draws_every_view_in_the_region_and_angle_bound():
    """The paper's baseline: the voxel centres it draws are exactly those of the region
    within the angle of a target's normal (brute force over the grid), each aimed at the
    first target it qualifies for, free, occupied or never observed alike; the same
    generator gives the same order, another generator another."""
    targets = [TargetModel("p", np.array([0.0, 0.0, 0.2]), UP, 0.02),
               TargetModel("s", np.array([0.6, 0.0, 0.2]), np.array([1.0, 0.0, 0.0]), 0.02)]
    g = free_grid(res=0.1)
    occupy(g, (-1, -1, 0), (1, 1, 0.2))  # the table top
    occupy(g, (-0.3, -1, 0.6), (0.3, 1, 0.7))  # a beam over the primary target
    never_seen = g.centers()[..., 1] > 0.5
    g.set_probability(0.5, never_seen)
    region = Region(0.3, 1.6, (((-0.5, -0.5, 1.0), 0.3),), ((0.2, 0.0), 0.9))
    positions, aims = biased_random(g, region, targets, np.random.default_rng(7), 50.0)
    expected = _brute_force_views(g, region, targets, 50.0)
    drawn = {tuple(np.round(p, 9)): int(k) for p, k in zip(positions, aims, strict=True)}
    assert drawn == expected and len(drawn) == len(positions) > 50
    assert set(aims.tolist()) == {0, 1}
    p_drawn = g.probability_at(positions)
    assert (p_drawn > 0.9).any()  # the beam's voxels
    assert (np.abs(p_drawn - 0.5) < 0.01).any()  # never observed
    assert (p_drawn < 0.1).any()  # known free
    again, _ = biased_random(g, region, targets, np.random.default_rng(7), 50.0)
    other, _ = biased_random(g, region, targets, np.random.default_rng(8), 50.0)
    assert np.array_equal(positions, again) and not np.array_equal(positions, other)


def test_biased_random_ignores_occlusion_entirely():
    """What the map holds does not change what it draws, nor in which order: a wall over
    the target, or none."""
    target = TargetModel("t", np.array([0.0, 0.0, 0.2]), UP, 0.02)
    region = Region(0.3, 1.6)
    clear = free_grid(res=0.1)
    walled = free_grid(res=0.1)
    occupy(walled, (-1, -1, 0.5), (1, 1, 0.6))  # a ceiling between target and cameras
    a = biased_random(clear, region, [target], np.random.default_rng(1), 60.0)
    b = biased_random(walled, region, [target], np.random.default_rng(1), 60.0)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_the_papers_biased_random_chooses_without_the_rating_function():
    """As a registered method it never asks for the rating function's field: its draws
    are rated only for the record, each for the target it is aimed at, and tried in the
    order drawn."""
    targets = (TargetModel("p", np.array([0.0, 0.0, 0.2]), UP, 0.02),
               TargetModel("s", np.array([0.5, 0.0, 0.2]), UP, 0.02, st_error=0.0005))
    g = free_grid(res=0.1)
    occupy(g, (-1, -1, 0), (1, 1, 0.2))
    region = Region(0.3, 1.6)

    def refuse() -> None:
        raise AssertionError("the rating function's field was asked for")

    def rate(positions: np.ndarray, aims: np.ndarray):
        return rate_positions(g, targets, CAMERA, positions, g.probability_at(positions),
                              aims=aims)

    given = MethodInput(targets, 0, CAMERA, g, region, np.zeros(2), 1.0,
                        np.random.default_rng(4), MethodSettings(random_max_angle_deg=50.0),
                        refuse, rate, refuse)
    field = METHODS["biased_random"].choose(given)
    positions, aims = biased_random(g, region, targets, np.random.default_rng(4), 50.0)
    assert np.array_equal(field.ratings.positions, positions)
    assert np.array_equal(field.target, aims) and np.array_equal(field.ranked(),
                                                                np.arange(len(positions)))
    for k, target in enumerate(targets):  # each rated for its own target
        mine = aims == k
        alone = rate_positions(g, [target], CAMERA, positions[mine],
                               g.probability_at(positions[mine]))
        assert np.allclose(field.ratings.total[mine], alone.ratings.total)


def test_placement_methods_are_found_by_name():
    """The built-in methods by name, a user's by "module:callable"; what is wrong with a
    bad name is said."""
    assert {"rating", "biased_random", "informed_random", "information_gain"} <= set(METHODS)
    assert method_named("biased_random") is METHODS["biased_random"]
    assert not METHODS["biased_random"].detectable_only
    assert not METHODS["biased_random"].site_in_frame
    own = method_named("taskcam.placement.methods:by_rating")
    assert own.choose is METHODS["rating"].choose and not own.detectable_only
    assert "unknown" in method_problem("nope")
    assert "not importable" in method_problem("no_such_module_here:f")
    assert "has no" in method_problem("taskcam.placement.methods:no_such_name")
    assert "not callable" in method_problem("taskcam.placement.methods:ACCEPTED")
    assert method_problem("rating") is None


def test_look_at_points_the_optical_axis_at_the_target():
    T = look_at(np.array([1.0, 0.5, 1.2]), np.array([0.0, 0.0, 0.2]))
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    expected = np.array([-1.0, -0.5, -1.0]) / 1.5
    assert np.allclose(R[:, 2], expected)  # +z forward (OpenCV)
    assert R[2, 0] == pytest.approx(0.0)  # x horizontal
    assert R[2, 1] < 0  # +y, image down, points down in the world
    straight_down = look_at(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert np.allclose(straight_down[:3, 2], [0, 0, -1])


def test_next_best_view_prefers_views_into_the_unknown_by_expected_information():
    """Candidates are ordered by the expected entropy gain of a view at the target from
    there, checked against the gain model directly; views looking across the target
    into a never-observed side come before views looking away from it."""
    target = TargetModel("t", np.array([0.0, 0.0, 0.2]), UP, 0.02)
    g = free_grid(res=0.1)
    occupy(g, (-1, -1, 0), (1, 1, 0.1))
    g.set_probability(0.5, np.broadcast_to(  # the x > 0.3 side was never observed
        (g.centers()[..., 0] > 0.3), g.shape))
    rated = search(g, [target], CAMERA)
    camera = Pinhole.from_fovy(math.radians(60), 64, 48)
    interest = region_mask(g, target.position, np.array([1.0, 1.0, 1.0]))
    gains = GainModel(g, camera, interest, max_range=3.0, stride=4)
    field = information_gain(rated, 0, target.position, gains, np.random.default_rng(5), 60)
    order = field.ranked()
    assert len(order) == 60 and len(set(order.tolist())) == 60
    direct = gains.gains([View(look_at(p, target.position))
                          for p in rated.ratings.positions[order]])
    assert np.all(np.diff(direct) <= 1e-9)  # best first
    x = rated.ratings.positions[order, 0]
    assert x[:10].mean() < -0.5 < x[-10:].mean()  # from -x, looking towards +x, first
    again = information_gain(rated, 0, target.position, gains, np.random.default_rng(5), 60)
    assert np.array_equal(order, again.ranked()) and field.strategy == "information_gain"
