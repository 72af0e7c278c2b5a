"""The CAD update as the paper describes it (sec. 3, steps 1-4): the pose the object lies
at comes from the map (mapping/cad_prior.py), and the voxels written for a pose carry its
uncertainty (mapping/cad.py, occupancy_of and move_object), against hand calculations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.mapping import MappingError, OccupancyGrid
from taskcam.mapping.cad import (
    BoxModel,
    fit_model,
    move_object,
    occupancy_of,
    pose_covariance,
    voxels_of,
)
from taskcam.mapping.cad_prior import (
    PLANAR,
    Misplacement,
    fit_lying_pose,
    lying_pose,
    quantisation_sd,
    support_layer,
)
from taskcam.mapping.grid import stored_log_odds

PANEL = BoxModel(np.array([[0.0, 0.0, 0.075]]), np.array([[0.005, 0.1, 0.075]]))
RES = 0.05
REACH = 0.5 * math.sqrt(3) * RES  # a voxel is touched by a model this close to its centre


def pose(x: float, y: float, z: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def yaw_of(T: np.ndarray) -> float:
    return math.degrees(math.atan2(T[1, 0], T[0, 0]))


def mapped(truth: np.ndarray, *others: tuple[BoxModel, np.ndarray]) -> OccupancyGrid:
    """A mapped scene as the grid's own voxelisation: the floor's layer and the panel's
    voxels (and those of ``others``) occupied, the rest observed free."""
    grid = OccupancyGrid.from_bounds(np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 0.5]), RES)
    grid.set_probability(0.3)
    grid.set_probability(0.9, voxels_of(grid, PANEL, truth) | support_layer(grid, 0.0))
    for model, at in others:
        grid.set_probability(0.9, voxels_of(grid, model, at))
    return grid


# ------------------------------------------------------------ the pose where it lies


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 45.0, 60.0])
@pytest.mark.parametrize("off", [(0.04, -0.02, 10.0), (-0.03, -0.03, -10.0), (0.0, 0.045, 8.0)])
def test_fit_recovers_a_pose_standing_on_a_grid_vertex(yaw_deg, off):
    """The panel's bottom-edge centre on a grid vertex: its voxels (and the floor's) are
    symmetric under a half turn about the vertical through it, and so is the panel, so
    the fitted place is the true one, to the solver (2 mm), from a nominal 4-5 cm and
    8-10 deg off. The yaw is quantised: within the floor the covariance states for it,
    sqrt(2) sigma_q / length = 5.8 deg; and within two stated standard deviations."""
    truth = pose(0.1, -0.05, yaw_deg=yaw_deg)
    grid = mapped(truth)
    dx, dy, dyaw = off
    found, why = fit_lying_pose(grid, PANEL, pose(0.1 + dx, -0.05 + dy, yaw_deg=yaw_deg + dyaw))
    assert found is not None, why
    assert found.source == "map" and found.voxels >= 20 and found.support_z == 0.0
    error = found.pose[:3, 3] - truth[:3, 3]
    assert np.abs(error).max() < 0.002
    floor = math.degrees(math.sqrt(2) * quantisation_sd(grid) / 0.2)
    assert floor == pytest.approx(5.85, abs=0.01)
    assert abs(yaw_of(found.pose) - yaw_deg) < floor
    assert abs(yaw_of(found.pose) - yaw_deg) < 2 * math.degrees(found.yaw_sd_rad)
    # height and tilt are not fitted: the nominal's (resting on the floor)
    assert found.pose[2, 3] == 0.0
    assert found.pose[:3, 2] == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)


def test_fit_at_random_places_is_within_the_quantisation():
    """Anywhere, at any yaw, nominal up to 5 cm and 10 deg off: the voxels pin the
    place to half a voxel per axis (every centre within half a voxel, per axis, of a
    point of the panel) and the yaw to atan(res / length) = 14 deg (its ends each half a
    voxel off, oppositely); the stated standard deviations cover the errors."""
    rng = np.random.default_rng(11)
    errors, sds = [], []
    for _ in range(20):
        truth = pose(*rng.uniform(-0.2, 0.2, 2), yaw_deg=rng.uniform(-180, 180))
        off = rng.normal(size=2)
        off *= rng.uniform(0.0, 0.05) / np.linalg.norm(off)
        nominal = pose(*(truth[:2, 3] + off), yaw_deg=yaw_of(truth) + rng.uniform(-10, 10))
        found, why = fit_lying_pose(mapped(truth), PANEL, nominal)
        assert found is not None, why
        turn = (yaw_of(found.pose) - yaw_of(truth) + 180) % 360 - 180
        errors.append([*(found.pose[:2, 3] - truth[:2, 3]), turn])
        sds.append([*found.position_sd_m[:2], math.degrees(found.yaw_sd_rad)])
    e, s = np.abs(np.array(errors)), np.array(sds)
    assert e[:, :2].max() <= RES / 2
    assert e[:, 2].max() <= math.degrees(math.atan(RES / 0.2))
    assert np.all(e <= 2.5 * s)


def test_a_post_beside_the_panel_does_not_pull_the_fit():
    """A post 15 cm beyond the panel's end, the nominal 4 cm toward it: the post's
    voxels nearest the panel (centres at x = 0.325) lie within the search margin (0.111 m
    of the model at the nominal, whose end is at 0.24), but the search's pose passes
    nearer the panel's, and the fit uses only the voxels near that pose: none of the
    post's. (Nearer, within about the misplacement plus two voxels, a neighbour can win:
    a pose that shifts the panel's end into the post's first column explains as many
    voxels as the true one.)"""
    truth = pose(0.1, -0.05, yaw_deg=90.0)  # the panel along x, its end at x = 0.2
    post = BoxModel(np.array([[0.0, 0.0, 0.3]]), np.array([[0.04, 0.04, 0.3]]))
    grid = mapped(truth, (post, pose(0.39, -0.05)))
    centres = grid.centers(np.argwhere((grid.states() == 1) & ~support_layer(grid, 0.0)))
    assert np.any((centres[:, 0] > 0.3) & (centres[:, 0] < 0.24 + 0.111))
    found, why = fit_lying_pose(grid, PANEL, pose(0.14, -0.05, yaw_deg=90.0))
    assert found is not None, why
    alone, _ = fit_lying_pose(mapped(truth), PANEL, pose(0.14, -0.05, yaw_deg=90.0))
    assert alone is not None
    assert found.voxels == alone.voxels
    assert np.abs(found.pose[:3, 3] - truth[:3, 3]).max() < 0.002


def test_an_unmapped_place_gives_no_fit_and_the_nominal_with_its_uncertainty():
    grid = OccupancyGrid.from_bounds(np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 0.5]), RES)
    nominal = pose(0.1, -0.05, yaw_deg=20.0)
    found, why = fit_lying_pose(grid, PANEL, nominal)
    assert found is None
    touched = int((voxels_of(grid, PANEL, nominal) & ~support_layer(grid, 0.0)).sum())
    assert "0 occupied voxels" in why
    assert f"of the {touched} voxels the model touches there {touched} were never observed" in why
    fallback = lying_pose(grid, PANEL, nominal)
    assert fallback.source == "nominal" and fallback.why == why
    assert np.array_equal(fallback.pose, nominal) and fallback.support_z == 0.0
    # uniformly within 5 cm and 10 deg: standard deviations bound / sqrt(3)
    assert fallback.position_sd_m[:2] == pytest.approx([0.05 / math.sqrt(3)] * 2)
    assert math.degrees(fallback.yaw_sd_rad) == pytest.approx(10 / math.sqrt(3))


def test_a_nominal_pose_outside_the_grid_says_so():
    grid = mapped(pose(0.1, -0.05))
    found, why = fit_lying_pose(grid, PANEL, pose(2.0, 0.0))
    assert found is None and "outside the grid" in why
    assert lying_pose(grid, PANEL, pose(2.0, 0.0)).source == "nominal"


def test_the_floor_alone_is_not_the_panel():
    """Only the floor's layer occupied: its voxels are the support's, left out."""
    grid = OccupancyGrid.from_bounds(np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 0.5]), RES)
    grid.set_probability(0.3)
    grid.set_probability(0.9, support_layer(grid, 0.0))
    found, why = fit_lying_pose(grid, PANEL, pose(0.1, -0.05))
    assert found is None and "0 occupied voxels" in why


def test_support_layer_by_hand():
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.array([0.1, 0.1, 0.2]), RES)
    layers = support_layer(grid, 0.0)[0, 0]  # bottoms 0, 0.05, 0.10, 0.15
    assert layers.tolist() == [True, False, False, False]
    assert support_layer(grid, 0.045)[0, 0].tolist() == [True, True, False, False]


def test_planar_fit_leaves_height_and_tilt_alone():
    rng = np.random.default_rng(2)
    tilted = pose(0.0, 0.0, 0.02, yaw_deg=5.0)
    tilted[:3, :3] = Rotation.from_euler("x", 4, degrees=True).as_matrix() @ tilted[:3, :3]
    points = rng.uniform(-0.1, 0.1, (200, 3))
    found, _ = fit_model(PANEL, points, tilted, free=PLANAR)
    assert found[2, 3] == tilted[2, 3]
    # the rotation changed only about the world's vertical
    relative = Rotation.from_matrix(found[:3, :3] @ tilted[:3, :3].T).as_rotvec()
    assert relative[:2] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_misplacement_is_checked():
    with pytest.raises(MappingError, match="misplacement"):
        Misplacement(-0.01, 0.1)


# ------------------------------------------------------------ voxels with uncertainty


def big_box_grid() -> tuple[OccupancyGrid, BoxModel]:
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    return grid, BoxModel(np.zeros((1, 3)), np.full((1, 3), 0.1))


def old_move(grid: OccupancyGrid, model: BoxModel, old: np.ndarray | None,
             new: np.ndarray | None) -> None:
    """The certain update as it was: clamp_min on the old pose's voxels, clamp_max on
    the new's."""
    if old is not None:
        grid.set_probability(grid.model.clamp_min, voxels_of(grid, model, old))
    if new is not None:
        grid.set_probability(grid.model.clamp_max, voxels_of(grid, model, new))


