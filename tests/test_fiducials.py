"""Natural fiducials: stereo disparity on rendered pairs, the evaluation function's pick,
and the bundle adjustment of stereo keyframes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration import to_gray
from calibration.bundle import BundleProblem, Keyframe, refine, triangulate
from calibration.ekf import StereoCamera
from calibration.fiducials import (
    Candidate,
    certainty,
    corners,
    depth_contrast,
    disparity,
    find_candidates,
    locate,
    pick,
    visual_contrast,
)
from mapping import OccupancyGrid, SensorModel, camera_to_world, opencv_pose
from sim import build_scene, load_scenario
from sim.render import Renderer, camera_pinhole, camera_pose


@pytest.fixture(scope="module")
def stereo_view():
    """Robot r1's stereo pair and depth at its start pose in the default scene."""
    s = load_scenario()
    scene = build_scene(s)
    data = scene.make_data()
    robot = scene.robots[0]
    pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        left, right = r.rgb(data, robot.camera), r.rgb(data, robot.right_camera)
        depth = r.depth(data, robot.camera)
    return s, pinhole, left, right, depth, opencv_pose(camera_pose(data, robot.camera))


@pytest.fixture(scope="module")
def rendered(stereo_view):
    """The pair, a grid marking the rendered surfaces occupied, and (u, v, d) -> world."""
    s, pinhole, left, right, depth, T = stereo_view
    grid = OccupancyGrid.from_bounds(np.array(s.grid.bounds_min), np.array(s.grid.bounds_max),
                                     0.05, SensorModel())
    grid.set_probability(0.01)
    surface = camera_to_world(T, pinhole.unproject(depth)[np.isfinite(depth)])
    idx = grid.index(surface)
    idx = idx[grid.inside(idx)]
    grid.set_probability(0.99, tuple(idx.T))
    stereo = StereoCamera(pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy, s.camera.baseline_m)
    return left, right, grid, lambda z: camera_to_world(T, stereo.point(z))


def test_disparity_of_rendered_corners_matches_the_rendered_depth(stereo_view):
    s, pinhole, left, right, depth, _ = stereo_view
    gl, gr = to_gray(left), to_gray(right)
    errors = []
    for uv in corners(gl, 2000, min_distance=4.0):
        d = disparity(gl, gr, uv)
        if d is None:
            continue
        u, v = np.rint(uv).astype(int)
        around = depth[v - 1:v + 2, u - 1:u + 2]  # the nearest surface at the corner
        z = pinhole.fx * s.camera.baseline_m / d
        errors.append(np.min(np.abs(z - around[np.isfinite(around)])) / z)
    assert len(errors) >= 4, len(errors)  # few: this scene has little surface texture
    assert np.median(errors) < 0.01  # better than 1 % of the depth
    assert np.max(errors) < 0.05


def test_pick_prefers_the_best_and_spreads_the_rest():
    rng = np.random.default_rng(0)
    cands = [Candidate(rng.uniform(0, 640, 2), 10.0, 0, 0, 0, float(rng.uniform()))
             for _ in range(200)]
    best = max(cands, key=lambda c: c.rating)
    spread = pick(cands, 15, spacing_px=60.0)
    greedy = sorted(cands, key=lambda c: -c.rating)[:15]
    assert spread[0] is best and len(spread) == 15

    def closest(cs: list[Candidate]) -> float:
        p = np.array([c.pixel for c in cs])
        d = np.linalg.norm(p[:, None] - p[None], axis=2)
        return float(d[np.triu_indices(len(cs), 1)].min())

    assert closest(spread) > closest(greedy)


