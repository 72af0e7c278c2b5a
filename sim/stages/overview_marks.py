"""What ``overview.png`` marks on the picture, read from ``summary.json``'s records so
that the picture tells the outcome the summary and the screen tell: each robot's camera
frustum (green when placed, red when not) and its name, the targets with their names
and roles; and how the labels are put where the free camera sees those points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import mujoco
import numpy as np

from taskcam.mapping import opencv_pose

PLACED_RGBA = (0.1, 0.9, 0.3, 1.0)  # a placed camera's frustum
UNPLACED_RGBA = (0.95, 0.15, 0.1, 1.0)  # a camera that was not placed: where it ended
TARGET_RGB = (255, 230, 60)
FONT = cv2.FONT_HERSHEY_SIMPLEX
FONT_SCALE = 0.5
LINE_PX = 16  # a label's height, for keeping labels apart


@dataclass(frozen=True)
class RobotMark:
    """A robot as the overview draws it: ``T_world_cam`` its camera where it ended
    (OpenCV convention, world), ``base`` its base's x, y (m) and yaw (rad)."""

    name: str
    placed: bool
    T_world_cam: np.ndarray
    base: tuple[float, float, float]

    @property
    def label(self) -> str:
        return self.name if self.placed else f"{self.name} (not placed)"

    @property
    def rgba(self) -> tuple[float, float, float, float]:
        return PLACED_RGBA if self.placed else UNPLACED_RGBA


@dataclass(frozen=True)
class TargetMark:
    """A target as the overview labels it: its name, role and centre (m, world)."""

    name: str
    role: str
    position: np.ndarray

    @property
    def label(self) -> str:
        return f"{self.name} ({self.role})"


def _pose(record: dict[str, Any]) -> np.ndarray:
    """A ``summary.json`` pose (position, quat_wxyz) as a 4x4 matrix."""
    T = np.eye(4)
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(record["quat_wxyz"], float))
    T[:3, :3] = rotation.reshape(3, 3)
    T[:3, 3] = record["position"]
    return T


def robot_marks(summary: dict[str, Any]) -> list[RobotMark]:
    """Every robot of ``summary``, placed or not, where it ended."""
    return [RobotMark(r["name"], bool(r["placed"]), opencv_pose(_pose(r["pose"])),
                      (r["base"]["x_m"], r["base"]["y_m"], r["base"]["yaw_rad"]))
            for r in summary["robots"]]


def target_marks(summary: dict[str, Any], scene_targets: Sequence[Any] = ()
                 ) -> list[TargetMark]:
    """The targets the placed robots ended viewing (their names and roles as
    ``summary.json`` gives them), then the scene's other targets (``scene_targets``:
    objects with ``name``, ``role`` and ``position``), each once."""
    marks: dict[str, TargetMark] = {}
    for r in summary["robots"]:
        if r.get("placed") and r.get("target"):
            t = r["target"]
            marks.setdefault(t["name"], TargetMark(t["name"], t["role"],
                                                   np.asarray(t["position"], float)))
    for t in scene_targets:
        marks.setdefault(t.name, TargetMark(t.name, t.role, np.asarray(t.position, float)))
    return list(marks.values())


def project(camera: mujoco.MjvGLCamera, points: np.ndarray, width: int, height: int
            ) -> np.ndarray:
    """Pixels (n, 2; x right, y down) of world ``points`` (n, 3; m) in a picture of
    ``width`` x ``height`` rendered from ``camera`` (a scene's, after its update);
    NaN for points behind it."""
    forward, up = np.asarray(camera.forward, float), np.asarray(camera.up, float)
    right = np.cross(forward, up)
    rel = np.atleast_2d(points) - np.asarray(camera.pos, float)
    x, y, z = rel @ right, rel @ up, rel @ forward
    near, bottom, top = camera.frustum_near, camera.frustum_bottom, camera.frustum_top
    half_w = camera.frustum_width or 0.5 * (top - bottom) * width / height
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (near * x / z - (camera.frustum_center - half_w)) / (2 * half_w) * width
        v = (top - near * y / z) / (top - bottom) * height
    out = np.column_stack([u, v])
    out[z <= 0] = np.nan
    return out


def _free_spot(x: int, y: int, size: tuple[int, int], taken: list[tuple[int, int, int, int]],
               shape: tuple[int, ...]) -> tuple[int, int]:
    """Where a label of ``size`` (w, h) anchored at (x, y) overlaps no ``taken`` box:
    moved down a line at a time (then up), kept inside the picture."""
    w, h = size
    for k in [0, *[s * j for j in range(1, 12) for s in (1, -1)]]:
        cx = int(np.clip(x, 2, shape[1] - w - 2))
        cy = int(np.clip(y + k * LINE_PX, h + 2, shape[0] - 4))
        box = (cx, cy - h, cx + w, cy + 3)
        if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3]
                   for b in taken):
            return cx, cy
    return int(np.clip(x, 2, shape[1] - w - 2)), int(np.clip(y, h + 2, shape[0] - 4))


def draw_labels(image: np.ndarray, labels: Sequence[tuple[str, np.ndarray,
                                                          tuple[int, int, int]]]) -> None:
    """Write each label (text, pixel where it points, RGB) beside its pixel on ``image``
    (RGB, in place), outlined for contrast, none over another."""
    taken: list[tuple[int, int, int, int]] = []
    for text, pixel, rgb in labels:
        if not np.all(np.isfinite(pixel)):
            continue
        (w, h), _ = cv2.getTextSize(text, FONT, FONT_SCALE, 1)
        x, y = _free_spot(int(pixel[0]) + 6, int(pixel[1]) - 6, (w, h), taken, image.shape)
        taken.append((x, y - h, x + w, y + 3))
        dot = (int(pixel[0]), int(pixel[1]))
        cv2.circle(image, dot, 3, rgb, -1, cv2.LINE_AA)
        if abs(y - (dot[1] - 6)) > 2:  # moved clear of another label: a leader to its dot
            cv2.line(image, dot, (x - 2, y - h // 2), rgb, 1, cv2.LINE_AA)
        cv2.putText(image, text, (x, y), FONT, FONT_SCALE, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(image, text, (x, y), FONT, FONT_SCALE, rgb, 1, cv2.LINE_AA)


def rgb255(rgba: tuple[float, float, float, float]) -> tuple[int, int, int]:
    return (round(255 * rgba[0]), round(255 * rgba[1]), round(255 * rgba[2]))
