"""Clearance and lines of sight in the simulated world (the truth, not the map)."""

from __future__ import annotations

import mujoco
import numpy as np

from .scene import Robot


def _collision_geoms(model: mujoco.MjModel, bodies: frozenset[int]) -> list[int]:
    return [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies
            and (model.geom_contype[g] or model.geom_conaffinity[g])]


def clearance(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot,
              limit: float = 1.0) -> tuple[float, float]:
    """Smallest distances (m), up to ``limit``: from the robot to any other collidable
    geometry but the floor, and between its own links that are not neighbours.
    Negative when penetrating."""
    own = _collision_geoms(model, robot.body_ids)
    floor = model.geom("floor").id
    others = [g for g in _collision_geoms(model, frozenset(range(model.nbody)) - robot.body_ids)
              if g != floor]
    fromto = np.zeros(6)
    to_others = to_self = limit
    for g in own:
        for h in others:
            to_others = min(to_others, mujoco.mj_geomDistance(model, data, g, h, limit, fromto))
    for i, g in enumerate(own):
        for h in own[i + 1:]:
            bg, bh = model.geom_bodyid[g], model.geom_bodyid[h]
            if bg == bh or model.body_parentid[bg] == bh or model.body_parentid[bh] == bg:
                continue
            to_self = min(to_self, mujoco.mj_geomDistance(model, data, g, h, limit, fromto))
    return float(to_others), float(to_self)


def blocked_rays(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot,
                 points: np.ndarray) -> int:
    """How many of the segments from the robot's camera to ``points`` meet any geometry."""
    origin = data.camera(robot.camera).xpos.copy()
    head = model.body(robot.head_body).id
    geomid = np.zeros(1, dtype=np.int32)
    count = 0
    for p in points:
        vec = p - origin
        dist = float(np.linalg.norm(vec))
        hit = mujoco.mj_ray(model, data, origin, vec / dist, None, 1, head, geomid)
        if geomid[0] >= 0 and hit < dist - 1e-4:
            count += 1
    return count


def robot_points(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot) -> list[np.ndarray]:
    """The corners (8, 3) of each of the robot's collision geoms' bounding boxes, in the
    world (m): the robot as a set of convex occluders."""
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    out = []
    for g in _collision_geoms(model, robot.body_ids):
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = centre + signs * half
        out.append(data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T)
    return out
