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

from mapping import integrate_depth, opencv_pose
from mapping.floor_map import UNSCANNED
from sim.stages.move import move
from sim.stages.world import World
from sim.world.base_scanner import scan_into
from sim.world.ik import solve_camera_pose
from sim.world.planning import ArmPlanner
from sim.world.render import camera_pose
from sim.world.scene import Robot
from sim.world.sensing import DepthSensor

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
    planner = planner_in("map")
    looks = _looks(world, robot, (stand, position), planner_in("map_seen"), sensor)
    driven = None
    if looks:
        planner = planner_in("map")
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
