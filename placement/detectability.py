"""Views from which the hole detector can find a target (calibration/targets.py).

A camera at distance d from a hole of radius r, looking at it from an angle a off its
normal, sees (to first order, the hole at the image's centre) an ellipse of semi-axes
f r / d and f r cos(a) / d pixels, f the focal length in pixels. The detector needs the
narrower one, the *projected radius* f r cos(a) / d, to be about a pixel or more, and the
angle to stay short of grazing: :class:`DetectorLimits`, as bench/studies/detector_limits.py
measured them. A stereo sighting needs the hole in both images, and the partner camera
may see it more obliquely than the one placed: ``detectable(..., baseline_m=...)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import PlacementError
from .rating import CameraModel, TargetModel


@dataclass(frozen=True)
class DetectorLimits:
    """The smallest projected radius (px, foreshortened: f r cos(a) / d) and the largest
    angle off the target's normal (deg) at which the detector still finds the hole."""

    # bench/studies/detector_limits.py (rendered, defocused views; 640x480 with and without MSAA,
    # 320x240 with; per image, found within 1 px in >= 95 % of samples): reliable down to
    # 0.75 px and up to 72.5 deg in all three, but the bins at that corner find only
    # 82-89 %; the defaults keep one bin inside it. Why there: wherever the detector
    # misses, its template's score at the hole is under the 0.5 it asks for (the LoG
    # response stays far above its 0.05). Below ~1 px the hole is under two pixels
    # across, and pixel sampling and the lens blur spread it into a faint blot unlike the
    # template (median score 0.6-0.7 at 0.5-0.75 px, 0.95 from 4 px); past ~72 deg the
    # dark ellipse fills only about cos(a) of the template's square window, so the
    # plate's texture dominates the normalised correlation (median score 0.95 head-on,
    # 0.75 at 72.5-75 deg, 0.5 at 77.5-80 deg).
    min_radius_px: float = 1.0
    max_off_normal_deg: float = 70.0

    def __post_init__(self) -> None:
        if not (self.min_radius_px > 0 and math.isfinite(self.min_radius_px)):
            raise PlacementError(f"min_radius_px {self.min_radius_px}: a number of pixels > 0")
        if not 0 < self.max_off_normal_deg < 90:
            raise PlacementError(f"max_off_normal_deg {self.max_off_normal_deg}: "
                                 "degrees in (0, 90)")


def focal_px(camera: CameraModel) -> float:
    """Focal length (px) of a camera with ``camera.fov`` (rad) over ``camera.pixels``."""
    return camera.pixels / (2.0 * math.tan(camera.fov / 2.0))


def projected_radius(positions: np.ndarray, target: TargetModel, camera: CameraModel
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per camera position (N, 3; m) looking at the target: the projected radius
    f r cos(a) / d (px; 0 from behind the hole's plane) and the angle a off its normal
    (rad)."""
    to_camera = np.asarray(positions, float).reshape(-1, 3) - np.asarray(target.position, float)
    distance = np.linalg.norm(to_camera, axis=1)
    normal = np.asarray(target.normal, float) / np.linalg.norm(target.normal)
    cos = np.clip(to_camera @ normal / np.maximum(distance, 1e-12), -1.0, 1.0)
    radius = np.where(distance > 0, focal_px(camera) * target.radius
                      * np.maximum(cos, 0.0) / np.maximum(distance, 1e-12), 0.0)
    return radius, np.arccos(cos)


def worst_partner(positions: np.ndarray, target: TargetModel, baseline_m: float) -> np.ndarray:
    """Where a stereo partner ``baseline_m`` (m) from each camera position (N, 3),
    across its line of sight to the target, sees the target most obliquely: moved
    within the plane of that line and the target's normal, away from the normal (its
    angle is then a + atan(baseline / d)). Placement does not know the roll the arm
    will give the head, so this is the partner to check."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    sight = positions - np.asarray(target.position, float)
    sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-12)
    normal = np.asarray(target.normal, float) / np.linalg.norm(target.normal)
    across = normal - (sight @ normal)[:, None] * sight  # the normal, across the line
    length = np.linalg.norm(across, axis=1, keepdims=True)
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    any_way = np.cross(sight, helper)  # looking along the normal every way is as oblique
    any_way /= np.maximum(np.linalg.norm(any_way, axis=1, keepdims=True), 1e-12)
    away = np.where(length > 1e-9, -across / np.maximum(length, 1e-12), any_way)
    return positions + baseline_m * away


def detectable(positions: np.ndarray, target: TargetModel, camera: CameraModel,
               limits: DetectorLimits = DetectorLimits(), *, baseline_m: float = 0.0
               ) -> np.ndarray:
    """Bool per camera position (N, 3; m): a view from there, looking at the target, sees
    its hole at a projected radius of at least ``limits.min_radius_px`` and within
    ``limits.max_off_normal_deg`` of its normal. With ``baseline_m`` > 0 (a stereo pair
    that must find it in both images), the partner camera at its worst roll
    (:func:`worst_partner`) must too."""
    radius, angle = projected_radius(positions, target, camera)
    ok = (radius >= limits.min_radius_px) & (angle <= math.radians(limits.max_off_normal_deg))
    if baseline_m > 0:
        ok &= detectable(worst_partner(positions, target, baseline_m), target, camera, limits)
    return ok
