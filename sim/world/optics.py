"""Depth of field in the image: defocus blur from the thin-lens circle of confusion.

The lens is focused at the distance s whose inverse is the mean of the inverses of the
depth of field's limits, so that the blur is the same at both; the aperture makes the
circle of confusion there the acceptable one, ``coc_px``. At depth z the blur circle's
diameter is c(z) = coc_px |1/z - 1/s| / |1/near - 1/s| pixels: below ``coc_px`` inside
the depth of field, growing outside it. Each pixel is blurred by a Gaussian of the
disk's spread (sigma = c / (2 sqrt 2)), interpolated between a few blur levels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

LEVELS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)  # Gaussian sigmas (px) computed once each


@dataclass(frozen=True)
class Lens:
    """Depth of field ``near_m`` to ``far_m`` and the acceptable circle of confusion."""

    near_m: float
    far_m: float
    coc_px: float = 1.5

    @property
    def focus_m(self) -> float:
        return 2.0 / (1.0 / self.near_m + 1.0 / self.far_m)

    @property
    def blur_sd_px(self) -> float:
        """The Gaussian blur's sd (px) at the depth of field's limits: its largest within."""
        return self.coc_px / (2 * np.sqrt(2))

    def blur_px(self, depth: np.ndarray) -> np.ndarray:
        """Blur-circle diameter (px) at z-depths (m); 0 where the depth is not finite."""
        z = np.where(np.isfinite(depth) & (depth > 0), depth, self.focus_m)
        edge = abs(1.0 / self.near_m - 1.0 / self.focus_m)
        return self.coc_px * np.abs(1.0 / z - 1.0 / self.focus_m) / edge


def defocus(rgb: np.ndarray, depth: np.ndarray, lens: Lens) -> np.ndarray:
    """The image (uint8, h x w x 3) as the lens renders it, given each pixel's depth."""
    sigma = np.minimum(lens.blur_px(depth) / (2 * np.sqrt(2)), LEVELS[-1])
    image = rgb.astype(np.float32)
    out = np.zeros_like(image)
    levels = np.asarray(LEVELS)
    upper = np.clip(np.searchsorted(levels, sigma, side="right"), 1, len(levels) - 1)
    lower = upper - 1
    weight = (sigma - levels[lower]) / (levels[upper] - levels[lower])
    for k, s in enumerate(LEVELS):
        if not ((lower == k).any() or (upper == k).any()):
            continue
        blurred = image if s == 0 else cv2.GaussianBlur(image, (0, 0), s)
        _add_level(out, blurred, lower, upper, weight, k)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@nb.njit(cache=True)
def _add_level(out: np.ndarray, blurred: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               weight: np.ndarray, level: int) -> None:
    """Add blur level ``level``'s share to each pixel (h, w, 3) between it and the next
    level: 1 - weight where it is the lower one, weight where it is the upper one."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            if lower[i, j] == level:
                share = 1.0 - weight[i, j]
            elif upper[i, j] == level:
                share = weight[i, j]
            else:
                continue
            for c in range(out.shape[2]):
                out[i, j, c] = np.float32(out[i, j, c] + share * np.float64(blurred[i, j, c]))
