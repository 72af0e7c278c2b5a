"""Planning one robot's move to a camera pose, in the planner's world: the nominal model
with every robot at its commanded joints (the others where they said they would be).

A move is planned in two parts. Its goal: mink's IK puts the camera at the candidate
position looking at the target, from a few seeds (the robot standing off behind the
candidate, facing the target, from three sides; then where it stands now), and the first
solution that keeps its clearance is the goal. Its way there: OMPL's RRT-Connect
searches the robot's joint space (base x, y, yaw and the six arm joints) for a
collision-free path, which OMPL's simplifier then shortens. The planner's world is
MuJoCo's: a configuration is valid when the robot's collision geoms keep the clearance
from everything but the floor (distance queries of the nominal model), its own links
stay apart, and its base stays within how far it may drive. The budget is a number of
validity checks, not seconds, so the same seed plans the same path on any machine.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from sim.world.collision import Proximity
from sim.world.ik import IKResult, IKSettings, solve_camera_pose
from sim.world.motion import dense_path
from sim.world.scene import Robot, Scene

ou.setLogLevel(ou.LOG_NONE)

CHECK_STEP = 0.01  # m (base) or rad (joints): motions are checked at least this finely
# The seeds' stand-off sides: behind the candidate as seen from the target, and turned
# about the candidate by these angles (deg): the first side that is clear is taken
STAND_OFF_TURNS_DEG = (0.0, 50.0, -50.0, 100.0, -100.0, 180.0)
ARM_SWING_RAD = math.pi / 2  # see ArmPlanner._bounds
# RRT-Connect's longest step (joint space, m and rad): a tree grows in steps short
# enough that a blocked one wastes few checks (its default, a fifth of the space's
# extent, is several metres and radians here)
STEP_RANGE = 1.0
SELF_CLEARANCE_M = 0.0  # a robot's own non-neighbouring links must not touch


@dataclass(frozen=True)
class Plan:
    """A goal configuration and the joint path there, or why there is none: ``reason``
    is None (it may be taken), "no goal configuration" (no IK solution that keeps the
    clearance) or "no path within the budget"."""

    ik: IKResult  # the goal's IK solution (or the best attempt)
    reason: str | None
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))  # (k, 9) joints
    checks: int = 0  # validity checks spent
    seconds: float = 0.0  # wall clock of goal and path

    def summary(self) -> dict[str, Any]:
        """The path's waypoints, base and arm lengths, and what planning cost."""
        out: dict[str, Any] = {"reason": self.reason, "validity_checks": self.checks,
                               "planning_s": round(self.seconds, 4)}
        if len(self.path):
            steps = np.diff(self.path, axis=0)
            out |= {"waypoints": len(self.path),
                    "base_path_m": round(float(np.linalg.norm(steps[:, :2], axis=1).sum()), 4),
                    "base_turn_rad": round(float(np.abs(steps[:, 2]).sum()), 4),
                    "arm_path_rad": round(float(np.linalg.norm(steps[:, 3:], axis=1).sum()), 4)}
        return out


