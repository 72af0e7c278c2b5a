"""Pose from fiducials (eq. 5-6, Kabsch, SQPnP), recursive statistics (eq. 7), the EKF."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.calibration.ekf import FiducialFilter, StereoCamera
from taskcam.calibration.pose import DegenerateGeometryError, estimate_pose, invert, linear_fit
from taskcam.calibration.stats import RunningPose

K = np.array([[415.7, 0.0, 319.5], [0.0, 415.7, 239.5], [0.0, 0.0, 1.0]])
CAMERA = StereoCamera(415.7, 415.7, 319.5, 239.5, 0.12)


def scene(rng: np.random.Generator, n: int = 12, flat: bool = False):
    """A random camera pose g01 and n fiducials 1-2 m in front of it."""
    g01 = np.eye(4)
    g01[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    g01[:3, 3] = rng.uniform(-1, 1, 3)
    cam = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n),
                           np.full(n, 1.5) if flat else rng.uniform(1.0, 2.0, n)])
    world = (cam - g01[:3, 3]) @ g01[:3, :3]  # g01^-1 applied to camera points
    pixels = cam @ K.T
    return g01, world, cam, pixels[:, :2] / pixels[:, 2:]


@pytest.mark.parametrize("method", ["linear", "kabsch", "sqpnp"])
def test_noise_free_points_give_the_exact_pose(method):
    rng = np.random.default_rng(1)
    for _ in range(5):
        g01, world, cam, pixels = scene(rng)
        est = estimate_pose(world, cam, pixels, K, method)
        assert est.method == method
        assert np.allclose(est.g01, g01, atol=1e-6)
        assert est.rms_px < 1e-4
        assert np.allclose(est.pose @ g01, np.eye(4), atol=1e-6)


def test_coplanar_points_make_the_linear_fit_report_the_degeneracy():
    rng = np.random.default_rng(2)
    g01, world, cam, pixels = scene(rng, flat=True)
    with pytest.raises(DegenerateGeometryError, match="lie in one plane"):
        linear_fit(world, cam)
    est = estimate_pose(world, cam, pixels, K, "linear")  # the fallback takes over
    assert est.method == "kabsch" and "one plane" in est.note
    assert np.allclose(est.g01, g01, atol=1e-6)
    with pytest.raises(DegenerateGeometryError, match="at least 3"):
        estimate_pose(world[:2], cam[:2], pixels[:2], K, "kabsch")


def test_noisy_fits_stay_close_and_improve_with_more_fiducials():
    rng = np.random.default_rng(3)
    errors = {8: [], 64: []}
    for n in errors:
        for _ in range(20):
            g01, world, cam, pixels = scene(rng, n)
            noisy = cam + rng.normal(0, 0.002, cam.shape)
            est = estimate_pose(world, noisy, pixels, K, "kabsch")
            errors[n].append(np.linalg.norm(invert(est.g01)[:3, 3] - invert(g01)[:3, 3]))
    assert np.median(errors[64]) < np.median(errors[8]) < 0.01


def test_recursive_statistics_equal_the_batch_ones():
    rng = np.random.default_rng(4)
    stats = RunningPose()
    Rs = Rotation.random(30, random_state=4).as_matrix()
    Xs = rng.normal(size=(30, 3))
    for R, X in zip(Rs, Xs, strict=True):
        stats.add(R, X)
    assert np.allclose(stats.mean_X, Xs.mean(axis=0))
    assert np.allclose(stats.cov_X, np.cov(Xs.T, bias=True))
    assert np.allclose(stats.mean_R, Rs.mean(axis=0))
    assert np.allclose(stats.var_R, Rs.var(axis=0))


def test_the_ekf_error_and_covariance_shrink_with_measurements():
    rng = np.random.default_rng(5)
    truth = np.array([0.3, -0.2, 1.6])
    sigma = 0.5
    errors, traces = [], []
    for _ in range(20):
        f = None
        for _k in range(25):
            g01 = np.eye(4)  # the camera moves about, each pose known to 1 mm and 0.05 deg
            g01[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix()
            g01[:3, 3] = rng.normal(0, 0.1, 3)
            pose_cov = np.diag([math.radians(0.05) ** 2] * 3 + [0.001 ** 2] * 3)
            z = CAMERA.measure(g01[:3, :3] @ truth + g01[:3, 3]) + rng.normal(0, sigma, 3)
            if f is None:
                f = FiducialFilter(CAMERA, z, g01, sigma, sigma, pose_cov)
                first_err, first_trace = np.linalg.norm(f.x - truth), np.trace(f.covariance)
            else:
                f.update(z, g01, pose_cov)
        errors.append((first_err, np.linalg.norm(f.x - truth)))
        traces.append((first_trace, np.trace(f.covariance)))
    errors, traces = np.array(errors), np.array(traces)
    assert np.median(errors[:, 1]) < 0.4 * np.median(errors[:, 0])
    assert np.all(traces[:, 1] < 0.2 * traces[:, 0])
    # and the covariance is honest: the errors are about as large as it says
    assert np.median(errors[:, 1]) < 3 * np.sqrt(np.median(traces[:, 1]))
