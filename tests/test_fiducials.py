"""Natural fiducials: the evaluation function's terms (eq. 8-9) and pick, and the bundle
adjustment of stereo keyframes (its Jacobian and its pose covariance)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.calibration.bundle import (
    BundleProblem,
    Keyframe,
    marginal_pose_covariance,
    refine,
    triangulate,
)
from taskcam.calibration.ekf import StereoCamera
from taskcam.calibration.fiducials import (
    Candidate,
    certainty,
    depth_contrast,
    pick,
    visual_contrast,
)
from taskcam.mapping import OccupancyGrid, SensorModel


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


def test_bundle_pose_covariance_is_the_pose_block_of_the_whole_inverse():
    """The Schur complement of the fiducials' blocks, inverted, is the poses' block of
    the inverse of the whole JᵀJ (brute force): three frames, two of them free."""
    rng = np.random.default_rng(7)
    cam, keyframes, start, g1 = _two_views(rng, 0.3)
    third = g1.copy()
    third[:3, 3] += [0.05, 0.0, -0.02]
    c = start @ third[:3, :3].T + third[:3, 3]
    keyframes.append(Keyframe(third, {i: cam.measure(p) for i, p in enumerate(c[::2])}))
    problem = BundleProblem(cam, keyframes, start, 0.3)
    J = problem.jacobian(problem.x0)
    whole = np.linalg.inv((J.T @ J).toarray())[:problem.n_pose, :problem.n_pose]
    assert problem.n_pose == 12
    assert np.allclose(marginal_pose_covariance(J, problem.n_pose), whole, rtol=1e-6,
                       atol=1e-9 * np.abs(whole).max())


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




