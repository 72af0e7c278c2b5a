"""A robot's stereo head as a depth camera: the renderer's ideal depth, or block matching
on the rendered left and right images."""

from __future__ import annotations

from typing import Literal

import mujoco
import numpy as np

from mapping import Pinhole, stereo_depth

from .render import Renderer
from .scene import Robot


class DepthSensor:
    """Z-depth (m) in the left camera: ``inf`` where nothing was hit, NaN where unknown."""

    def __init__(self, renderer: Renderer, pinhole: Pinhole, source: Literal["render", "stereo"],
                 baseline_m: float) -> None:
        self.renderer, self.pinhole, self.source = renderer, pinhole, source
        self.baseline_m = baseline_m

    def depth(self, data: mujoco.MjData, robot: Robot) -> np.ndarray:
        if self.source == "render":
            return self.renderer.depth(data, robot.camera)
        left = self.renderer.rgb(data, robot.camera)
        right = self.renderer.rgb(data, robot.right_camera)
        return stereo_depth(left, right, self.pinhole, self.baseline_m)
