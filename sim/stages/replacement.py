"""Placing a camera again during the task: the outcome (its record and the camera as the
task now knows it), and the signature of the callback that makes it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from taskcam.sim.stages.task_result import Camera


@dataclass(frozen=True)
class Replacement:
    """A camera's re-placement during the task: its record in ``replacements``, and the
    camera as the task now knows it (None: it could not be placed again)."""

    record: dict[str, Any]
    camera: Camera | None


# Given a camera to place again, the step, why, its site rating now (None: it lost the
# panel, any view is better) and the panel's believed pose: its re-placement, or None if
# cameras are not re-placed.
Replace = Callable[[Camera, int, str, float | None, np.ndarray], Replacement | None]
