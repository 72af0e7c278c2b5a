"""Natural fiducials: stereo disparity on rendered pairs, the evaluation function's pick,
and the bundle adjustment of stereo keyframes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration import to_gray
from calibration.bundle import Keyframe, refine, triangulate
from calibration.ekf import StereoCamera
from calibration.fiducials import Candidate, corners, disparity, pick
from sim import build_scene, load_scenario
from sim.render import Renderer, camera_pinhole


def test_disparity_of_rendered_corners_matches_the_rendered_depth():
    s = load_scenario()
    scene = build_scene(s)
    data = scene.make_data()
    robot = scene.robots[0]
    pinhole = camera_pinhole(scene.model, robot.camera)
    with Renderer(scene.model, pinhole.width, pinhole.height) as r:
        left, right = r.rgb(data, robot.camera), r.rgb(data, robot.right_camera)
        depth = r.depth(data, robot.camera)
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


def triangulate_all(cam: StereoCamera, key: Keyframe) -> np.ndarray:
    return np.array([triangulate(cam, z, key.g01) for _, z in sorted(key.observations.items())])
