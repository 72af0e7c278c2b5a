"""A left keypoint's right pixel by optical flow (``stereo = "flow"``):
pyramidal Lucas-Kanade (OpenCV) from the left image to the right one, started at a
guessed disparity and checked by flowing back. It spares SIFT on the right image, which
costs as much as on the left, for disparities nearly as good: over the default seed
0's located frames, against the renderer's depth, a median error of 0.128 px, 90th
percentile 0.590 (SIFT matched in both images: 0.095 and 0.417; bench/studies/tracker_truth.py).
On the pose-correction bench it corrects a little worse (docs/benchmarks.md), so it is
not the default."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

# Lucas-Kanade's iterations stop after 30 or once a step is under 0.01 px
FLOW_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)


@dataclass(frozen=True)
class FlowSettings:
    """How a pixel is followed from one image into another (pixels)."""

    window_px: int = 15  # Lucas-Kanade's window: textured enough, little of a far surface
    levels: int = 4  # pyramid levels above the image: a start may be 2**4 x 7 px off
    check_px: float = 0.3  # flowed back, a pixel must land this near where it began


def flow(before: np.ndarray, after: np.ndarray, points: np.ndarray, start: np.ndarray,
         s: FlowSettings) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) in ``after`` of ``points`` (n, 2) of ``before`` (8-bit images),
    searched from ``start`` (n, 2), and whether each was followed there and back to
    within ``check_px`` and lies inside the image."""
    if len(points) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    p0 = np.ascontiguousarray(points, np.float32).reshape(-1, 1, 2)
    guess = np.ascontiguousarray(start, np.float32).reshape(-1, 1, 2)
    window = (s.window_px, s.window_px)
    p1, ok1, _ = cv2.calcOpticalFlowPyrLK(before, after, p0, guess, winSize=window,
                                          maxLevel=s.levels, criteria=FLOW_CRITERIA,
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(after, before, p1, p0.copy(), winSize=window,
                                            maxLevel=s.levels, criteria=FLOW_CRITERIA,
                                            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    there = np.asarray(p1, float).reshape(-1, 2)
    ok = (ok1.ravel() == 1) & (ok2.ravel() == 1)
    ok &= np.linalg.norm(np.asarray(back, float).reshape(-1, 2) - points, axis=1) <= s.check_px
    h, w = after.shape[:2]
    ok &= (there[:, 0] >= 0) & (there[:, 1] >= 0) & (there[:, 0] <= w - 1) & (there[:, 1] <= h - 1)
    return there, ok


def nearest_disparity(pts: np.ndarray, expected: np.ndarray | None, default: float
                      ) -> np.ndarray:
    """A first disparity (n) for left pixels (n, 2): that of the nearest pixel where a
    known fiducial is ``expected`` ((u, v, d), m x 3), or ``default`` with none."""
    if expected is None or len(expected) == 0:
        return np.full(len(pts), default)
    _, nearest = cKDTree(expected[:, :2]).query(pts)
    return np.asarray(expected[nearest, 2], float)


def flow_disparities(left: np.ndarray, right: np.ndarray, pts: np.ndarray, guess: np.ndarray,
                     row_px: float, most_px: float, s: FlowSettings = FlowSettings()
                     ) -> np.ndarray:
    """Disparity (px) of each left point (n, 2) in the rectified right image (8-bit),
    NaN where none is sure: flowed (:func:`flow`) from the disparity ``guess`` (n), and
    kept if its row moved at most ``row_px`` and its disparity lies in (0.5,
    ``most_px``]."""
    out = np.full(len(pts), np.nan)
    if len(pts) == 0:
        return out
    there, ok = flow(left, right, pts, pts - np.column_stack([guess, np.zeros(len(pts))]), s)
    d = pts[:, 0] - there[:, 0]
    ok &= (np.abs(there[:, 1] - pts[:, 1]) <= row_px) & (d > 0.5) & (d <= most_px)
    out[ok] = d[ok]
    return out
