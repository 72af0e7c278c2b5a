"""Calibration from images: target detection (sec. 2.2). Free of MuJoCo."""

from .targets import HoleDetection, detect_holes, disk_template, locate_hole, log_response, to_gray

__all__ = ["HoleDetection", "detect_holes", "disk_template", "locate_hole", "log_response",
           "to_gray"]
