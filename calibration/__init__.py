"""Calibration from images (sec. 2.2, 2.4): target detection; natural fiducials, the
camera's pose from them (eq. 5-6, Kabsch, SQPnP), recursive pose statistics (eq. 7),
fiducial EKFs (eq. 10-12) and bundle adjustment of stereo keyframes. Free of MuJoCo."""

from .errors import CalibrationError
from .targets import (
    HoleDetection,
    detect_holes,
    disk_template,
    holes_near,
    locate_hole,
    log_response,
    match_hole_near,
    to_gray,
)

__all__ = ["CalibrationError", "HoleDetection", "detect_holes", "disk_template", "holes_near",
           "locate_hole", "log_response", "match_hole_near", "to_gray"]
