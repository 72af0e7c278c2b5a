"""The fiducial tracker's settings: how keypoints are found and matched across the stereo
pair, and how fiducials are followed from frame to frame.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TrackerSettings:
    """How fiducials are found and followed (pixels unless stated)."""

    detector: str = "sift"  # "sift" or "orb" (FAST corners refined to sub-pixel)
    stereo: str = "descriptors"  # right pixels by "descriptors", "flow" (calibration/flow.py)
    # or "correlation" along the row
    row_px: float = 1.0  # with "descriptors": a stereo match's rows differ by at most this
    features: int = 800  # keypoints per image at most
    contrast: float = 0.01  # SIFT contrast threshold (of intensities in [0, 1])
    ratio: float = 0.8  # a fiducial match's descriptor distance over the runner-up's, at most
    patch_px: int = 11  # side of the patch a left keypoint is correlated along its row
    max_disparity_px: float = 160.0  # f b / 0.31 m for the default head (416 px, 0.12 m):
    # nearer than any placed camera's depth of field
    min_correlation: float = 0.8  # a stereo match's normalised correlation, at least
    peak_margin: float = 0.1  # ... and this above any other disparity's
    search_px: float = 30.0  # around the predicted projection
    inlier_px: float = 2.0
    min_inliers: int = 8
    max_jump_m: float = 0.03  # a located pose this far from the prediction is refused
    max_jump_deg: float = 2.0
    pixel_sigma: float = 0.3  # of a keypoint's position
