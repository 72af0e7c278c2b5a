"""A fiducial's position by an extended Kalman filter (eq. 10-12), with filterpy.

State: the fiducial's world position x (3). Measurement: z = (u, v, d), its pixel in the
left camera and its stereo disparity d = f b / z_cam (pixels), through h(x) of the
camera pose g01 (world to camera). The measurement noise is the pixel noise plus the
camera pose's uncertainty carried through h (eq. 10 with R_k = R_pixel + J_pose Σ J_poseᵀ,
the pose as a small rotation then translation in the camera frame). The filter starts
from the triangulation of the first measurement, its covariance that of the inverse map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter


@dataclass(frozen=True)
class StereoCamera:
    """The left camera's intrinsics (pixels) and the stereo baseline (m)."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

    def measure(self, p: np.ndarray) -> np.ndarray:
        """(u, v, d) of a camera-frame point p (3)."""
        return np.array([self.fx * p[0] / p[2] + self.cx, self.fy * p[1] / p[2] + self.cy,
                         self.fx * self.baseline / p[2]])

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """d(u, v, d) / dp at a camera-frame point (3x3)."""
        x, y, z = p
        return np.array([[self.fx / z, 0.0, -self.fx * x / z ** 2],
                         [0.0, self.fy / z, -self.fy * y / z ** 2],
                         [0.0, 0.0, -self.fx * self.baseline / z ** 2]])

    def point_covariance(self, p: np.ndarray, sd_px: float) -> np.ndarray:
        """The 3x3 covariance (m^2, camera frame) of the point triangulated at ``p``
        from a left and a right centre each found to ``sd_px`` per axis (the disparity,
        their difference, to sqrt(2) ``sd_px``; the rows are rectified to one)."""
        J = np.linalg.inv(self.jacobian(p))
        noise = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 2.0]]) * sd_px ** 2
        return J @ noise @ J.T

    def point(self, z: np.ndarray) -> np.ndarray:
        """The camera-frame point of a measurement (u, v, d): triangulation."""
        depth = self.fx * self.baseline / z[2]
        return np.array([(z[0] - self.cx) * depth / self.fx, (z[1] - self.cy) * depth / self.fy,
                         depth])


def skew(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def measurement_noise(camera: StereoCamera, g01: np.ndarray, x: np.ndarray,
                      pixel_sigma: float, disparity_sigma: float,
                      pose_cov: np.ndarray | None) -> np.ndarray:
    """R_k: pixel and disparity noise, plus the pose covariance (6x6, rotation then
    translation, in the camera frame) carried through h."""
    R = np.diag([pixel_sigma ** 2, pixel_sigma ** 2, disparity_sigma ** 2])
    if pose_cov is not None:
        p = g01[:3, :3] @ x + g01[:3, 3]
        J = camera.jacobian(p) @ np.hstack([-skew(p), np.eye(3)])
        R = R + J @ pose_cov @ J.T
    return R


class FiducialFilter:
    """EKF on one fiducial's world position."""

    def __init__(self, camera: StereoCamera, z: np.ndarray, g01: np.ndarray,
                 pixel_sigma: float = 0.3, disparity_sigma: float = 0.3,
                 pose_cov: np.ndarray | None = None) -> None:
        self.camera = camera
        self.pixel_sigma, self.disparity_sigma = pixel_sigma, disparity_sigma
        self.ekf = ExtendedKalmanFilter(dim_x=3, dim_z=3)
        R_pose, t = g01[:3, :3], g01[:3, 3]
        p = camera.point(np.asarray(z, float))
        x0 = R_pose.T @ (p - t)
        H = camera.jacobian(p) @ R_pose
        Hinv = np.linalg.inv(H)
        noise = measurement_noise(camera, g01, x0, pixel_sigma, disparity_sigma, pose_cov)
        self.ekf.x = x0.reshape(3, 1)
        self.ekf.P = Hinv @ noise @ Hinv.T
        self.ekf.Q = np.zeros((3, 3))  # fiducials do not move
        self.updates = 0

    @property
    def x(self) -> np.ndarray:
        return self.ekf.x.ravel().copy()

    @property
    def covariance(self) -> np.ndarray:
        return np.array(self.ekf.P, copy=True)

    def update(self, z: np.ndarray, g01: np.ndarray, pose_cov: np.ndarray | None = None
               ) -> None:
        """One more measurement (u, v, d) from a camera at g01 (eq. 11-12)."""
        cam = self.camera
        R, t = g01[:3, :3], g01[:3, 3]

        def hx(x: np.ndarray) -> np.ndarray:
            return cam.measure(R @ x.ravel() + t).reshape(3, 1)

        def jac(x: np.ndarray) -> np.ndarray:
            return cam.jacobian(R @ x.ravel() + t) @ R

        noise = measurement_noise(cam, g01, self.x, self.pixel_sigma, self.disparity_sigma,
                                  pose_cov)
        self.ekf.predict()
        self.ekf.update(np.asarray(z, float).reshape(3, 1), jac, hx, R=noise)
        self.updates += 1