class ArmPlanner:
    """Plans camera moves for the robots of ``scene``: goal by IK, path by OMPL.

    ``belief`` (data of the nominal model) holds the commanded configuration; a plan
    that may be taken leaves the robot at its goal there, any other leaves it as it was.
    A base may drive at most ``drive_m`` (horizontal) from where it started the episode;
    ``checks`` is the path search's budget of validity checks; ``rng`` seeds each plan.
    """

    def __init__(self, scene: Scene, belief: mujoco.MjData, clearance_m: float,
                 ik_margin_m: float, move_base: bool = True, *, drive_m: float = 1.5,
                 checks: int = 20000, rng: np.random.Generator | None = None,
                 settings: IKSettings = IKSettings()) -> None:
        self.scene, self.belief = scene, belief
        self.clearance_m, self.ik_margin_m = clearance_m, ik_margin_m
        self.move_base, self.settings = move_base, settings
        self.drive_m, self.checks = drive_m, checks
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._proximity: dict[str, Proximity] = {}
        self._scratch = mujoco.MjData(scene.model)

    def proximity(self, robot: Robot) -> Proximity:
        if robot.name not in self._proximity:
            self._proximity[robot.name] = Proximity(self.scene.model, robot, self.scene.robots)
        return self._proximity[robot.name]

    def home(self, robot: Robot) -> np.ndarray:
        """Where the robot's base started the episode (x, y; m)."""
        return self.scene.start_qpos[robot.qpos_adr[:2]]

    # ------------------------------------------------------------ validity

    def _valid(self, robot: Robot, joints: np.ndarray, clearance_m: float) -> bool:
        """Is the robot at ``joints`` (9) clear of everything by ``clearance_m``, its own
        links apart, and its base within its drive?"""
        if np.hypot(*(joints[:2] - self.home(robot))) > self.drive_m + 1e-9:
            return False
        d = self._scratch
        d.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(self.scene.model, d)
        c = self.proximity(robot).measure(d)
        return c.own > SELF_CLEARANCE_M and c.others >= clearance_m

    # ------------------------------------------------------------ goal

    def _seeds(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
               position: np.ndarray) -> list[np.ndarray]:
        """Configurations to start the goal's IK from: standing off behind the
        candidate (as far from it as the camera is from the base now), facing the
        target, from each side in STAND_OFF_TURNS_DEG; then the present one."""
        seeds = []
        if self.move_base:
            q = start[robot.qpos_adr]
            self._scratch.qpos[:] = start
            mujoco.mj_kinematics(self.scene.model, self._scratch)
            camera = self._scratch.site(robot.optical_site).xpos
            offset = float(np.hypot(*(camera[:2] - q[:2])))  # base to camera, horizontal
            facing = math.atan2(*(look_at[1::-1] - position[1::-1]))  # candidate to target
            camera_bearing = math.atan2(camera[1] - q[1], camera[0] - q[0]) - q[2]
            for turn in STAND_OFF_TURNS_DEG:
                yaw = facing + math.radians(turn)
                seed = start.copy()
                base = position[:2] - offset * np.array([math.cos(yaw), math.sin(yaw)])
                # the base turned so that the camera lies ahead of it as it does now
                seed[robot.qpos_adr[:2]] = base
                seed[robot.qpos_adr[2]] = _near_angle(yaw - camera_bearing, q[2])
                seeds.append(seed)
        seeds.append(start.copy())
        return seeds

    def goal(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
             position: np.ndarray) -> tuple[IKResult, bool]:
        """The first IK solution from the seeds that keeps the clearance (with the IK
        margin) and the drive limit; else the best attempt, and False."""
        best: IKResult | None = None
        for seed in self._seeds(robot, start, look_at, position):
            ik = solve_camera_pose(self.scene.model, seed, robot, look_at, position,
                                   self.move_base, self.settings)
            if ik.converged and self._valid(robot, ik.qpos[robot.qpos_adr], self.ik_margin_m):
                return ik, True
            if best is None or ik.position_error_m < best.position_error_m:
                best = ik
        assert best is not None
        return best, False

    # ------------------------------------------------------------ path

    def path(self, robot: Robot, start: np.ndarray, goal: np.ndarray
             ) -> tuple[np.ndarray | None, int]:
        """OMPL's RRT-Connect from ``start`` to ``goal`` (9 joints each), simplified;
        None if none was found within the budget; and the validity checks spent."""
        active = list(range(9)) if self.move_base else list(range(3, 9))
        fixed = start.copy()
        lo, hi = self._bounds(robot, start, goal)
        space = ob.RealVectorStateSpace(len(active))
        bounds = ob.RealVectorBounds(len(active))
        for i, j in enumerate(active):
            bounds.setLow(i, float(lo[j]))
            bounds.setHigh(i, float(hi[j]))
        space.setBounds(bounds)
        ou.RNG.setSeed(int(self.rng.integers(1, 2 ** 31 - 1)))  # before the planner's RNGs
        setup = og.SimpleSetup(space)
        spent = [0]

        def joints_of(state: Any) -> np.ndarray:
            q = fixed.copy()
            q[active] = [state[i] for i in range(len(active))]
            return q

        def valid(state: Any) -> bool:
            spent[0] += 1
            return self._valid(robot, joints_of(state), self.clearance_m)

        setup.setStateValidityChecker(valid)
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(CHECK_STEP / space.getMaximumExtent())
        a, b = space.allocState(), space.allocState()
        for i, j in enumerate(active):
            a[i], b[i] = float(start[j]), float(goal[j])
        setup.setStartAndGoalStates(a, b)
        setup.setup()
        if info.checkMotion(a, b):  # the straight way is clear: no search needed
            return np.array([start, goal]), spent[0]
        planner = og.RRTConnect(info)
        planner.setRange(STEP_RANGE)
        setup.setPlanner(planner)
        stop = ob.PlannerTerminationCondition(lambda: spent[0] >= self.checks)
        setup.solve(stop)
        if not setup.haveExactSolutionPath():
            return None, spent[0]
        setup.simplifySolution()  # no time limit: OMPL's full, deterministic simplification
        found = setup.getSolutionPath()
        path = np.array([joints_of(found.getState(k)) for k in range(found.getStateCount())])
        return path, spent[0]

    def _bounds(self, robot: Robot, start: np.ndarray, goal: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """The joint space searched (9 each): the base's drive square, a quarter turn
        beyond where its yaw starts and ends, the arm's joints ARM_SWING_RAD beyond where they start
        and end (within their ranges)."""
        m = self.scene.model
        q0, q1 = start, goal
        ids = [m.jnt_qposadr.tolist().index(a) for a in robot.qpos_adr]
        lo, hi = m.jnt_range[ids, 0].copy(), m.jnt_range[ids, 1].copy()
        home = self.home(robot)
        lo[:2], hi[:2] = home - self.drive_m, home + self.drive_m
        lo[2] = min(q0[2], q1[2]) - math.pi / 2
        hi[2] = max(q0[2], q1[2]) + math.pi / 2
        # the arm's joints within a quarter turn beyond where they start and end: a
        # camera move needs no more, and the search does not wander through whole turns
        lo[3:] = np.maximum(lo[3:], np.minimum(q0[3:], q1[3:]) - ARM_SWING_RAD)
        hi[3:] = np.minimum(hi[3:], np.maximum(q0[3:], q1[3:]) + ARM_SWING_RAD)
        lo, hi = np.minimum(lo, np.minimum(q0, q1)), np.maximum(hi, np.maximum(q0, q1))
        return lo, hi

    # ------------------------------------------------------------ both

    def plan(self, robot: Robot, look_at: np.ndarray, position: np.ndarray) -> Plan:
        started = time.perf_counter()
        start = self.belief.qpos.copy()
        self._scratch.qpos[:] = start
        ik, ok = self.goal(robot, start, look_at, position)
        if not ok:
            return Plan(ik, "no goal configuration", seconds=time.perf_counter() - started)
        path, checks = self.path(robot, start[robot.qpos_adr], ik.qpos[robot.qpos_adr])
        self._scratch.qpos[:] = start
        if path is None:
            return Plan(ik, "no path within the budget", checks=checks,
                        seconds=time.perf_counter() - started)
        self.scene.set_robot(self.belief, robot, ik.qpos)
        return Plan(ik, None, path, checks, time.perf_counter() - started)


    def camera_path(self, robot: Robot, path: np.ndarray) -> np.ndarray:
        """Where the robot's camera goes along a joint path (n, 3; m), densely."""
        d = self._scratch
        d.qpos[:] = self.belief.qpos
        out = []
        for joints in dense_path(path, 0.05, 0.05):
            d.qpos[robot.qpos_adr] = joints
            mujoco.mj_kinematics(self.scene.model, d)
            out.append(d.site(robot.optical_site).xpos.copy())
        return np.array(out)


def _near_angle(angle: float, reference: float) -> float:
    """``angle`` (rad) shifted by whole turns to lie within half a turn of ``reference``."""
    return reference + (angle - reference + math.pi) % (2 * math.pi) - math.pi
