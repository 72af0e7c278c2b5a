"""The panel in a colour image: its pixels (the hull of its yellow squares) and the
image windows around them that stereo measuring of it needs."""

from __future__ import annotations

import cv2
import numpy as np


def panel_mask(rgb: np.ndarray) -> np.ndarray:
    """The panel's pixels: the convex hull of its yellow squares (largest blob).

    Two other colours blended across an edge pass through yellow (orange against green,
    in the one-pixel line a multisampled render draws along it): such a line touching the
    panel would join its blob and stretch the hull over the background, so lines under
    three pixels wide are opened away after the squares are closed together."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    yellow = cv2.inRange(hsv, (20, 100, 50), (38, 255, 255))  # not the orange bases (17)
    joined = cv2.morphologyEx(yellow, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        cv2.morphologyEx(joined, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)))
    mask = np.zeros(rgb.shape[:2], np.uint8)
    if count <= 1:
        return mask.astype(bool)
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    ys, xs = np.nonzero(labels == biggest)
    hull = cv2.convexHull(np.column_stack([xs, ys]).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1)
    return cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)  # off its outline


def window(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    """Rows and columns within ``margin`` pixels of ``mask``'s pixels (it has some)."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    return (slice(max(0, ys.min() - margin), min(h, ys.max() + margin + 1)),
            slice(max(0, xs.min() - margin), min(w, xs.max() + margin + 1)))


def measuring_window(mask: np.ndarray, margin: int, disparities: int) -> tuple[slice, slice]:
    """:func:`window`, with a left image's stereo disparity range (``disparities``
    pixels) in front (left) of it: the right image's match of a pixel lies up to that
    far left of it."""
    rows, cols = window(mask, margin)
    return rows, slice(max(0, cols.start - disparities), cols.stop)
