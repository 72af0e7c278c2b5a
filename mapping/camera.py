"""Pinhole cameras and frame conventions, free of any simulator.

Camera frames here follow OpenCV: +z forward, +x right, +y down; pixel (u, v) has u
along image columns and v along rows, and pixel centres sit at integer coordinates.
A MuJoCo camera frame (-z forward, +y up) maps to it by ``MUJOCO_TO_OPENCV``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class Pinhole:
    """Intrinsics of an ideal pinhole camera (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fovy(cls, fovy_rad: float, width: int, height: int) -> Pinhole:
        """Square pixels and a vertical field of view, as MuJoCo's cameras have."""
        f = (height / 2) / math.tan(fovy_rad / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2)

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def rays(self, stride: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel grid (u, v), every ``stride``-th, and its rays with unit z, shape (h, w, 3)."""
        u, v = np.meshgrid(np.arange(0, self.width, stride), np.arange(0, self.height, stride))
        rays = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones(u.shape)], -1)
        return u, v, rays

    def unproject(self, depth: np.ndarray, stride: int = 1) -> np.ndarray:
        """Points (h, w, 3) in the camera frame from z-depth (m), sampled every ``stride``."""
        _, _, rays = self.rays(stride)
        return rays * depth[::stride, ::stride, None]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (n, 2) of camera-frame points (n, 3); z must be > 0."""
        points = np.atleast_2d(points)
        z = points[:, 2]
        return np.stack([self.fx * points[:, 0] / z + self.cx,
                         self.fy * points[:, 1] / z + self.cy], -1)

    def contains(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether pixels (n, 2) lie inside the image, ``margin`` pixels from its border."""
        pixels = np.atleast_2d(pixels)
        return ((pixels[:, 0] >= -0.5 + margin) & (pixels[:, 0] <= self.width - 0.5 - margin)
                & (pixels[:, 1] >= -0.5 + margin) & (pixels[:, 1] <= self.height - 0.5 - margin))


def opencv_pose(T_world_mjcam: np.ndarray) -> np.ndarray:
    """``T_world_cam`` of the OpenCV-convention frame from a MuJoCo camera pose (4x4)."""
    T = np.array(T_world_mjcam, dtype=float, copy=True)
    T[:3, :3] = T[:3, :3] @ MUJOCO_TO_OPENCV
    return T


def mujoco_pose(T_world_cvcam: np.ndarray) -> np.ndarray:
    """``T_world_cam`` of the MuJoCo-convention frame from an OpenCV one: the flip is its
    own inverse, so this is :func:`opencv_pose` read the other way."""
    return opencv_pose(T_world_cvcam)


def world_to_camera(T_world_cam: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (n, 3) in the world expressed in the camera frame."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    return (np.atleast_2d(points) - t) @ R


def camera_to_world(T_world_cam: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 3) in the camera frame expressed in the world."""
    return points @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
