"""Targets seen in stereo, and the common target frame all robots' sightings establish
(sec. 2.2).

Each placed camera looks for every target where its believed pose (the corrected one,
else the commanded one) puts it: the hole is found in the left and in the right image
(LoG, then template matching, calibration/targets.py), the disparity of the two centres
gives its depth, and the believed pose carries the point into the world. The common
frame is the work-piece's CAD frame moved onto every target located (secondary ones
weighed by their ST_error), with its origin where that puts the primary target, its z
axis along the work-piece normal (from its CAD model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from taskcam.mapping import Pinhole, Target, opencv_pose, world_to_camera

from .ekf import StereoCamera
from .targets import holes_near

# A target is looked for where the believed pose puts it, as far around as that
# prediction is uncertain: SIGMAS standard deviations of its pixel, plus the detector's
# own error where it is reliable (docs/detector_limits.md: within 1 px).
SIGMAS = 3.0
DETECTOR_PX = 1.0


def search_slack_px(depth_m: float, fx: float, position_sd_m: float,
                    rotation_sd_deg: float) -> float:
    """How far (px) a target ``depth_m`` in front of the camera may lie from its predicted
    pixel, given the standard deviations of the camera's and the target's positions
    together (m, root of the covariance's trace) and of the camera's rotation (deg)."""
    pixel_sd = fx * math.hypot(position_sd_m / depth_m, math.radians(rotation_sd_deg))
    return SIGMAS * pixel_sd + DETECTOR_PX


@dataclass(frozen=True)
class Sighting:
    """One robot's stereo sighting of one target."""

    robot: str
    target: str
    pixel: tuple[float, float]  # left image
    disparity: float  # pixels
    score: float | None  # the left template match (a hole; None: a fitted slot)
    position: np.ndarray  # world (m), through the believed camera pose
    # of ``position``, from the believed camera pose's uncertainty; the sighting's own
    # stereo error is left out: not measured, and its bias near the camera (the hole's
    # ellipse centre off its projected centre, docs/detector_limits.md) is no noise
    sd_m: float = 0.0
    placement: int = 0  # which of the robot's placements it was made from
    pose_status: str = "as commanded"  # of the believed pose (corrected, failed, ...)

    def summary(self, truth: np.ndarray) -> dict[str, Any]:
        return {"target": self.target, "pixel": [round(c, 3) for c in self.pixel],
                "disparity_px": round(self.disparity, 3),
                "score": None if self.score is None else round(self.score, 4),
                "position": self.position.round(5).tolist(), "sd_m": round(self.sd_m, 6),
                "placement": self.placement, "pose": self.pose_status,
                "error_m": round(float(np.linalg.norm(self.position - truth)), 6)}


def projected_disk(target: Target, T_world_cam: np.ndarray, pinhole: Pinhole
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """Where a camera (OpenCV convention) sees the target's centre (u, v), and the 2x2
    map from the unit circle to its rim's pixel offsets (the ellipse of the oblique
    hole, to first order); None if it is behind the camera."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    p = R.T @ (target.position - t)
    if p[2] <= 0.05:
        return None
    x, y, z = p
    J = np.array([[pinhole.fx / z, 0.0, -pinhole.fx * x / z ** 2],
                  [0.0, pinhole.fy / z, -pinhole.fy * y / z ** 2]]) @ R.T  # d pixel / d world
    n = target.normal / np.linalg.norm(target.normal)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return pinhole.project(p[None])[0], target.radius * J @ np.column_stack([e1, e2])


def sight(robot: str, left: np.ndarray, right: np.ndarray, target: Target,
          T_believed_mjcam: np.ndarray, pinhole: Pinhole, baseline_m: float, *,
          position_sd_m: float, rotation_sd_deg: float,
          others: tuple[Target, ...] = ()) -> Sighting | None:
    """The target found in both images where the believed pose puts it: within
    :func:`search_slack_px` of the prediction, given the standard deviations of the
    camera's and the target's positions together (m) and of the camera's rotation (deg).
    A hole is this target's only if it lies nearer this target's predicted pixel than
    any of ``others``' (the other targets), and it is claimed only if it is the one such
    hole in the left image's window and the one on its row in the right image's (two
    would be a guess). None if the target is behind the camera, out of the image, not
    found in both images or not found unambiguously."""
    T = opencv_pose(T_believed_mjcam)
    disk = projected_disk(target, T, pinhole)
    if disk is None or not pinhole.contains(disk[0][None], margin=5.0)[0]:
        return None
    (u, v), shape = disk
    radius_px = math.sqrt(abs(float(np.linalg.det(shape))))
    depth = float(world_to_camera(T, target.position[None])[0, 2])
    slack = search_slack_px(depth, pinhole.fx, position_sd_m, rotation_sd_deg)
    rivals = [p[0] for t in others if (p := projected_disk(t, T, pinhole)) is not None]
    mine = [h for h in holes_near(left, (float(u), float(v)), radius_px, 3 * radius_px + slack,
                                  shape)
            if all(math.hypot(h.u - u, h.v - v) <= math.hypot(h.u - a, h.v - b)
                   for a, b in rivals)]
    if len(mine) != 1:
        return None
    found = mine[0]
    shift = pinhole.fx * baseline_m / depth  # the expected disparity
    # given the left detection, only the depth's error and the detectors' move the right one
    paired = [h for h in holes_near(right, (found.u - shift, found.v), radius_px,
                                    slack + DETECTOR_PX, shape)
              if abs(h.v - found.v) <= 1.5 and found.u - h.u > 0]
    if len(paired) != 1:
        return None
    d = found.u - paired[0].u
    camera = StereoCamera(pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy, baseline_m)
    in_cam = camera.point(np.array([found.u, found.v, d]))
    return Sighting(robot, target.name, (found.u, found.v), d, found.score,
                    T[:3, :3] @ in_cam + T[:3, 3])


def _cad_frame(primary: Target) -> np.ndarray:
    """The target frame (4x4) in the CAD model: at the primary target, z along its
    normal, x the world's x turned into the plate."""
    z = primary.normal / np.linalg.norm(primary.normal)
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, primary.position
    return T


def common_frame(sightings: list[Sighting], targets: tuple[Target, ...]) -> dict[str, Any]:
    """The target frame from every robot's sightings, and each target's measured place
    against the truth.

    Each target's place is the mean over robots weighted by the inverse variance of each
    sighting (``sd_m``), so that a camera whose pose could not be corrected counts as
    little as its uncertainty says. The frame is the work-piece's CAD frame moved onto
    every target located: the turn about the plate's normal and the shift that carry the
    targets' CAD places onto their measured ones (weighted least squares; a secondary
    target weighs as its place's variance plus its ST_error squared, eq. 4: its relation
    to the primary is known only that well). One target located gives the shift alone
    (the turn stays unmeasured); the primary need not be among them: secondary targets
    stand in for it. The frame's origin is where it puts the primary target, its z axis
    the plate's normal (CAD), its x axis the CAD frame's turned; ``from`` names the
    targets it rests on, ``sd_m`` is its shift's standard deviation (m, per axis) at
    ``pivot`` (their weighted centre), ``yaw_sd_deg`` its turn's (None: unmeasured)."""
    out: dict[str, Any] = {"targets": {}}
    measured: dict[str, np.ndarray] = {}
    variance: dict[str, float] = {}
    for t in targets:
        mine = [s for s in sightings if s.target == t.name]
        if not mine:
            continue
        seen = np.array([s.position for s in mine])
        weights = 1.0 / np.maximum([s.sd_m for s in mine], 1e-6) ** 2
        mean = weights @ seen / weights.sum()
        measured[t.name] = mean
        variance[t.name] = 1.0 / float(weights.sum())
        out["targets"][t.name] = {
            "robots": [s.robot for s in mine],
            "poses": [s.pose_status for s in mine],
            "weights": (weights / weights.sum()).round(4).tolist(),
            "position": mean.round(5).tolist(),
            "sd_m": round(float(np.sqrt(1.0 / weights.sum())), 6),
            "spread_m": round(float(max(np.linalg.norm(p - mean) for p in seen)), 6),
            "error_m": round(float(np.linalg.norm(mean - t.position)), 6)}
    primary = next(t for t in targets if t.role == "primary")
    used = [t for t in targets if t.name in measured]
    if not used:
        out["frame"] = None
        return out
    z = primary.normal / np.linalg.norm(primary.normal)
    w = np.array([1.0 / (variance[t.name] + (t.st_error if t.role == "secondary" else 0.0) ** 2)
                  for t in used])
    nominal = np.array([t.position for t in used])
    found = np.array([measured[t.name] for t in used])
    p_mid, q_mid = w @ nominal / w.sum(), w @ found / w.sum()
    a, b = nominal - p_mid, found - q_mid
    a_plane = a - np.outer(a @ z, z)
    lever = float(w @ (a_plane ** 2).sum(axis=1))
    yaw, yaw_sd = 0.0, None
    if len(used) > 1 and lever > 1e-12:
        # the turn about z that best carries the CAD offsets onto the measured ones
        yaw = math.atan2(float(w @ (np.cross(a_plane, b) @ z)), float(w @ (a_plane * b).sum(1)))
        yaw_sd = math.sqrt(1.0 / lever)  # rad: each place's variance over its lever arm
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_rotvec(yaw * z).as_matrix()
    motion[:3, 3] = q_mid - motion[:3, :3] @ p_mid
    frame = motion @ _cad_frame(primary)
    out["frame"] = {"origin": frame[:3, 3].round(5).tolist(),
                    "x_axis": frame[:3, 0].round(6).tolist(),
                    "z_axis": frame[:3, 2].round(6).tolist(),
                    "y_axis": frame[:3, 1].round(6).tolist(),
                    "from": [t.name for t in used], "primary_seen": primary.name in measured,
                    "pivot": q_mid.round(5).tolist(),
                    "sd_m": round(float(np.sqrt(1.0 / w.sum())), 6),
                    "yaw_sd_deg": None if yaw_sd is None else round(math.degrees(yaw_sd), 4)}
    return out


def frame_matrix(frame: dict[str, Any]) -> np.ndarray:
    """The 4x4 pose of a frame as :func:`common_frame` gives it."""
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = frame["x_axis"], frame["y_axis"], frame["z_axis"]
    T[:3, 3] = frame["origin"]
    return T


def frame_motion(targets: tuple[Target, ...], measured: dict[str, Any]) -> np.ndarray:
    """The rigid motion (4x4, world) that carries the work-piece's CAD model (nominal) to
    where the target frame the robots measured puts it; identity when no target was
    measured."""
    if measured.get("frame") is None:  # nothing located: the nominal place
        return np.eye(4)
    primary = next(t for t in targets if t.role == "primary")
    return frame_matrix(measured["frame"]) @ np.linalg.inv(_cad_frame(primary))


def in_measured_frame(point: np.ndarray, targets: tuple[Target, ...],
                      measured: dict[str, Any]) -> np.ndarray:
    """Where a point of the work-piece's CAD model (world, nominal) is, given the target
    frame the robots measured (:func:`frame_motion`)."""
    moved = frame_motion(targets, measured)
    return moved[:3, :3] @ np.asarray(point, float) + moved[:3, 3]
