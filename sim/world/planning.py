"""Planning one robot's move to a camera pose, in the planner's world: the nominal model
with every robot at its commanded joints (the others where they said they would be)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from sim.world.collision import Proximity
from sim.world.ik import IKResult, IKSettings, solve_camera_pose
from sim.world.motion import dense_path
from sim.world.scene import Robot, Scene


@dataclass(frozen=True)
class Plan:
    """An IK solution and its path, and why it may not be taken (None: it may)."""

    ik: IKResult
    reason: str | None  # "unreachable" or "collision"


class ArmPlanner:
    """Plans camera moves with collision-avoiding IK and checks the path densely.

    ``belief`` (data of the nominal model) holds the commanded configuration; a plan
    that may be taken leaves the robot at its goal there, any other leaves it as it was.
    """

    def __init__(self, scene: Scene, belief: mujoco.MjData, clearance_m: float,
                 ik_margin_m: float, move_base: bool = True,
                 settings: IKSettings = IKSettings()) -> None:
        self.scene, self.belief = scene, belief
        self.clearance_m, self.ik_margin_m = clearance_m, ik_margin_m
        self.move_base, self.settings = move_base, settings
        self._proximity: dict[str, Proximity] = {}

    def proximity(self, robot: Robot) -> Proximity:
        if robot.name not in self._proximity:
            self._proximity[robot.name] = Proximity(self.scene.model, robot, self.scene.robots)
        return self._proximity[robot.name]

    def plan(self, robot: Robot, look_at: np.ndarray, position: np.ndarray) -> Plan:
        start = self.belief.qpos.copy()
        near = self.proximity(robot)
        ik = solve_camera_pose(self.scene.model, start, robot, look_at, position,
                               self.move_base, self.settings, near.avoid, self.ik_margin_m)
        if not ik.converged:
            return Plan(ik, "unreachable")
        if not self.path_clear(robot, ik.path):
            self.scene.set_robot(self.belief, robot, start)
            return Plan(ik, "collision")
        self.scene.set_robot(self.belief, robot, ik.qpos)
        return Plan(ik, None)

    def path_clear(self, robot: Robot, path: np.ndarray) -> bool:
        """Does every point along the joint path, densely, keep the clearance from the
        other robots and the world, and the robot's links apart?"""
        q = self.belief.qpos.copy()
        near = self.proximity(robot)
        for joints in dense_path(path):
            q[robot.qpos_adr] = joints
            self.scene.set_robot(self.belief, robot, q)
            c = near.measure(self.belief)
            if c.own <= 0.0 or c.others < self.clearance_m:
                return False
        return True
