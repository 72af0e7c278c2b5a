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
import math
import time
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from taskcam.mapping import FloorMap, OccupancyGrid
from taskcam.sim.world.arm import Arm, scene_arm
from taskcam.sim.world.base_scanner import SCAN_HEIGHT_M
from taskcam.sim.world.collision import KeepOutBoxes, Proximity
from taskcam.sim.world.ik import IKResult, IKSettings, solve_camera_pose
from taskcam.sim.world.joint_space import (
    CHECK_STEP,
    STEP_RANGE,
    near_angle,
    nearest_turns,
    search_box,
    segment_clear,
)
from taskcam.sim.world.mapped_obstacles import MapFields, left_to_map, map_fields, robot_spheres
from taskcam.sim.world.motion import dense_path
from taskcam.sim.world.plan import Plan
from taskcam.sim.world.rrt import rrt_connect
from taskcam.sim.world.scene import Robot, Scene
from taskcam.sim.world.standing import STAND_CELL_M, Places, Stands, clear_places, ranked_stands

# The goal's IK from a stand of the capability map: the base stays about where the seed
# put it (its posture costs 100 times the arm's) and the arm reaches
GOAL_IK = IKSettings(base_posture_cost=0.1)
# At most this many stands of the capability map are solved from (the nearest drives
# first), this far apart (m): an IK solve costs 5-50 ms, and the map's seed already
# holds the pose to within a cell (4 cm, 10 deg), so a pose that does not converge from
# the nearest few seldom does from farther ones (tests/test_reach.py: 97 % converge from
# the first of a cell's seeds)
SOLVED_SEEDS = 4
SEED_APART_M = 0.25
# ... and where the robot stands: the map's seeds for the pose from there (its cell's and
# the nearest directions')
HERE_SEEDS = 2
# How far a base may drive to a view by default (m, along its way): it may cross the
# room it has mapped, the default grid's 3 m square walked round half its edge (6 m)
DRIVE_M = 6.0


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
                 ik_margin_m: float, move_base: bool = True, *, drive_m: float = DRIVE_M,
                 room: tuple[np.ndarray, np.ndarray] | None = None, arm: Arm | None = None,
                 checks: int = 20000, rng: np.random.Generator | None = None,
                 keep_out: KeepOutBoxes | None = None, grid: OccupancyGrid | None = None,
                 floor: FloorMap | None = None, unobserved_blocks: bool = True,
                 places: dict[tuple[Any, ...], Places] | None = None,
                 settings: IKSettings = IKSettings()) -> None:
        self.scene, self.belief = scene, belief
        self.clearance_m, self.ik_margin_m = clearance_m, ik_margin_m
        self.move_base, self.settings = move_base, settings
        self.drive_m, self.checks, self.keep_out = drive_m, checks, keep_out
        self.arm = scene_arm(scene) if arm is None else arm
        self.room = room
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._proximity: dict[str, Proximity] = {}
        self._spheres = {r.name: robot_spheres(scene.model, r) for r in scene.robots}
        self._scratch = mujoco.MjData(scene.model)
        # clear places for each robot's base, by all they depend on (shared by planners)
        self._standing: dict[tuple[Any, ...], Places] = {} if places is None else places
        self._depends: tuple[Any, ...] = (drive_m, clearance_m, move_base, None if room is None
                                          else (tuple(room[0]), tuple(room[1])))
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

    def places(self, robot: Robot) -> Places:
        """The places (x, y; m) the robot's base can get to: cells every STAND_CELL_M
        of the room (``room``; without one, the square of the drive about where it
        stands) where it is clear (its arm at home, facing any of four ways), that a
        drive of at most ``drive_m`` through clear cells reaches from the cell nearest
        where it stands now. Computed once for what it depends on (the planner's
        settings and maps, the commanded configuration, where the panel is), in the
        ``places`` the planner was given."""
        key = (robot.name, self.belief.qpos.tobytes(), self.belief.mocap_pos.tobytes(),
               self.belief.mocap_quat.tobytes(), *self._depends)
        if key not in self._standing:
            self._standing[key] = self._places(robot)
        return self._standing[key]

    def _places(self, robot: Robot) -> Places:
        here = self.belief.qpos[robot.qpos_adr[:3]]
        room = self.room if self.room is not None else (here[:2] - self.drive_m,
                                                        here[:2] + self.drive_m)
        self._scratch.qpos[:] = self.belief.qpos
        return clear_places(lambda q: self._clear(robot, q, self.clearance_m),
                            self.scene.start_qpos[robot.qpos_adr], here, room, self.drive_m)

    def stands(self, robot: Robot, look_at: np.ndarray, position: np.ndarray) -> Stands:
        """Where the base can stand to put the camera at ``position`` looking at
        ``look_at`` (m): the places it can get to (:meth:`places`) from which the arm's
        capability map reaches the pose, behind the camera first, then the quickest to
        get to (the drive and the turn), with the base's yaw and the arm's joints of the
        map's seed (inverse reachability)."""
        return ranked_stands(self.places(robot), self.arm, look_at, position,
                             float(self.belief.qpos[robot.qpos_adr[2]]))

    def may_stand(self, robot: Robot, positions: np.ndarray) -> np.ndarray:
        """For camera positions (n, 3; m): could the arm reach each from a place the base
        can get to, looking some way? (A necessary condition at a lookup's cost: the
        farthest the arm reaches at the camera's height, to the nearest place.)"""
        if not self.move_base:
            base = self.belief.qpos[robot.qpos_adr[:2]]
            distance = np.hypot(*(positions[:, :2] - base).T)
        else:
            places = self.places(robot)
            if not len(places.xy):
                return np.zeros(len(positions), bool)
            distance, _ = places.tree.query(positions[:, :2])
        return distance <= self.arm.reach.reach_at(positions[:, 2])

    # ------------------------------------------------------------ validity

    def _valid(self, robot: Robot, joints: np.ndarray, clearance_m: float) -> bool:
        """Is the robot at ``joints`` (9) clear of everything by ``clearance_m``, its own
        links apart, and its base on (or beside) a place it can get to?"""
        return self._validity(robot, clearance_m)(joints)

    def _validity(self, robot: Robot, clearance_m: float) -> Callable[[np.ndarray], bool]:
        """:meth:`_valid` for one robot and clearance, the places its base gets to looked
        up once: for a path's checks, while the commanded configuration holds still."""
        places = self.places(robot) if self.move_base else None

        def valid(joints: np.ndarray) -> bool:
            if places is not None and not places.reached(joints[:2]):
                return False
            return self._clear(robot, joints, clearance_m)
        return valid

    def clear(self, robot: Robot, joints: np.ndarray) -> bool:
        """Is the robot at ``joints`` (9) where it may be: clear by the clearance, its own
        links apart, its base on a place it can get to?"""
        return self._valid(robot, joints, self.clearance_m)

    def _clear(self, robot: Robot, joints: np.ndarray, clearance_m: float) -> bool:
        """Is the robot at ``joints`` (9) clear of everything by ``clearance_m``, and
        its own links apart?"""
        d = self._scratch
        d.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(self.scene.model, d)
        near = self.proximity(robot)
        if self.keep_out is not None and self.keep_out.apart(  # each geom's bounding sphere
                d.geom_xpos, near.own_array, near.own_radii) < clearance_m:  # out of it
            return False
        if self.maps is not None and self.maps.clearance(
                self._spheres[robot.name], d) < clearance_m:  # off what the maps hold
            return False
        return near.clear(d, clearance_m)

    # ------------------------------------------------------------ goal

    def _seeds(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
               position: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Configurations to start the goal's IK from: the base standing elsewhere, and
        the base where it stands (tried first: the least move). With the base moving: the
        stands of the capability map (:meth:`stands`), the quickest first, at most
        SOLVED_SEEDS that are clear and SEED_APART_M apart, each the base there, turned
        as the map says, and the arm at the map's seed; with the camera within the arm's
        reach of where the base stands, the map's seeds for the base where it is, and the
        present configuration."""
        seeds: list[np.ndarray] = []
        here: list[np.ndarray] = []
        if self.move_base:
            stands = self.stands(robot, look_at, position)
            taken: list[np.ndarray] = []
            for xy, yaw, joints in zip(stands.xy, stands.yaw, stands.joints, strict=True):
                if len(seeds) >= SOLVED_SEEDS:
                    break
                if any(np.hypot(*(xy - t)) < SEED_APART_M for t in taken):
                    continue
                seed = start.copy()
                seed[robot.qpos_adr] = (*xy, near_angle(float(yaw), start[robot.qpos_adr[2]]),
                                        *joints)
                if self._valid(robot, seed[robot.qpos_adr], self.clearance_m):
                    seeds.append(seed)
                    taken.append(xy)
        base = start[robot.qpos_adr[:3]]
        c, s = math.cos(base[2]), math.sin(base[2])
        to_base = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # world to base
        local = to_base @ (position - np.array([*base[:2], 0.0]))
        if not self.move_base or np.hypot(*local[:2]) <= self.arm.reach_m:
            direction = np.asarray(look_at, float) - position
            direction /= max(float(np.linalg.norm(direction)), 1e-12)
            joints, _ = self.arm.reach.seeds(local, to_base @ direction, HERE_SEEDS)
            for arm in joints:
                seed = start.copy()
                seed[robot.qpos_adr[3:]] = arm
                here.append(seed)
            here.append(start.copy())
        return seeds, here

    def goal(self, robot: Robot, start: np.ndarray, look_at: np.ndarray,
             position: np.ndarray) -> tuple[IKResult | None, str | None]:
        """The first IK solution that keeps ``ik_margin_m`` (the clearance and a margin
        for the move's positioning errors) and the base on a place it can get to, from
        the seeds (:meth:`_seeds`: where the base stands, its base free to move, then
        elsewhere, its base held about there), and None; else the best attempt and why: "no goal
        configuration", or "no place to stand" when no place the base can get to puts
        the pose within the arm's reach (no IK is tried then)."""
        best: IKResult | None = None
        elsewhere, here = self._seeds(robot, start, look_at, position)
        if not elsewhere and not here:
            return None, "no place to stand"
        for seed, settings in [*((s, self.settings) for s in here),
                               *((s, GOAL_IK) for s in elsewhere)]:
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
        valid = self._validity(robot, self.clearance_m)
        if segment_clear(valid, start, goal, spent):
            return np.array([start, goal]), spent[0]
        if self.move_base:
            home = nearest_turns(self.scene.model, robot,
                                 self.scene.start_qpos[robot.qpos_adr], start)
            tucked_here, tucked_there = start.copy(), goal.copy()
            tucked_here[3:], tucked_there[3:] = home[3:], home[3:]
            legs = []
            if valid(tucked_here) and valid(tucked_there):
                arm, base = list(range(3, 9)), [0, 1, 2]
                for a, b, joints in ((start, tucked_here, arm),
                                     (tucked_here, tucked_there, base),
                                     (tucked_there, goal, arm)):
                    leg = (np.array([a, b]) if segment_clear(valid, a, b, spent)
                           else self._search(valid, robot, a, b, joints, spent))
                    if leg is None:
                        break
                    legs.append(leg)
            if len(legs) == 3:
                return np.vstack([legs[0], legs[1][1:], legs[2][1:]]), spent[0]
        found = self._search(valid, robot, start, goal, list(range(9)) if self.move_base
                             else list(range(3, 9)), spent)
        return found, spent[0]

    def _search(self, valid: Callable[[np.ndarray], bool], robot: Robot, start: np.ndarray,
                goal: np.ndarray, active: list[int], spent: list[int]) -> np.ndarray | None:
        """RRT-Connect (sim/world/rrt.py) from ``start`` to ``goal`` (9 joints each) over
        the joints ``active`` (the others held as at ``start``), on which ``valid`` holds,
        until ``spent`` reaches the budget; the path found or None."""
        places = self.places(robot).xy if self.move_base else np.zeros((0, 2))
        lo, hi = search_box(self.scene.model, robot, places, start, goal)
        return rrt_connect(valid, start, goal, active, lo, hi, self.rng, spent, self.checks,
                           CHECK_STEP, STEP_RANGE)

    # ------------------------------------------------------------ both

    def plan(self, robot: Robot, look_at: np.ndarray, position: np.ndarray) -> Plan:
        started = time.perf_counter()
        start = self.belief.qpos.copy()
        self._scratch.qpos[:] = start
        ik, why = self.goal(robot, start, look_at, position)
        if ik is None or why is not None:
            return Plan(ik, why, seconds=time.perf_counter() - started)
        goal = ik.qpos.copy()  # the same pose, each turning joint the shorter way round
        goal[robot.qpos_adr] = nearest_turns(self.scene.model, robot, goal[robot.qpos_adr],
                                             start[robot.qpos_adr])
        ik = dataclasses.replace(ik, qpos=goal)
        path, checks = self.path(robot, start[robot.qpos_adr], goal[robot.qpos_adr])
        self._scratch.qpos[:] = start
        why = self._refused(path)
        if path is None or why is not None:
            return Plan(ik, why, checks=checks, seconds=time.perf_counter() - started)
        self.scene.set_robot(self.belief, robot, ik.qpos)
        return Plan(ik, None, path, checks, time.perf_counter() - started)

    def _refused(self, path: np.ndarray | None) -> str | None:
        """Why a path found (or None) may not be taken: none found within the budget,
        or its base drives farther than ``drive_m`` (and a cell: the goal lies within
        one of a place the base gets to)."""
        if path is None:
            return "no path within the budget"
        drive = float(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1).sum())
        if drive > self.drive_m + STAND_CELL_M:
            return "no path within the drive"
        return None

    def drive_to(self, robot: Robot, xy: np.ndarray) -> Plan:
        """A plan that drives the base to ``xy`` (m), its arm tucked at home, turned as
        it stands or by quarter turns as the place needs (no IK: a base's goal is its
        joints)."""
        started = time.perf_counter()
        start = self.belief.qpos[robot.qpos_adr].copy()
        home = nearest_turns(self.scene.model, robot, self.scene.start_qpos[robot.qpos_adr],
                             start)
        for turn in np.arange(4) * math.pi / 2:
            goal = np.array([*xy, start[2] + turn, *home[3:]])
            if self._valid(robot, goal, self.clearance_m):
                break
        else:
            return Plan(None, "no place to stand", seconds=time.perf_counter() - started)
        path, checks = self.path(robot, start, goal)
        why = self._refused(path)
        if path is None or why is not None:
            return Plan(None, why, checks=checks, seconds=time.perf_counter() - started)
        full = self.belief.qpos.copy()
        full[robot.qpos_adr] = goal
        self.scene.set_robot(self.belief, robot, full)
        return Plan(None, None, path, checks, time.perf_counter() - started)

    def arm_points(self, robot: Robot, qpos: np.ndarray) -> np.ndarray:
        """Where the robot's arm is at the configuration ``qpos`` (full; m): its elbow's
        and its wrist's bodies, the links between the shoulder and the head that pass
        through the space round the camera's view."""
        d = self._scratch
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.scene.model, d)
        m = self.scene.model
        ids = [int(m.jnt_bodyid[m.jnt_qposadr.tolist().index(a)]) for a in robot.qpos_adr[5:7]]
        points = d.xpos[ids].copy()
        d.qpos[:] = self.belief.qpos
        return points

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
