"""The insertion's corridor: the space the panel will pass through on its way from where
it lies to its slot (the open-loop carry, then the descent), which robots placing their
cameras keep out of. Cameras the bases can drive close to the work-piece would otherwise
stand in the carrier's way.

The corridor is a chain of oriented boxes, the panel's box at points along its carry as
the task makes it (sim/stages/task.py: a straight line lifted by an arc, the orientation
kept), grown by three standard deviations of where the carrier puts it. It comes from
the nominal model: the panel where the scenario lays it, the slot where the work-piece
is believed to stand.
"""

from __future__ import annotations

import mujoco
import numpy as np

from taskcam.sim.config.stages import TaskConfig
from taskcam.sim.world.collision import KeepOutBoxes

CARRY_SAMPLES = 11  # boxes along the carry (as many as the task's open-loop carry steps)
DESCENT_SAMPLES = 4  # ... and along the descent into the slot
CARRY_SIGMAS = 3.0  # the boxes are grown by this many of the carry's standard deviations


def carry_corridor(model: mujoco.MjModel, data: mujoco.MjData, cfg: TaskConfig) -> KeepOutBoxes:
    """The corridor of the panel's carry to its slot in ``model`` at ``data`` (the
    nominal model and the belief)."""
    body = model.body("panel/panel")
    mocap = int(body.mocapid[0])
    geom = model.geom("panel/panel")
    flat = np.zeros(9)
    mujoco.mju_quat2Mat(flat, data.mocap_quat[mocap])
    R = flat.reshape(3, 3)
    start = data.mocap_pos[mocap].copy()
    slot = data.site("workpiece/slot").xpos.copy()
    above = np.array([0.0, 0.0, cfg.approach_m])
    s = np.linspace(0.0, 1.0, CARRY_SAMPLES)[:, None]
    carry = (1 - s) * start + s * (slot + above) + 4 * s * (1 - s) * above
    descent = slot + np.linspace(1.0, 0.0, DESCENT_SAMPLES)[:, None] * above
    bottoms = np.vstack([carry, descent])  # the panel's frame: its bottom edge's centre
    centres = bottoms + geom.pos @ R.T
    grow = CARRY_SIGMAS * cfg.carry_error_m
    n = len(centres)
    return KeepOutBoxes(centres, np.repeat(R[None], n, axis=0),
                   np.repeat((geom.size + grow)[None], n, axis=0))


def site_corners(corridor: KeepOutBoxes) -> np.ndarray:
    """The corners (m, world) of the corridor's end, the panel's boxes from above its
    slot down into it: what a camera measuring the insertion must hold in frame and
    in focus."""
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    last = slice(len(corridor.centres) - DESCENT_SAMPLES, None)
    c, R, h = corridor.centres[last], corridor.rotations[last], corridor.halves[last]
    return (c[:, None, :] + np.einsum("bij,bkj->bki", R, signs * h[:, None, :])).reshape(-1, 3)


def sees_site(position: np.ndarray, look_at: np.ndarray, corners: np.ndarray, fovy_rad: float,
              near_m: float, far_m: float) -> bool:
    """Does a camera at ``position`` looking at ``look_at`` hold every corner within its
    depth of field and within the cone of its vertical field of view (whatever its
    roll)?"""
    rays = corners - position
    distance = np.linalg.norm(rays, axis=1)
    axis = (look_at - position) / np.linalg.norm(look_at - position)
    inside = rays @ axis >= distance * np.cos(fovy_rad / 2)
    return bool(np.all(inside) and distance.min() >= near_m and distance.max() <= far_m)
