"""Planning one robot's move to a camera pose, in the planner's world: the nominal model
with every robot at its commanded joints (the others where they said they would be).

A move is planned in two parts. Its goal: mink's IK puts the camera at the candidate
position looking at the target, from seeds where the base can stand (behind the
candidate, facing the target, from the nearest clear sides; then where it stands now),
and the first solution that keeps its clearance is the goal. Its way there: straight,
or as mobile manipulators travel (arm tucked, base driven, arm out), or OMPL's
RRT-Connect over the robot's joint space (base x, y, yaw and the six arm joints);
OMPL's simplifier reduces a searched path's waypoints. The planner's world is MuJoCo's
and the map's: a configuration is valid when the robot's collision geoms keep the
clearance from everything the nominal model knows but the floor (MuJoCo's distance
queries), from what the robots mapped where the clutter is known only by the maps
(sim/world/mapped_obstacles.py; given the maps) and from the boxes it is told to keep
out of, its own links stay apart, and its base stays within how far it may
drive. The budget is a number of validity checks, not seconds, so the same seed
plans the same path on any machine.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou
from scipy.ndimage import label
from scipy.spatial import cKDTree

from mapping import FloorMap, OccupancyGrid
from sim.world.base_scanner import SCAN_HEIGHT_M
from sim.world.collision import KeepOut, Proximity
from sim.world.ik import IKResult, IKSettings, solve_camera_pose
from sim.world.mapped_obstacles import MapFields, left_to_map, map_fields, robot_spheres
from sim.world.motion import dense_path
from sim.world.scene import ARM_REACH_M, Robot, Scene

ou.setLogLevel(ou.LOG_NONE)

# The goal's IK from a stand-off seed: the base stays about where the seed put it (its
# posture costs 100 times the arm's) and the arm reaches; the seeds search for where the
# base stands
GOAL_IK = IKSettings(base_posture_cost=0.1)
CHECK_STEP = 0.01  # m (base) or rad (joints): motions are checked at least this finely
# The seeds' stand-off sides: behind the candidate as seen from the target, and turned
# about the candidate by these angles (deg), nearest first (a check costs 0.1 ms)
STAND_OFF_TURNS_DEG = (0.0, 30.0, -30.0, 60.0, -60.0, 90.0, -90.0, 120.0, -120.0, 150.0,
                       -150.0, 180.0)
# ... as far as the home posture holds its camera from its base (about 0.6 m), or this
# much farther (m): the arm stretched over what stands in front of the candidate (a
# table's edge), within its reach (ARM_REACH_M): from farther the arm cannot get there
STAND_OFF_BACK_M = (0.0, 0.35)
# At most this many clear stand-off seeds are solved from (the nearest sides first): an
# IK solve costs 5-50 ms, and a candidate the arm cannot reach from the nearest clear
# sides is seldom reached from the farther ones
SOLVED_SEEDS = 4
STAND_CELL_M = 0.1  # the grid of places a base may stand on (m), see ArmPlanner.places
ARM_SWING_RAD = math.pi / 2  # see ArmPlanner._bounds
# RRT-Connect's longest step (joint space, m and rad): a tree grows in steps short
# enough that a blocked one wastes few checks (its default, a fifth of the space's
# extent, is several metres and radians here)
STEP_RANGE = 1.0


@dataclass(frozen=True)
class Plan:
    """A goal configuration and the joint path there, or why there is none: ``reason``
    is None (it may be taken), "no place to stand" (nowhere clear for the base near
    the candidate), "no goal configuration" (no IK solution that keeps the clearance)
    or "no path within the budget"."""

    ik: IKResult | None  # the goal's IK solution (or the best attempt; None: none tried)
    reason: str | None
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))  # (k, 9) joints
    checks: int = 0  # validity checks spent
    seconds: float = 0.0  # wall clock of goal and path

    def summary(self) -> dict[str, Any]:
        """The path's waypoints, base and arm lengths, and what planning cost."""
        out: dict[str, Any] = {"reason": self.reason, "validity_checks": self.checks,
                               "time_s": round(self.seconds, 4)}
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
    ``checks`` is the path search's budget of validity checks; ``rng`` seeds each plan;
    the robot's collision geoms (their bounding spheres) keep the clearance from the
    boxes ``keep_out`` too (the insertion's corridor). Given the robots' maps (``grid``,
    the cameras' voxels, and ``floor``, the bases' scanners' floor plan) the scene's
    obstacles inside the grid are known only as mapped (sim/world/mapped_obstacles.py;
    what the sensors never observed blocks the way if ``unobserved_blocks``); without
    them, as the nominal model has them.
    """

    def __init__(self, scene: Scene, belief: mujoco.MjData, clearance_m: float,
                 ik_margin_m: float, move_base: bool = True, *, drive_m: float = 1.5,
                 checks: int = 20000, rng: np.random.Generator | None = None,
                 keep_out: KeepOut | None = None, grid: OccupancyGrid | None = None,
                 floor: FloorMap | None = None, unobserved_blocks: bool = True,
                 places: dict[tuple[Any, ...], cKDTree] | None = None,
                 settings: IKSettings = IKSettings()) -> None:
        self.scene, self.belief = scene, belief
        self.clearance_m, self.ik_margin_m = clearance_m, ik_margin_m
        self.move_base, self.settings = move_base, settings
        self.drive_m, self.checks, self.keep_out = drive_m, checks, keep_out
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._proximity: dict[str, Proximity] = {}
        self._spheres = {r.name: robot_spheres(scene.model, r) for r in scene.robots}
        self._scratch = mujoco.MjData(scene.model)
        # clear places for each robot's base, by all they depend on (shared by planners)
        self._standing: dict[tuple[Any, ...], cKDTree] = {} if places is None else places
        self._depends: tuple[Any, ...] = (drive_m, clearance_m, move_base)
        if keep_out is not None:
            self._depends += (keep_out.centres.tobytes(), keep_out.rotations.tobytes(),
                              keep_out.halves.tobytes())
        self.unmapped: frozenset[int] = frozenset()  # obstacle geoms known by the map only
        self.maps: MapFields | None = None
        if grid is not None and floor is not None:
            self.unmapped = left_to_map(scene.model, belief, grid)
            started = mujoco.MjData(scene.model)  # every robot where it started
            started.qpos[:] = scene.start_qpos
            mujoco.mj_kinematics(scene.model, started)
            # a configuration held is clear by the planner's lights: the clearance, the
            # goal's margin and the fields' bounds' slack (a voxel's diagonal) around it
            slack = max(clearance_m, ik_margin_m) + grid.resolution * math.sqrt(3)
            self.maps = map_fields(grid, floor, scene.model, self.unmapped, (belief, started),
                                   self._spheres.values(), slack, SCAN_HEIGHT_M, unobserved_blocks)
            self._depends += (hashlib.blake2b(grid.log_odds.tobytes() + floor.state.tobytes()
                                              ).digest(), unobserved_blocks)

    def proximity(self, robot: Robot) -> Proximity:
        if robot.name not in self._proximity:
            self._proximity[robot.name] = Proximity(self.scene.model, robot, self.scene.robots,
                                                    skip=self.unmapped)
        return self._proximity[robot.name]

    def home(self, robot: Robot) -> np.ndarray:
        """Where the robot's base started the episode (x, y; m)."""
        return self.scene.start_qpos[robot.qpos_adr[:2]]

    def places(self, robot: Robot) -> cKDTree:
        """The places (x, y; m) the robot's base can get to: cells every STAND_CELL_M
        over its drive where it is clear (its arm at home, facing any of four ways),
        connected (side by side) to the one nearest where it stands now. Computed once
        for what it depends on (the planner's settings and maps, the commanded
        configuration, where the panel is), in the ``places`` the planner was given."""
        key = (robot.name, self.belief.qpos.tobytes(), self.belief.mocap_pos.tobytes(),
               self.belief.mocap_quat.tobytes(), *self._depends)
        if key not in self._standing:
            home = self.scene.start_qpos[robot.qpos_adr]
            here = self.belief.qpos[robot.qpos_adr[:2]]
            self._scratch.qpos[:] = self.belief.qpos
            steps = np.arange(-self.drive_m, self.drive_m + 1e-9, STAND_CELL_M)
            x, y = np.meshgrid(steps + home[0], steps + home[1], indexing="ij")
            inside = np.hypot(x - home[0], y - home[1]) <= self.drive_m
            clear = np.zeros(x.shape, bool)
            q = home.copy()
            for i, j in zip(*np.nonzero(inside), strict=True):
                q[:2] = x[i, j], y[i, j]
                clear[i, j] = any(self._valid(robot, q, self.clearance_m) for q[2] in
                                  home[2] + np.arange(4) * math.pi / 2)
            labels, _ = label(clear)
            keep = clear
            if clear.any():  # the part connected to the clear cell nearest the robot
                cells = np.column_stack([x[clear], y[clear]])
                ij = np.argwhere(clear)[np.argmin(np.hypot(*(cells - here).T))]
                keep = labels == labels[ij[0], ij[1]]
            self._standing[key] = cKDTree(np.column_stack([x[keep], y[keep]]))
        return self._standing[key]

    def standing_room(self, robot: Robot, positions: np.ndarray) -> np.ndarray:
        """For camera positions (n, 3; m): is there a place the base can get to
        (:meth:`places`) within the arm's reach of each? (A necessary condition, at a
        lookup's cost: the seeds decide.)"""
        if not self.move_base:
            return np.ones(len(positions), bool)
        tree = self.places(robot)
        if tree.n == 0:
            return np.zeros(len(positions), bool)
        near, _ = tree.query(positions[:, :2], distance_upper_bound=ARM_REACH_M)
        return np.isfinite(near)

    # ------------------------------------------------------------ validity

    def _valid(self, robot: Robot, joints: np.ndarray, clearance_m: float) -> bool:
        """Is the robot at ``joints`` (9) clear of everything by ``clearance_m``, its own
        links apart, and its base within its drive?"""
        if np.hypot(*(joints[:2] - self.home(robot))) > self.drive_m + 1e-9:
            return False
        d = self._scratch
        d.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(self.scene.model, d)
        near = self.proximity(robot)
        if self.keep_out is not None:  # each geom's bounding sphere out of it
            own = near.own_array
            apart = self.keep_out.distance(d.geom_xpos[own]) - self.scene.model.geom_rbound[own]
            if apart.min() < clearance_m:
                return False
        if self.maps is not None and self.maps.clearance(
                self._spheres[robot.name], d) < clearance_m:  # off what the maps hold
            return False
        return near.clear(d, clearance_m)

    # ------------------------------------------------------------ goal

    def _seeds(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
               position: np.ndarray) -> list[np.ndarray]:
        """Configurations to start the goal's IK from: the arm in its home posture
        (compact, as the robot starts the episode), the base standing off behind the
        candidate (as far as the home posture holds the camera from the base, or
        STAND_OFF_BACK_M farther), facing the target, from each side in
        STAND_OFF_TURNS_DEG; then the present configuration."""
        seeds = []
        if self.move_base:
            home = self.scene.start_qpos
            q = home[robot.qpos_adr]
            self._scratch.qpos[:] = start
            self._scratch.qpos[robot.qpos_adr] = q
            mujoco.mj_kinematics(self.scene.model, self._scratch)
            camera = self._scratch.site(robot.optical_site).xpos
            offset = float(np.hypot(*(camera[:2] - q[:2])))  # base to camera, horizontal
            bearing = math.atan2(camera[1] - q[1], camera[0] - q[0]) - q[2]  # in the base
            facing = math.atan2(*(look_at[1::-1] - position[1::-1]))  # candidate to target
            for turn, back in itertools.product(STAND_OFF_TURNS_DEG, STAND_OFF_BACK_M):
                yaw = facing + math.radians(turn)
                seed = start.copy()
                seed[robot.qpos_adr] = q
                seed[robot.qpos_adr[:2]] = position[:2] - (offset + back) * np.array(
                    [math.cos(yaw), math.sin(yaw)])
                # turned so that the camera lies ahead of the base as at home
                seed[robot.qpos_adr[2]] = _near_angle(yaw - bearing, start[robot.qpos_adr[2]])
                seeds.append(seed)
        seeds.append(start.copy())
        return seeds

    def goal(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
             position: np.ndarray) -> tuple[IKResult | None, str | None]:
        """The first IK solution that keeps ``ik_margin_m`` (the clearance and a margin
        for the move's positioning errors) and the drive limit, from the first
        SOLVED_SEEDS stand-off seeds that are clear and where the robot stands, and None;
        else the best attempt and why: "no goal configuration", or "no place to stand"
        when no stand-off seed is clear and the candidate is beyond the arm's reach of
        where the robot stands (no IK is tried then; a base that does not move always
        tries)."""
        best: IKResult | None = None
        *stand_offs, here = self._seeds(robot, start, look_at, position)
        if stand_offs:  # only where the base can get to: near a place it reaches
            near, _ = self.places(robot).query(
                np.array([s[robot.qpos_adr[:2]] for s in stand_offs]),
                distance_upper_bound=STAND_CELL_M)
            stand_offs = [s for s, d in zip(stand_offs, near, strict=True) if np.isfinite(d)]
        seeds = [s for s in stand_offs
                 if self._valid(robot, s[robot.qpos_adr], self.clearance_m)][:SOLVED_SEEDS]
        base = start[robot.qpos_adr[:2]]
        if not self.move_base or np.hypot(*(position[:2] - base)) <= ARM_REACH_M:
            seeds.append(here)  # where it stands, it is clear (or as clear as it can be)
        if not seeds:
            return None, "no place to stand"
        for seed in seeds:
            settings = self.settings if seed is here else GOAL_IK
            ik = solve_camera_pose(self.scene.model, seed, robot, look_at, position,
                                   self.move_base, settings)
            if ik.converged and self._valid(robot, ik.qpos[robot.qpos_adr], self.ik_margin_m):
                return ik, None
            if best is None or ik.position_error_m < best.position_error_m:
                best = ik
        return best, "no goal configuration"

    # ------------------------------------------------------------ path

    def path(self, robot: Robot, start: np.ndarray, goal: np.ndarray
             ) -> tuple[np.ndarray | None, int]:
        """A collision-free joint path (k, 9) from ``start`` to ``goal`` (9 joints
        each), or None if none was found within the budget; and the validity checks
        spent. Tried in turn: the straight way; with the base moving, as mobile
        manipulators travel, in three legs each straight or else searched by OMPL: the
        arm into its home posture where the robot stands, the base's way (x, y, yaw)
        with the arm tucked, the arm out again at the goal; then OMPL's search over base
        and arm together."""
        spent = [0]
        if self._segment_clear(robot, start, goal, spent):
            return np.array([start, goal]), spent[0]
        if self.move_base:
            home = self._nearest_turns(robot, self.scene.start_qpos[robot.qpos_adr], start)
            tucked_here, tucked_there = start.copy(), goal.copy()
            tucked_here[3:], tucked_there[3:] = home[3:], home[3:]
            legs = []
            if self._valid(robot, tucked_here, self.clearance_m) and self._valid(
                    robot, tucked_there, self.clearance_m):
                arm, base = list(range(3, 9)), [0, 1, 2]
                for a, b, joints in ((start, tucked_here, arm),
                                     (tucked_here, tucked_there, base),
                                     (tucked_there, goal, arm)):
                    leg = (np.array([a, b]) if self._segment_clear(robot, a, b, spent)
                           else self._search(robot, a, b, joints, spent))
                    if leg is None:
                        break
                    legs.append(leg)
            if len(legs) == 3:
                return np.vstack([legs[0], legs[1][1:], legs[2][1:]]), spent[0]
        found = self._search(robot, start, goal, list(range(9)) if self.move_base
                             else list(range(3, 9)), spent)
        return found, spent[0]

    def _segment_clear(self, robot: Robot, a: np.ndarray, b: np.ndarray,
                       spent: list[int]) -> bool:
        """Is the straight joint-space segment from ``a`` (clear) to ``b`` clear,
        checked every CHECK_STEP? Counts its checks in ``spent``."""
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / CHECK_STEP))
        for k in range(1, n + 1):
            spent[0] += 1
            if not self._valid(robot, a + (b - a) * (k / n), self.clearance_m):
                return False
        return True

    def _search(self, robot: Robot, start: np.ndarray, goal: np.ndarray, active: list[int],
                spent: list[int]) -> np.ndarray | None:
        """OMPL's RRT-Connect from ``start`` to ``goal`` (9 joints each) over the joints
        ``active`` (the others held as at ``start``), until ``spent`` reaches the
        budget; the path found, its waypoints reduced by OMPL's simplifier, or None."""
        lo, hi = self._bounds(robot, start, goal)
        space = ob.RealVectorStateSpace(len(active))
        bounds = ob.RealVectorBounds(len(active))
        for i, j in enumerate(active):
            bounds.setLow(i, float(lo[j]))
            bounds.setHigh(i, float(hi[j]))
        space.setBounds(bounds)
        ou.RNG.setSeed(int(self.rng.integers(1, 2 ** 31 - 1)))  # before the planner's RNGs
        setup = og.SimpleSetup(space)

        def joints_of(state: Any) -> np.ndarray:
            q = start.copy()
            q[active] = [state[i] for i in range(len(active))]
            return q

        def valid(state: Any) -> bool:
            spent[0] += 1
            return self._valid(robot, joints_of(state), self.clearance_m)

        def state(q: np.ndarray) -> Any:
            x = space.allocState()
            for i, j in enumerate(active):
                x[i] = float(q[j])
            return x

        setup.setStateValidityChecker(valid)
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(CHECK_STEP / space.getMaximumExtent())
        setup.setStartAndGoalStates(state(start), state(goal))
        planner = og.RRTConnect(info)
        planner.setRange(STEP_RANGE)
        setup.setPlanner(planner)
        setup.solve(ob.PlannerTerminationCondition(lambda: spent[0] >= self.checks))
        if not setup.haveExactSolutionPath():
            return None
        found = setup.getSolutionPath()
        setup.getPathSimplifier().reduceVertices(found)  # OMPL's shortcutting of waypoints
        return np.array([joints_of(found.getState(k)) for k in range(found.getStateCount())])

    def _bounds(self, robot: Robot, start: np.ndarray, goal: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """The joint space searched (9 each): the base's drive square, a quarter turn
        beyond where its yaw starts and ends, the arm's joints ARM_SWING_RAD beyond
        where they start and end (within their ranges)."""
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
        ik, why = self.goal(robot, start, look_at, position)
        if ik is None or why is not None:
            return Plan(ik, why, seconds=time.perf_counter() - started)
        goal = ik.qpos.copy()  # the same pose, each turning joint the shorter way round
        goal[robot.qpos_adr] = self._nearest_turns(robot, goal[robot.qpos_adr],
                                                   start[robot.qpos_adr])
        ik = dataclasses.replace(ik, qpos=goal)
        path, checks = self.path(robot, start[robot.qpos_adr], goal[robot.qpos_adr])
        self._scratch.qpos[:] = start
        if path is None:
            return Plan(ik, "no path within the budget", checks=checks,
                        seconds=time.perf_counter() - started)
        self.scene.set_robot(self.belief, robot, ik.qpos)
        return Plan(ik, None, path, checks, time.perf_counter() - started)

    def _nearest_turns(self, robot: Robot, joints: np.ndarray, near: np.ndarray) -> np.ndarray:
        """``joints`` (9) with each turning joint (the yaw, the arm's) moved by whole
        turns, within its range, to lie nearest ``near`` (9): the same pose, reached
        without turning a joint the long way round (mapping's IK may leave a joint a
        whole turn from home)."""
        m = self.scene.model
        out = joints.copy()
        for k in range(2, 9):
            j = int(m.jnt_qposadr.tolist().index(robot.qpos_adr[k]))
            turns = joints[k] + 2 * math.pi * np.arange(-3, 4)
            if m.jnt_limited[j]:
                lo, hi = m.jnt_range[j]
                turns = turns[(turns >= lo) & (turns <= hi)]
            if len(turns):
                out[k] = turns[np.argmin(np.abs(turns - near[k]))]
        return out

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