@pytest.mark.parametrize("covariance", [None, np.zeros((6, 6))])
def test_zero_uncertainty_is_the_old_update_exactly(covariance):
    rng = np.random.default_rng(5)
    old, new = pose(0.3, 0.3, 0.1, yaw_deg=10.0), pose(0.35, 0.32, 0.1, yaw_deg=40.0)
    a = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    a.log_odds[...] = rng.integers(-1990, 3476, a.shape)  # anything within the clamps
    b = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    b.log_odds[...] = a.log_odds
    freed, occupied = move_object(a, PANEL, old, new, covariance, covariance)
    old_move(b, PANEL, old, new)
    assert np.array_equal(a.log_odds, b.log_odds)
    assert freed == voxels_of(a, PANEL, old).sum() and occupied == voxels_of(a, PANEL, new).sum()


def test_uncertain_voxels_by_hand_across_a_face():
    """A 0.2 m cube whose +x face lies exactly reach (half a voxel diagonal) short of the
    voxel centres at x = 0.675: with a position standard deviation of 2 cm those centres
    are at P = Phi(0) = 0.5, and the neighbours a voxel (2.5 sd) either side at
    Phi(+-2.5) = 0.99379, 0.00621; the next one out, 5 sd, is left alone."""
    grid, box = big_box_grid()
    at = pose(0.675 - REACH - 0.1, 0.525, 0.525)
    row = [(12, 10, 10), (13, 10, 10), (14, 10, 10)]  # centres x = 0.625, 0.675, 0.725
    shift = pose_covariance(0.02, 0.0)
    idx, p = occupancy_of(grid, box, at, shift)
    where = {tuple(i): v for i, v in zip(idx.tolist(), p, strict=True)}
    assert [where[r] for r in row] == pytest.approx([0.99379, 0.5, 0.00621], abs=1e-5)
    assert where[row[1]] == pytest.approx(0.5, abs=1e-12)
    assert (15, 10, 10) not in where  # Phi(-5): beyond SPREAD_SDS
    outward = [where[(k, 10, 10)] for k in range(10, 15)]  # from the cube's centre out
    assert np.all(np.diff(outward) < 0)
    # written into a free map: clipped to the clamps, 0.5 stored as log-odds 0
    grid.set_probability(grid.model.clamp_min)
    move_object(grid, box, None, at, new_covariance=shift)
    stored = grid.probability()
    assert [stored[r] for r in row] == pytest.approx(
        [grid.model.clamp_max, 0.5, grid.model.clamp_min], abs=1e-3)
    assert grid.log_odds[row[1]] == 0


