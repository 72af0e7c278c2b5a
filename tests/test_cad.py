"""The map updated from a moving object's CAD model (sec. 3, steps 1-4), against brute
force and by hand."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.mapping import OccupancyGrid
from taskcam.mapping.cad import BoxModel, fit_model, move_object, to_object, voxels_of

PANEL = BoxModel(np.array([[0.0, 0.0, 0.075]]), np.array([[0.005, 0.1, 0.075]]))


def pose(x: float, y: float, z: float, yaw_deg: float = 0.0, tilt_deg: float = 0.0
         ) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zx", [yaw_deg, tilt_deg], degrees=True).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def test_distance_by_hand():
    box = BoxModel(np.zeros((1, 3)), np.array([[1.0, 2.0, 3.0]]))
    points = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 3.0, 0.0], [0.5, 0.0, 0.0]])
    assert box.distance(points) == pytest.approx([-1.0, 1.0, np.sqrt(2.0), -0.5])
    assert PANEL.size == pytest.approx(0.2)


def test_union_of_boxes_distance_matches_each_box_alone():
    """The compiled distance of three overlapping boxes equals the smallest of each box's
    own signed distance (outside: the norm of the excess; inside: minus the depth)."""
    rng = np.random.default_rng(3)
    centres, halves = rng.normal(0.0, 0.05, (3, 3)), rng.uniform(0.01, 0.08, (3, 3))
    points = rng.normal(0.0, 0.1, (4000, 3))
    excess = np.abs(points[:, None, :] - centres) - halves  # (n, boxes, 3)
    each = (np.linalg.norm(np.maximum(excess, 0.0), axis=2)
            + np.minimum(excess.max(axis=2), 0.0))
    d, g = BoxModel(centres, halves).distance_and_gradient(points)
    assert d == pytest.approx(each.min(axis=1), abs=1e-15)
    assert np.linalg.norm(g, axis=1) == pytest.approx(1.0)


def test_voxels_of_match_brute_force_sampling():
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), 0.05)
    at = pose(0.43, 0.51, 0.2, yaw_deg=30.0)
    mask = voxels_of(grid, PANEL, at)
    # brute force: a voxel is touched when the model passes within half its diagonal
    centres = grid.centers().reshape(-1, 3)
    expected = PANEL.distance(to_object(at, centres)) <= 0.5 * np.sqrt(3) * 0.05
    assert np.array_equal(mask.ravel(), expected)
    assert mask.sum() > 10
    # every point of the panel's surface lies in a marked voxel
    rng = np.random.default_rng(0)
    local = rng.uniform(-1, 1, (2000, 3)) * PANEL.halves[0] + PANEL.centres[0]
    world = local @ at[:3, :3].T + at[:3, 3]
    assert mask[tuple(grid.index(world).T)].all()


def test_moving_the_object_leaves_no_stale_voxels_and_marks_the_new_place():
    grid = OccupancyGrid.from_bounds(np.zeros(3), np.ones(3), 0.05)
    grid.set_probability(0.2)  # known free
    old, new = pose(0.3, 0.3, 0.1), pose(0.7, 0.6, 0.3, yaw_deg=45.0)
    move_object(grid, PANEL, None, old)
    assert (grid.probability()[voxels_of(grid, PANEL, old)] > 0.9).all()
    freed, occupied = move_object(grid, PANEL, old, new)
    p = grid.probability()
    assert freed > 0 and occupied > 0
    now = voxels_of(grid, PANEL, new)
    assert (p[now] > 0.9).all()
    assert (p[~now] < 0.5).all()  # nothing left where the panel used to be


def test_fit_recovers_the_pose_from_surface_points():
    rng = np.random.default_rng(1)
    truth = pose(0.4, -0.2, 0.55, yaw_deg=12.0, tilt_deg=3.0)
    # points on the two large faces and the bottom edge region, as a camera would see
    local = np.column_stack([rng.choice([-0.005, 0.005], 600), rng.uniform(-0.1, 0.1, 600),
                             rng.uniform(0.0, 0.15, 600)])
    edge = np.column_stack([rng.uniform(-0.005, 0.005, 100), rng.uniform(-0.1, 0.1, 100),
                            np.zeros(100)])
    side = np.column_stack([rng.uniform(-0.005, 0.005, 100), np.full(100, 0.1),
                            rng.uniform(0.0, 0.15, 100)])
    local = np.vstack([local, edge, side])
    world = local @ truth[:3, :3].T + truth[:3, 3] + rng.normal(0, 0.001, local.shape)
    start = pose(0.43, -0.17, 0.53, yaw_deg=5.0)  # 4 cm and 7 degrees off
    found, rms = fit_model(PANEL, world, start)
    assert np.linalg.norm(found[:3, 3] - truth[:3, 3]) < 0.003
    angle = Rotation.from_matrix(found[:3, :3].T @ truth[:3, :3]).magnitude()
    assert np.degrees(angle) < 1.0
    assert rms < 0.002


def test_a_hopeless_fit_stops_after_its_coarse_stage_and_a_good_one_is_refined():
    """Points scattered a decimetre around the model stay far from it after the coarse
    stage: with a 2 cm limit the fit ends there (as a coarse-only fit); points on the
    surface pass the limit and get the fine stage (as a fit without one)."""
    rng = np.random.default_rng(4)
    start = pose(0.4, -0.2, 0.55)
    scattered = start[:3, 3] + rng.normal(0.0, 0.1, (400, 3))
    coarse_only = fit_model(PANEL, scattered, start, loss_scales_m=(0.02,))
    stopped = fit_model(PANEL, scattered, start, give_up_median_m=0.02)
    assert np.median(np.abs(PANEL.distance(to_object(stopped[0], scattered)))) > 0.02
    assert np.array_equal(stopped[0], coarse_only[0]) and stopped[1] == coarse_only[1]
    local = np.column_stack([rng.choice([-0.005, 0.005], 400), rng.uniform(-0.1, 0.1, 400),
                             rng.uniform(0.0, 0.15, 400)])
    surface = local + pose(0.41, -0.2, 0.55, yaw_deg=3.0)[:3, 3]
    refined = fit_model(PANEL, surface, start, give_up_median_m=0.02)
    assert np.array_equal(refined[0], fit_model(PANEL, surface, start)[0])


def test_analytic_jacobian_matches_finite_differences():
    """The fit's Jacobian (rotation vector on the left, then translation) against
    central differences, for a two-box model, points inside and outside, and the
    one-sided 'ahead' residuals."""
    from taskcam.mapping.cad import fit_residuals, pose_left_jacobian

    model = BoxModel(np.array([[0.0, 0.0, 0.075], [0.05, 0.0, 0.02]]),
                     np.array([[0.005, 0.1, 0.075], [0.01, 0.02, 0.02]]))
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.15, 0.2, (300, 3))
    ahead = points + rng.normal(0.0, 0.01, points.shape)
    R0, t0 = Rotation.from_rotvec([0.2, -0.1, 0.3]), np.array([0.01, 0.02, -0.03])

    def pose_of(x: np.ndarray) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = (Rotation.from_rotvec(x[:3]) * R0).as_matrix()
        T[:3, 3] = t0 + x[3:]
        return T

    for x in (np.zeros(6), np.array([0.1, -0.2, 0.15, 0.01, 0.0, -0.02])):
        step = 1e-7
        numeric = np.column_stack([
            (fit_residuals(model, pose_of(x + e), points, ahead)[0]
             - fit_residuals(model, pose_of(x - e), points, ahead)[0]) / (2 * step)
            for e in step * np.eye(6)])
        analytic = fit_residuals(model, pose_of(x), points, ahead)[1] @ pose_left_jacobian(x[:3])
        assert np.abs(numeric).max() > 0.5
        # equal but for the few points within a step of a kink (an edge or the surface)
        close = np.all(np.abs(numeric - analytic) < 1e-6, axis=1)
        assert close.mean() > 0.97


def test_gradient_points_away_from_the_box_by_hand():
    box = BoxModel(np.zeros((1, 3)), np.array([[1.0, 2.0, 3.0]]))
    d, g = box.distance_and_gradient(np.array([[2.0, 0.0, 0.0], [0.5, 0.0, 0.0],
                                               [2.0, 3.0, 0.0], [0.0, -1.5, 0.0]]))
    assert d == pytest.approx([1.0, -0.5, np.sqrt(2.0), -0.5])
    assert g == pytest.approx(np.array([[1, 0, 0], [1, 0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0],
                                        [0, -1, 0]]))
