"""Circular-hole targets: where one is in the world, and finding it in images by
Laplacian-of-Gaussian filtering, then template matching.

A hole is a dark disk on a brighter plate. The scale-normalised LoG response of a
disk of radius r peaks at its centre for sigma = r / sqrt(2) (sec. 2.2); matching a
dark-disk template around that peak refines the centre to a fraction of a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class HoleDetection:
    """A detected hole: centre (u, v) and radius in pixels, template-match score in [-1, 1]."""

    u: float
    v: float
    radius_px: float
    score: float


def to_gray(image: np.ndarray) -> np.ndarray:
    """Float32 intensity in [0, 1] of an RGB (h, w, 3) or gray (h, w) uint8 image."""
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    return gray.astype(np.float32) / 255.0


def log_response(gray: np.ndarray, sigma: float) -> np.ndarray:
    """Scale-normalised LoG, sigma^2 * laplacian(G_sigma * I): positive on dark blobs."""
    blurred = cv2.GaussianBlur(gray, (0, 0), sigma)
    return (sigma ** 2) * cv2.Laplacian(blurred, cv2.CV_32F, ksize=3)


def disk_template(radius_px: float, margin: float = 1.0,
                  shape: np.ndarray | None = None) -> np.ndarray:
    """A dark disk (0) on a bright square (1), anti-aliased, side about 2 (1 + margin) r.
    With ``shape`` (2x2: pixel offset of the rim point at angle t is shape @ (cos t,
    sin t)) the disk is the ellipse a circle seen obliquely makes."""
    A = np.diag([radius_px, radius_px]) if shape is None else np.asarray(shape, float)
    reach = float(np.linalg.norm(A, 2))
    half = math.ceil(reach * (1 + margin)) + 1
    y, x = np.mgrid[-half:half + 1, -half:half + 1].astype(float)
    q = np.linalg.solve(A, np.stack([x.ravel(), y.ravel()]))  # in unit-circle units
    norm = np.linalg.norm(q, axis=0)
    unit = np.where(norm > 1e-9, q / np.maximum(norm, 1e-9), np.array([[1.0], [0.0]]))
    scale = np.linalg.norm(A @ unit, axis=0)  # pixels per unit radius this way
    signed = ((norm - 1) * scale).reshape(x.shape)  # about the distance to the rim (px)
    return np.clip(signed + 0.5, 0.0, 1.0).astype(np.float32)


def _subpixel(values: np.ndarray, y: int, x: int) -> tuple[float, float]:
    """Peak offset (dx, dy) of the quadratic surface through the 3x3 neighbourhood (its
    cross term follows a tilted peak, as an oblique hole's ellipse makes)."""
    h, w = values.shape
    if not (0 < y < h - 1 and 0 < x < w - 1):
        return 0.0, 0.0
    dy, dx = np.mgrid[-1:2, -1:2].reshape(2, -1).astype(float)
    design = np.column_stack([np.ones(9), dx, dy, dx * dx, dy * dy, dx * dy])
    c = np.linalg.lstsq(design, values[y - 1:y + 2, x - 1:x + 2].ravel().astype(float),
                        rcond=None)[0]
    hessian = np.array([[2 * c[3], c[5]], [c[5], 2 * c[4]]])
    if np.linalg.det(hessian) <= 0 or hessian[0, 0] >= 0:  # not a maximum
        return 0.0, 0.0
    ox, oy = np.linalg.solve(hessian, -c[1:3])
    return float(np.clip(ox, -0.5, 0.5)), float(np.clip(oy, -0.5, 0.5))


def detect_holes(image: np.ndarray, radius_px: float, max_count: int = 20,
                 min_score: float = 0.5, shape: np.ndarray | None = None
                 ) -> list[HoleDetection]:
    """Dark disks of about ``radius_px`` pixels (of ``shape``, see
    :func:`disk_template`, when given), best first."""
    gray = to_gray(image)
    if shape is not None:
        radius_px = math.sqrt(abs(float(np.linalg.det(shape))))  # the same area
    response = log_response(gray, max(radius_px / math.sqrt(2), 0.7))
    peaks = (response == cv2.dilate(response, np.ones((5, 5), np.uint8))) & (response > 0.05)
    ys, xs = np.nonzero(peaks)
    order = np.argsort(-response[ys, xs])[: 5 * max_count]
    template = disk_template(radius_px, shape=shape)
    half = template.shape[0] // 2
    found: list[HoleDetection] = []
    for y, x in zip(ys[order], xs[order], strict=True):
        det = match_hole_near(gray, template, half, int(x), int(y), radius_px)
        if det is None or det.score < min_score:
            continue
        if any(math.hypot(det.u - d.u, det.v - d.v) < radius_px for d in found):
            continue
        found.append(det)
    found.sort(key=lambda d: -d.score)
    return found[:max_count]


def match_hole_near(gray: np.ndarray, template: np.ndarray, half: int, x: int, y: int,
                    radius_px: float) -> HoleDetection | None:
    """The hole ``template`` (:func:`disk_template`, ``half`` its half-width) matched in a
    window around pixel (x, y) of ``gray``, at sub-pixel precision; None if the window
    leaves the image."""
    reach = max(2, int(radius_px // 2))
    x0, y0 = x - half - reach, y - half - reach
    x1, y1 = x + half + reach + 1, y + half + reach + 1
    if x0 < 0 or y0 < 0 or x1 > gray.shape[1] or y1 > gray.shape[0]:
        return None
    scores = cv2.matchTemplate(gray[y0:y1, x0:x1], template, cv2.TM_CCOEFF_NORMED)
    _, best, _, (bx, by) = cv2.minMaxLoc(scores)
    dx, dy = _subpixel(scores, by, bx)
    return HoleDetection(x0 + half + bx + dx, y0 + half + by + dy, radius_px, float(best))


def holes_near(image: np.ndarray, expected_uv: tuple[float, float], radius_px: float,
               search_px: float, shape: np.ndarray | None = None) -> list[HoleDetection]:
    """The detected holes within ``search_px`` pixels of where one is expected, nearest
    first."""
    def gap(d: HoleDetection) -> float:
        return math.hypot(d.u - expected_uv[0], d.v - expected_uv[1])

    return sorted((d for d in detect_holes(image, radius_px, shape=shape)
                   if gap(d) <= search_px), key=gap)


def locate_hole(image: np.ndarray, expected_uv: tuple[float, float], radius_px: float,
                search_px: float, shape: np.ndarray | None = None) -> HoleDetection | None:
    """The detected hole nearest to where it is expected, within ``search_px`` pixels."""
    near = holes_near(image, expected_uv, radius_px, search_px, shape)
    return near[0] if near else None
