"""Metric depth from a rectified stereo pair by semi-global block matching (OpenCV).

The pair comes from two parallel cameras with identical intrinsics, the right one
displaced by ``baseline_m`` along the left camera's +x axis (image x to the right), so
a point at column u in the left image appears at column u - d in the right image, with
disparity d = fx * baseline / z > 0. Depth is returned in the left camera.

Invalid pixels are NaN, never ``inf`` (which elsewhere means "sky, nothing hit"):
no match (holes, textureless areas, occlusions), left-right inconsistency, or a
disparity below ``StereoSettings.min_disparity_px`` (too far to measure).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Pinhole
from .errors import MappingError

__all__ = ["StereoSettings", "stereo_depth"]


@dataclass(frozen=True)
class StereoSettings:
    """Semi-global block matching (``cv2.StereoSGBM``) and validity checks; units are pixels.

    The defaults suit a 640x480, 60 deg vertical-fov camera (fx = 415.7 px) with a
    0.12 m baseline: 192 disparities reach down to fx * b / 191 px = 0.26 m, and
    ``min_disparity_px`` = 4 px drops pixels beyond fx * b / 4 = 12.5 m.
    """

    num_disparities: int = 192  # search range [0, num_disparities) px; a multiple of 16
    block_size: int = 5  # matched block side (px), odd
    uniqueness_ratio: int = 10  # % by which the best match cost must beat the second best
    speckle_window_size: int = 100  # largest disparity blob (px) treated as noise; 0: off
    speckle_range: int = 2  # largest disparity step (px) inside one blob
    min_disparity_px: float = 4.0  # smaller disparities (too far) are invalid
    left_right_check: bool = True  # invalidate where left and right disparities differ > 1 px

    def __post_init__(self) -> None:
        problems = []
        if self.num_disparities <= 0 or self.num_disparities % 16:
            problems.append(f"num_disparities {self.num_disparities}: a positive multiple of 16")
        if self.block_size < 1 or self.block_size % 2 == 0:
            problems.append(f"block_size {self.block_size}: a positive odd number")
        if not 0 <= self.uniqueness_ratio <= 100:
            problems.append(f"uniqueness_ratio {self.uniqueness_ratio}: 0 to 100")
        if self.speckle_window_size < 0 or self.speckle_range < 0:
            problems.append(f"speckle_window_size {self.speckle_window_size}, speckle_range "
                            f"{self.speckle_range}: >= 0")
        if not 0 < self.min_disparity_px < self.num_disparities:
            problems.append(f"min_disparity_px {self.min_disparity_px}: in (0, num_disparities)")
        if problems:
            raise MappingError("invalid stereo settings: " + "; ".join(problems))


def _matcher(settings: StereoSettings, channels: int) -> cv2.StereoSGBM:
    area = channels * settings.block_size**2
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=settings.num_disparities,
        blockSize=settings.block_size,
        P1=8 * area,
        P2=32 * area,
        disp12MaxDiff=-1,  # the left-right check is done explicitly, with a second matcher
        uniquenessRatio=settings.uniqueness_ratio,
        speckleWindowSize=settings.speckle_window_size,
        speckleRange=settings.speckle_range,
        mode=cv2.StereoSGBM_MODE_SGBM,
    )


def _disparity(matcher: cv2.StereoSGBM, left: np.ndarray, right: np.ndarray,
               pad: int) -> np.ndarray:
    """Disparity (px, float32) of each left pixel, NaN where SGBM found none.

    SGBM leaves the first ``num_disparities`` columns unmatched; padding both images on
    the left by ``pad`` columns lets it match them at the disparities that stay inside
    the right image (the others fail the left-right check).
    """
    if pad:
        left = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        right = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
    raw = matcher.compute(left, right)[:, pad:]  # int16, 4 fractional bits; < 0: none
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < 0] = np.nan
    return disparity


def _check_image(name: str, image: np.ndarray, camera: Pinhole) -> np.ndarray:
    image = np.asarray(image)
    shape = (camera.height, camera.width)
    if image.dtype != np.uint8 or image.shape[:2] != shape or image.ndim not in (2, 3) or (
            image.ndim == 3 and image.shape[2] != 3):
        raise MappingError(f"{name} image must be uint8 of shape {shape} or {(*shape, 3)}, "
                         f"got {image.dtype} {image.shape}")
    return np.ascontiguousarray(image)


def stereo_depth(left_rgb: np.ndarray, right_rgb: np.ndarray, camera: Pinhole,
                 baseline_m: float, settings: StereoSettings = StereoSettings(),
                 window: tuple[slice, slice] | None = None) -> np.ndarray:
    """Metric z-depth (m) in the left camera, float32 (h, w), from a rectified pair.

    ``left_rgb`` and ``right_rgb`` are uint8 images (h, w, 3) or grey (h, w) of
    ``camera``; the right camera sits ``baseline_m`` along the left one's +x axis.
    z = fx * baseline / disparity, with SGBM's 1/16-px subpixel disparity. NaN where
    there is no valid disparity; never ``inf``, never <= 0.

    With ``window`` (rows, columns of the left image), only that part is matched (and
    the right image's columns from ``num_disparities`` to its left): much cheaper for a
    small object; SGBM's smoothing paths then end at the window's edges.
    """
    if not baseline_m > 0:
        raise MappingError(f"baseline_m {baseline_m}: a number of metres > 0")
    left = _check_image("left", left_rgb, camera)
    right = _check_image("right", right_rgb, camera)
    if left.shape != right.shape:
        raise MappingError(f"left and right images differ in shape: {left.shape}, "
                           f"{right.shape}; accepted: images of one shape")
    if window is None:
        return _depth(left, right, camera, baseline_m, settings, 0)
    rows, cols = (slice(*w.indices(n)[:2]) for w, n in
                  zip(window, (camera.height, camera.width), strict=True))
    first = max(0, cols.start - settings.num_disparities)
    sub = dataclasses.replace(camera, width=cols.stop - first, height=rows.stop - rows.start,
                              cx=camera.cx - first, cy=camera.cy - rows.start)
    part = _depth(left[rows, first:cols.stop], right[rows, first:cols.stop], sub, baseline_m,
                  settings, cols.start - first)
    depth = np.full((camera.height, camera.width), np.nan, np.float32)
    depth[rows, cols] = part[:, cols.start - first:]
    return depth


def _depth(left: np.ndarray, right: np.ndarray, camera: Pinhole, baseline_m: float,
           settings: StereoSettings, skip: int) -> np.ndarray:
    """:func:`stereo_depth` of whole images, but for their first ``skip`` columns (left
    NaN: only matched against). SGBM matches no column closer than ``num_disparities``
    to the left edge: the left image is padded by as many as it lacks; the mirrored pair
    of the left-right check always is (its right edge is the window's)."""
    matcher = _matcher(settings, 1 if left.ndim == 2 else 3)
    pad = settings.num_disparities
    disparity = _disparity(matcher, left, right, max(0, pad - skip))
    disparity[:, :skip] = np.nan

    if settings.left_right_check:
        # Mirroring both images turns the right image into the left one of a rectified
        # pair, so the same matcher gives each right pixel its disparity.
        right_disparity = _disparity(matcher, right[:, ::-1].copy(), left[:, ::-1].copy(),
                                     pad)[:, ::-1]
        v, u = np.nonzero(np.isfinite(disparity))
        d = disparity[v, u]
        u_right = np.rint(u - d).astype(np.intp)
        inside = (u_right >= 0) & (u_right < camera.width)
        d_right = np.full(d.shape, np.nan, np.float32)
        d_right[inside] = right_disparity[v[inside], u_right[inside]]
        consistent = np.abs(d_right - d) <= 1.0  # False where d_right is NaN
        disparity[v[~consistent], u[~consistent]] = np.nan

    with np.errstate(invalid="ignore"):
        disparity[~(disparity >= settings.min_disparity_px)] = np.nan
    return (camera.fx * baseline_m / disparity).astype(np.float32)
