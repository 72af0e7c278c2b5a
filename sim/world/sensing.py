"""A robot's stereo head as a depth camera: the renderer's ideal depth, or block matching
on the rendered left and right images."""

from __future__ import annotations

from typing import Literal

import mujoco
import numpy as np

from taskcam.mapping import Pinhole, stereo_depth
from taskcam.sim.world.render import Renderer
from taskcam.sim.world.scene import Robot


class DepthSensor:
    """Z-depth (m) in the left camera: ``inf`` where nothing was hit, NaN where unknown.

    Pixels that see a robot are NaN: the robots know their own bodies and joint states
    and filter them out (a robot self-filter), so moving arms are not mapped as
    obstacles. The mask comes from rendering the robots at their known poses.
    """

    def __init__(self, renderer: Renderer, pinhole: Pinhole, source: Literal["render", "stereo"],
                 baseline_m: float, robot_geoms: np.ndarray) -> None:
        self.renderer, self.pinhole, self.source = renderer, pinhole, source
        self.baseline_m = baseline_m
        self.robot_geoms = robot_geoms  # bool per geom id

    def depth(self, data: mujoco.MjData, robot: Robot) -> np.ndarray:
        if self.source == "render":
            depth = self.renderer.depth(data, robot.camera)
        else:
            left = self.renderer.rgb(data, robot.camera)
            right = self.renderer.rgb(data, robot.right_camera)
            depth = stereo_depth(left, right, self.pinhole, self.baseline_m)
        seen = self.renderer.segmentation(data, robot.camera)
        depth[(seen >= 0) & self.robot_geoms[np.maximum(seen, 0)]] = np.nan
        return depth