def test_a_rotation_spreads_by_its_lever_arm_by_hand():
    """A rotation sd of 0.2 rad about the vertical moves the +x face by 0.2 x (lever arm
    along y): at 0.1 m from the pose's origin that is 2 cm, the spread of the test
    above; at 0.2 m, 4 cm: P = Phi(+-0.05 / 0.04) = 0.89435, 0.10565 a voxel either side
    of the boundary; on the origin's line, none: inside 1, a voxel out nothing."""
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    long_box = BoxModel(np.zeros((1, 3)), np.array([[0.1, 0.3, 0.1]]))
    at = pose(0.675 - REACH - 0.1, 0.425, 0.525)  # centres y 0.425 + 0.1, + 0.2
    idx, p = occupancy_of(grid, long_box, at, pose_covariance(0.0, np.array([0.0, 0.0, 0.2])))
    where = {tuple(i): v for i, v in zip(idx.tolist(), p, strict=True)}
    assert [where[(k, 10, 10)] for k in (12, 13, 14)] == pytest.approx(
        [0.99379, 0.5, 0.00621], abs=1e-5)
    assert [where[(k, 12, 10)] for k in (12, 13, 14)] == pytest.approx(
        [0.89435, 0.5, 0.10565], abs=1e-5)
    assert where[(12, 8, 10)] == pytest.approx(1.0) and (14, 8, 10) not in where


