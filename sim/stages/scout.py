"""Scouting for placement: a robot whose arm would reach a view only from, or through,
space the robots never observed looks at that space, and drives nearer to look again,
before the planner is asked once more (plan to the frontier, look, plan again).

A look turns the robot's camera (its arm alone, by gaze IK) at a point and integrates
the depth it measures into the map, as mapping does; the arm goes back where it was. The
turn is held clear of the known geometry and of what the maps saw occupied, not of the
space never observed: that is what the camera, turning towards it, looks at. A drive
takes the base, arm tucked, to the place it can get to nearest the stand it hopes for
(a stand of the capability map on space not yet observed), and its scanner sweeps the
floor there. The planner in the robots' map then sees what the looks found: free space
opens the way, an obstacle closes it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from taskcam.mapping import integrate_depth, opencv_pose
from taskcam.mapping.floor_map import UNSCANNED
from taskcam.sim.stages.move import move
from taskcam.sim.stages.world import World
from taskcam.sim.world.base_scanner import scan_into
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.plan import Plan
from taskcam.sim.world.planning import ArmPlanner
from taskcam.sim.world.render import camera_pose
from taskcam.sim.world.scene import Robot
from taskcam.sim.world.sensing import DepthSensor

# A robot goes to look at most this many times a placement (a trip: a look or two and a
# drive of a few seconds; three let it look round a wall and again from nearer) ...
TRIPS = 3
# ... and asks at most this many times whether space never observed holds it back (a
# question is a plan in the map with that space free: up to a path search's budget)
QUESTIONS = 6
# Where a robot looks along a way held back by space never observed: points of it at
# least this far apart (m; a view 1 m off covers a metre across at the default 60 deg)
LOOK_APART_M = 0.5
# A drive is taken when the place nearest the hoped-for stand is farther than this (m:
# two floor cells); nearer, only looks help
STEP_M = 0.2
# Where a look at a stand aims: this high above the floor (m), where the arm tucked at
# home passes (the home posture holds the head about a metre up)
STAND_LOOK_Z_M = 0.9


def look(world: World, robot: Robot, point: np.ndarray, planner: ArmPlanner,
         sensor: DepthSensor) -> bool:
    """Turn ``robot``'s camera at ``point`` (m) by its arm alone, if a configuration
    ``planner`` holds clear does (the planner with the space never observed taken as
    free), measure depth and integrate it into the map where the robot believes its
    camera is; the arm is left where it was. Whether it looked."""
    s, belief, data = world.scenario, world.belief, world.data
    ik = solve_camera_pose(world.nominal, belief.qpos, robot, point, None, move_base=False)
    if not ik.converged or not planner.clear(robot, ik.qpos[robot.qpos_adr]):
        return False
    believed, true = belief.qpos.copy(), data.qpos.copy()
    arm = robot.qpos_adr[3:]
    turned = data.qpos.copy()  # the world's arm turned as the belief's is
    turned[arm] = true[arm] + ik.qpos[arm] - believed[arm]
    world.scene.set_robot(data, robot, turned, world.model)
    world.scene.set_robot(belief, robot, ik.qpos)
    depth = sensor.depth(data, robot)
    believed_camera = opencv_pose(camera_pose(belief, robot.camera))
    integrate_depth(world.grid, depth, world.pinhole, believed_camera, s.grid.max_range_m,
                    s.mapping.pixel_stride)
    world.scene.set_robot(data, robot, true, world.model)
    world.scene.set_robot(belief, robot, believed)
    return True


def scout(world: World, robot: Robot, hoped: np.ndarray,
          planner_in: Callable[[str], ArmPlanner], look_at: np.ndarray, position: np.ndarray,
          prior_sd: tuple[float, float], sensor: DepthSensor | None, drive: bool = True
          ) -> dict[str, Any] | None:
    """One trip for a camera at ``position`` looking at ``look_at`` (m) that the planner
    in the robots' map finds no stand for, but would from ``hoped`` (x, y; m) if the
    space never observed were free (``planner_in``: the planner in a world, "map" or
    "map_seen", as the maps now are): look at the stand and at the view (with a
    ``sensor``); if the planner, asked again, still finds no stand, drive to the place
    nearest the stand, scanning, and look again. What the trip did, or None if nothing
    could be done."""
    stand = np.array([*hoped, STAND_LOOK_Z_M])
    unknown_before = _unknown(world)
    looks = _looks(world, robot, (stand, position), planner_in("map_seen"), sensor)
    planner = planner_in("map")  # as the looks left the map
    driven = None
    if drive and not len(planner.stands(robot, look_at, position).xy):
        with world.timer("ik"):
            places = planner.places(robot)
            nearest = places.xy[int(np.argmin(np.hypot(*(places.xy - hoped).T)))]
            here = world.belief.qpos[robot.qpos_adr[:2]]
            plan = planner.drive_to(robot, nearest) if np.hypot(*(nearest - here)) >= STEP_M \
                else None
        if plan is not None and plan.reason is None:
            move(world, robot, plan.path, None, prior_sd)
            scan_into(world.floor, world.model, world.data, world.belief, [robot],
                      world.scene.robot_geoms())
            driven = {"to": nearest.round(3).tolist(), "path": plan.summary()}
            looks += _looks(world, robot, (stand, position), planner_in("map_seen"), sensor)
    seen = unknown_before - _unknown(world)
    if driven is None and not looks:
        return None
    return {"for": position.round(3).tolist(), "stand": hoped.round(3).tolist(),
            "looks": looks, "drive": driven, "observed": seen}


def look_along(world: World, robot: Robot, points: np.ndarray, position: np.ndarray,
               planner: ArmPlanner, sensor: DepthSensor) -> dict[str, Any] | None:
    """Look where the arm would be at a goal the robots' map holds back only by space
    never observed (``points``: the arm's links there, m) for the camera at ``position``
    (m); what was done, or None if no look could be taken."""
    unknown_before = _unknown(world)
    looks = _looks(world, robot, tuple(points), planner, sensor)
    if not looks:
        return None
    return {"for": position.round(3).tolist(), "stand": None, "looks": looks, "drive": None,
            "observed": unknown_before - _unknown(world)}


def _looks(world: World, robot: Robot, points: tuple[np.ndarray, ...], planner: ArmPlanner,
           sensor: DepthSensor | None) -> int:
    """Looks at each of ``points`` (m) that a clear configuration turns the camera to."""
    if sensor is None:
        return 0
    with world.timer("mapping"):
        return sum(look(world, robot, p, planner, sensor) for p in points)


def _unknown(world: World) -> int:
    """Cells never observed: the map's voxels and the floor plan's cells."""
    return int(np.count_nonzero(world.grid.states() == 0)
               + np.count_nonzero(world.floor.state == UNSCANNED))


def spread(points: np.ndarray, apart_m: float) -> np.ndarray:
    """The points (n, 3; m) in order, each kept if at least ``apart_m`` from those kept."""
    kept: list[np.ndarray] = []
    for p in points:
        if all(np.linalg.norm(p - k) >= apart_m for k in kept):
            kept.append(p)
    return np.array(kept).reshape(-1, 3)


class Scouting:
    """One placement's scouting: when the planner in the robots' map (``planner_in``:
    the planner in a world, "map" or "map_seen", as the maps now are) finds no stand or
    no plan for a candidate that the same map with the space never observed taken as
    free would give, the robot looks (with a ``sensor``) and, if it may ``drive``,
    drives nearer; at most TRIPS trips and QUESTIONS questions, none unless ``on``. The
    trips taken are in ``trips``."""

    def __init__(self, world: World, robot: Robot, planner_in: Callable[[str], ArmPlanner],
                 prior_sd: tuple[float, float], sensor: DepthSensor | None, *, on: bool,
                 drive: bool) -> None:
        self.world, self.robot, self.planner_in = world, robot, planner_in
        self.prior_sd, self.sensor, self.on, self.drive = prior_sd, sensor, on, drive
        self.trips: list[dict[str, Any]] = []
        self.asked = 0
        self._hopeful: ArmPlanner | None = None

    def _may_ask(self) -> bool:
        return self.on and len(self.trips) < TRIPS and self.asked < QUESTIONS

    def _hopeful_planner(self) -> ArmPlanner:
        self.asked += 1
        if self._hopeful is None:
            self._hopeful = self.planner_in("map_seen")
        return self._hopeful

    def _taken(self, trip: dict[str, Any] | None) -> bool:
        """Keep a trip; the maps changed, so the hopeful planner is made again."""
        if trip is None:
            return False
        self.trips.append(trip)
        self._hopeful = None
        return True

    def stands(self, planner: ArmPlanner, look_at: np.ndarray, position: np.ndarray
               ) -> tuple[ArmPlanner, bool]:
        """The planner to go on with, and whether it finds a stand for the camera at
        ``position`` looking at ``look_at`` (m), after a trip if one helps."""
        world, robot = self.world, self.robot
        with world.timer("ik"):
            if len(planner.stands(robot, look_at, position).xy):
                return planner, True
            if not self._may_ask():
                return planner, False
            wanted = self._hopeful_planner().stands(robot, look_at, position)
        if not len(wanted.xy) or not self._taken(scout(
                world, robot, wanted.xy[0], self.planner_in, look_at, position, self.prior_sd,
                self.sensor, drive=self.drive)):
            return planner, False
        planner = self.planner_in("map")
        with world.timer("ik"):
            return planner, len(planner.stands(robot, look_at, position).xy) > 0

    def plan(self, planner: ArmPlanner, refused: Plan, look_at: np.ndarray,
             position: np.ndarray, start: np.ndarray) -> tuple[ArmPlanner, Plan]:
        """After ``planner`` ``refused`` the camera at ``position`` looking at
        ``look_at`` (m), the robot at ``start`` (its full configuration): if the map with
        the space never observed free would give a plan, look where the arm would pass
        (its camera's way, its elbow and wrist at the goal) and plan again. The planner
        and the plan to go on with."""
        world, robot = self.world, self.robot
        if not self._may_ask() or self.sensor is None:
            return planner, refused
        with world.timer("ik"):
            hopeful = self._hopeful_planner()
            hoped = hopeful.plan(robot, look_at, position)
            world.scene.set_robot(world.belief, robot, start)  # a plan leaves it at its goal
        if hoped.reason is not None or hoped.ik is None:
            return planner, refused
        points = np.vstack([hopeful.camera_path(robot, hoped.path),
                            hopeful.arm_points(robot, hoped.ik.qpos)])
        if not self._taken(look_along(world, robot, spread(points, LOOK_APART_M), position,
                                      hopeful, self.sensor)):
            return planner, refused
        planner = self.planner_in("map")
        with world.timer("ik"):
            return planner, planner.plan(robot, look_at, position)