def test_bundle_adjustment_recovers_the_moved_camera():
    rng = np.random.default_rng(1)
    cam = StereoCamera(415.7, 415.7, 319.5, 239.5, 0.12)
    points = np.column_stack([rng.uniform(-0.6, 0.6, 40), rng.uniform(-0.4, 0.4, 40),
                              rng.uniform(1.0, 2.0, 40)])
    g0 = np.eye(4)  # the known keyframe: world = camera frame
    g1 = np.eye(4)  # the camera after the move: 10 degrees and 30 cm away
    g1[:3, :3] = Rotation.from_rotvec([0.05, -0.15, 0.08]).as_matrix()
    g1[:3, 3] = [0.3, -0.05, 0.1]
    sigma = 0.2

    def observe(g: np.ndarray) -> dict[int, np.ndarray]:
        c = points @ g[:3, :3].T + g[:3, 3]
        return {i: cam.measure(p) + rng.normal(0, sigma, 3) for i, p in enumerate(c)}

    k0, k1 = Keyframe(g0, observe(g0), known=True), observe(g1)
    start = triangulate_all(cam, k0)
    guess = g1.copy()  # the commanded pose: 3 cm and 2 degrees off
    guess[:3, :3] = Rotation.from_rotvec([0.0, 0.035, 0.0]).as_matrix() @ g1[:3, :3]
    guess[:3, 3] += [0.02, -0.02, 0.01]
    result = refine(cam, [k0, Keyframe(guess, k1)], start, sigma)
    found = result.poses[1]
    position = np.linalg.norm(np.linalg.inv(found)[:3, 3] - np.linalg.inv(g1)[:3, 3])
    angle = Rotation.from_matrix(found[:3, :3] @ g1[:3, :3].T).magnitude()
    assert position < 0.002 and np.degrees(angle) < 0.05
    assert result.rms_px == pytest.approx(sigma, rel=0.5)
    assert np.median(np.linalg.norm(result.points - points, axis=1)) < np.median(
        np.linalg.norm(start - points, axis=1))  # two views triangulate better than one


def _two_views(rng: np.random.Generator, sigma: float
               ) -> tuple[StereoCamera, list[Keyframe], np.ndarray, np.ndarray]:
    """Forty points seen from a known pose and from one 30 cm and 10 degrees away (whose
    start guess is 3 cm and 2 degrees off); the triangulated start points."""
    cam = StereoCamera(415.7, 415.7, 319.5, 239.5, 0.12)
    points = np.column_stack([rng.uniform(-0.6, 0.6, 40), rng.uniform(-0.4, 0.4, 40),
                              rng.uniform(1.0, 2.0, 40)])
    g1 = np.eye(4)
    g1[:3, :3] = Rotation.from_rotvec([0.05, -0.15, 0.08]).as_matrix()
    g1[:3, 3] = [0.3, -0.05, 0.1]

    def observe(g: np.ndarray) -> dict[int, np.ndarray]:
        c = points @ g[:3, :3].T + g[:3, 3]
        return {i: cam.measure(p) + rng.normal(0, sigma, 3) for i, p in enumerate(c)}

    k0 = Keyframe(np.eye(4), observe(np.eye(4)), known=True)
    guess = g1.copy()
    guess[:3, :3] = Rotation.from_rotvec([0.0, 0.035, 0.0]).as_matrix() @ g1[:3, :3]
    guess[:3, 3] += [0.02, -0.02, 0.01]
    return cam, [k0, Keyframe(guess, observe(g1))], triangulate_all(cam, k0), g1


def test_bundle_jacobian_matches_finite_differences():
    cam, keyframes, start, _ = _two_views(np.random.default_rng(4), 0.2)
    problem = BundleProblem(cam, keyframes, start, 0.2)
    x = problem.x0 + np.random.default_rng(5).normal(0, 1e-3, len(problem.x0))
    analytic = problem.jacobian(x).toarray()
    step = 1e-6
    numeric = np.column_stack([
        (problem.residuals(x + step * e) - problem.residuals(x - step * e)) / (2 * step)
        for e in np.eye(len(x))])
    assert np.abs(analytic - numeric).max() < 1e-4 * np.abs(numeric).max()