def test_freeing_lowers_by_the_old_pose_s_probability_by_hand():
    """After freeing, P = p_old clamp_min + (1 - p_old) P_before: the certain inside goes
    to clamp_min, the boundary (p_old = 0.5) from 0.97 to 0.545, the far unchanged."""
    grid, box = big_box_grid()
    at = pose(0.675 - REACH - 0.1, 0.525, 0.525)
    grid.set_probability(grid.model.clamp_max)
    before = grid.log_odds.copy()
    freed, occupied = move_object(grid, box, at, None, old_covariance=pose_covariance(0.02, 0.0))
    p = grid.probability()
    assert p[10, 10, 10] == pytest.approx(grid.model.clamp_min, abs=1e-3)  # the centre
    assert p[13, 10, 10] == pytest.approx(0.5 * 0.12 + 0.5 * 0.97, abs=1e-3)
    assert grid.log_odds[18, 10, 10] == before[18, 10, 10]  # 0.3 m beyond the face
    assert occupied == 0 and freed == np.sum(occupancy_of(
        grid, box, at, pose_covariance(0.02, 0.0))[1] >= 0.5)


def test_freeing_then_occupying_an_overlapping_pose_keeps_the_new_voxels():
    """The panel moves 3 cm and turns 5 deg, both poses uncertain: every voxel the new
    pose touches with probability p ends at least at p (clipped), those it more likely
    than not touches are occupied; voxels only the old pose had are lowered."""
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    grid.set_probability(0.3)
    old, new = pose(0.5, 0.5, 0.3), pose(0.53, 0.5, 0.3, yaw_deg=5.0)
    old_c, new_c = pose_covariance(0.01, math.radians(3)), pose_covariance(0.005, math.radians(1))
    move_object(grid, PANEL, None, old, new_covariance=old_c)
    move_object(grid, PANEL, old, new, old_c, new_c)
    p = grid.probability()
    idx, p_new = occupancy_of(grid, PANEL, new, new_c)
    lo, hi = grid.model.clamp_min, grid.model.clamp_max
    assert np.all(p[tuple(idx.T)] >= np.clip(p_new, lo, hi) - 1e-3)
    assert np.all(p[tuple(idx[p_new >= 0.5].T)] > 0.5)
    # voxels the old pose touched (p_old >= 0.5, occupied to that) and the new less
    # likely than clamp_min: at most max over p >= 0.5 of p clamp_min + (1 - p) p =
    # 0.3136 (p = 0.56)
    only_old = voxels_of(grid, PANEL, old) & ~voxels_of(grid, PANEL, new)
    only_old[tuple(idx[p_new >= lo].T)] = False
    assert only_old.sum() > 10 and np.all(p[only_old] < 0.3136 + 1e-3)


def test_kept_voxels_are_not_freed():
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), RES)
    grid.set_probability(0.9)
    floor = support_layer(grid, 0.0)
    move_object(grid, PANEL, pose(0.5, 0.5, 0.0), None, keep=floor)
    assert np.all(grid.log_odds[floor] == stored_log_odds(0.9))
    assert np.any(grid.log_odds[~floor] < stored_log_odds(0.9))


def test_a_covariance_is_six_by_six():
    grid, box = big_box_grid()
    with pytest.raises(MappingError, match="6x6"):
        occupancy_of(grid, box, pose(0.5, 0.5, 0.5), np.eye(3))
