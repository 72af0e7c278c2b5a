"""The calibration package's one exception type."""

from __future__ import annotations


class CalibrationError(ValueError):
    """A bad argument to the calibration code, or data it cannot calibrate from: the
    message names the value and what is accepted."""
