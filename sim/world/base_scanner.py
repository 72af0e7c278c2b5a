"""The bases' planar laser scanners: each robot's base sweeps a horizontal plane near
the floor with MuJoCo's ray casts in the simulated world, and the scan is entered into
the floor plan (taskcam.mapping.FloorMap) where the robot believes it stands.

The scanner is a plausible mobile base's safety scanner: a 360° plane (two 270°
scanners at opposite corners, as omnidirectional bases carry them) SCAN_HEIGHT_M above
the floor, a ray every half degree, out to SCAN_RANGE_M. Rays that meet a robot are
self-filtered, as the cameras' depth is: the robots know where they are, and a robot
is not an obstacle of the map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from taskcam.mapping import FloorMap, ray_directions
from taskcam.sim.world.scene import Robot

SCAN_HEIGHT_M = 0.15  # the scan plane (m): safety scanners sit 0.1-0.2 m above the floor
SCAN_RAYS = 720  # a ray every 0.5° (such scanners resolve 0.33-0.5°)
SCAN_RANGE_M = 10.0  # m: beyond any workspace here (such scanners reach 10-25 m)


def scan(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot,
         robot_geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One scan from where ``robot``'s base is in ``data``: per ray, its direction in
    the base's frame (n, 2), the free range (m) and whether it ended on something that
    is not a robot (``robot_geoms``: bool per geom id)."""
    base = data.qpos[robot.qpos_adr]
    local = ray_directions(SCAN_RAYS)
    c, s = math.cos(base[2]), math.sin(base[2])
    world = local @ np.array([[c, s], [-s, c]])
    vec = np.zeros((SCAN_RAYS, 3))
    vec[:, :2] = world
    geomid = np.zeros(SCAN_RAYS, np.int32)
    dist = np.zeros(SCAN_RAYS)
    origin = np.array([base[0], base[1], SCAN_HEIGHT_M])
    mujoco.mj_multiRay(model, data, origin, vec.reshape(-1), None, 1,
                       int(model.body(robot.base_body).id), geomid, dist, None, SCAN_RAYS,
                       SCAN_RANGE_M)
    missed = geomid < 0
    ranges = np.where(missed, SCAN_RANGE_M, dist)
    hit = ~missed & ~robot_geoms[np.maximum(geomid, 0)]
    return local, ranges, hit


def scan_into(floor: FloorMap, model: mujoco.MjModel, data: mujoco.MjData,
              belief: mujoco.MjData, robots: Sequence[Robot], robot_geoms: np.ndarray) -> None:
    """Every robot scans where it is (``data``, the simulated world) and the scan enters
    ``floor`` where the robot believes it is (``belief``)."""
    for robot in robots:
        local, ranges, hit = scan(model, data, robot, robot_geoms)
        x, y, yaw = belief.qpos[robot.qpos_adr[:3]]
        c, s = math.cos(yaw), math.sin(yaw)
        floor.integrate(np.array([x, y]), local @ np.array([[c, s], [-s, c]]), ranges, hit)