def test_bundle_pose_covariance_matches_the_scatter_of_repeated_solves():
    rng = np.random.default_rng(6)
    sigma, positions, reported = 0.3, [], []
    for _ in range(40):
        cam, keyframes, start, g1 = _two_views(rng, sigma)
        result = refine(cam, keyframes, start, sigma)
        positions.append(result.poses[1][:3, 3] - g1[:3, 3])
        reported.append(np.sqrt(np.diag(result.pose_cov[1])[3:]))
    scatter = np.std(positions, axis=0)
    ratio = scatter / np.mean(reported, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def triangulate_all(cam: StereoCamera, key: Keyframe) -> np.ndarray:
    return np.array([triangulate(cam, z, key.g01) for _, z in sorted(key.observations.items())])


def test_visual_contrast_by_hand():
    gray = np.full((100, 100), 0.5, dtype=np.float32)
    assert visual_contrast(gray, np.array([50.0, 50.0])) == 0.0
    gray[47:54, 47:54] = 0.2  # a dark 7 x 7 square around one bright pixel
    gray[50, 50] = 1.0
    # |C| grows for windows 3, 5, 7 (means 0.2889, 0.232, 0.2163) and falls at 9 (0.3284)
    mean7 = (48 * 0.2 + 1.0) / 49
    assert visual_contrast(gray, np.array([50.0, 50.0])) == pytest.approx(
        (1.0 - mean7) / mean7 * 7, rel=1e-5)


def _grid(fill: float) -> tuple[OccupancyGrid, np.ndarray]:
    g = OccupancyGrid.from_bounds(np.zeros(3), np.full(3, 1.0), 0.05, SensorModel())
    g.set_probability(fill)
    return g, g.probability()


def test_certainty_is_p_over_the_radius_of_falling_certainty():
    g, p = _grid(0.01)
    centre = np.array(g.shape) // 2
    point = g.centers(centre[None])[0]
    p[tuple(centre)] = 0.99
    assert certainty(g, p, point) == pytest.approx(0.99)  # all known around: r = 1
    r = np.rint(np.linalg.norm(np.indices(g.shape).transpose(1, 2, 3, 0) - centre, axis=3))
    p[:] = np.where(r <= 1, 0.99, np.where(r == 2, 0.7, 0.5))  # known, less so, unknown
    assert certainty(g, p, point) == pytest.approx(0.99 / 3)


def test_depth_contrast_rises_with_finer_structure():
    g, p = _grid(0.01)
    point = g.centers((np.array(g.shape) // 2)[None])[0]
    assert depth_contrast(g, p, point) == 0.0  # nothing but free space
    p[:, :, : g.shape[2] // 2] = 0.99  # a floor under the point
    step = depth_contrast(g, p, point)
    idx = np.indices(g.shape).sum(axis=0)
    p[:] = np.where(idx % 2 == 0, 0.99, 0.01)  # a voxel checkerboard
    assert depth_contrast(g, p, point) > step > 0.0


def test_locate_finds_a_shifted_patch_to_a_tenth_of_a_pixel():
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.uniform(0, 1, (120, 160)).astype(np.float32), (0, 0), 1.5)
    shifted = cv2.warpAffine(image, np.float32([[1, 0, 3.4], [0, 1, -2.2]]), (160, 120),
                             flags=cv2.INTER_CUBIC)
    template = image[73:88, 93:108]  # centred on (100, 80)
    found = locate(shifted, template, np.array([100.0, 80.0]), 8)
    assert found is not None and found[1] > 0.95
    assert np.allclose(found[0], [103.4, 77.8], atol=0.1)


def test_candidates_of_a_rendered_pair_are_measured_and_rated(rendered):
    left, right, grid, to_world = rendered
    found = find_candidates(left, right, grid, to_world)
    assert len(found) >= 3
    assert all(c.disparity > 0 and 0.0 <= c.rating <= 3.0 for c in found)
    for term in ("certainty", "contrast", "depth_contrast"):  # each scaled to [0, 1]
        values = [getattr(c, term) for c in found]
        assert max(values) > 0 or all(v == 0 for v in values)
    assert max(c.rating for c in found) > 1.0
