"""The robot's joint space as the planner searches it: straight segments checked finely,
the box a search explores, and turning joints taken the short way round.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import mujoco
import numpy as np

from taskcam.sim.world.scene import Robot
from taskcam.sim.world.standing import STAND_CELL_M

CHECK_STEP = 0.01  # m (base) or rad (joints): motions are checked at least this finely
ARM_SWING_RAD = math.pi / 2  # see search_box
# RRT-Connect's longest step (joint space, m and rad): a tree grows in steps short
# enough that a blocked one wastes few checks (its default, a fifth of the space's
# extent, is several metres and radians here)
STEP_RANGE = 1.0


def segment_clear(valid: Callable[[np.ndarray], bool], a: np.ndarray, b: np.ndarray,
                   spent: list[int]) -> bool:
    """Is the straight joint-space segment from ``a`` (clear) to ``b`` clear by
    ``valid``, checked every CHECK_STEP? Counts its checks in ``spent``."""
    n = max(1, math.ceil(float(np.linalg.norm(b - a)) / CHECK_STEP))
    for k in range(1, n + 1):
        spent[0] += 1
        if not valid(a + (b - a) * (k / n)):
            return False
    return True


def search_box(model: mujoco.MjModel, robot: Robot, places: np.ndarray, start: np.ndarray,
               goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint space searched (9 each): the box round the ``places`` (k, 2; m) the
    base can get to (a cell beyond), a quarter turn beyond where its yaw starts and
    ends, the arm's joints ARM_SWING_RAD beyond where they start and end (within their
    ranges)."""
    q0, q1 = start, goal
    ids = [model.jnt_qposadr.tolist().index(a) for a in robot.qpos_adr]
    lo, hi = model.jnt_range[ids, 0].copy(), model.jnt_range[ids, 1].copy()
    xy = np.vstack([places, q0[None, :2]])
    lo[:2], hi[:2] = xy.min(axis=0) - STAND_CELL_M, xy.max(axis=0) + STAND_CELL_M
    lo[2] = min(q0[2], q1[2]) - math.pi / 2
    hi[2] = max(q0[2], q1[2]) + math.pi / 2
    # the arm's joints within a quarter turn beyond where they start and end: a
    # camera move needs no more, and the search does not wander through whole turns
    lo[3:] = np.maximum(lo[3:], np.minimum(q0[3:], q1[3:]) - ARM_SWING_RAD)
    hi[3:] = np.minimum(hi[3:], np.maximum(q0[3:], q1[3:]) + ARM_SWING_RAD)
    lo, hi = np.minimum(lo, np.minimum(q0, q1)), np.maximum(hi, np.maximum(q0, q1))
    return lo, hi


def nearest_turns(model: mujoco.MjModel, robot: Robot, joints: np.ndarray, near: np.ndarray
                  ) -> np.ndarray:
    """``joints`` (9) with each turning joint (the yaw, the arm's) moved by whole
    turns, within its range, to lie nearest ``near`` (9): the same pose, reached
    without turning a joint the long way round (mapping's IK may leave a joint a
    whole turn from home)."""
    out = joints.copy()
    for k in range(2, 9):
        j = int(model.jnt_qposadr.tolist().index(robot.qpos_adr[k]))
        turns = joints[k] + 2 * math.pi * np.arange(-3, 4)
        if model.jnt_limited[j]:
            lo, hi = model.jnt_range[j]
            turns = turns[(turns >= lo) & (turns <= hi)]
        if len(turns):
            out[k] = turns[np.argmin(np.abs(turns - near[k]))]
    return out


def near_angle(angle: float, reference: float) -> float:
    """``angle`` (rad) shifted by whole turns to lie within half a turn of ``reference``."""
    return reference + (angle - reference + math.pi) % (2 * math.pi) - math.pi
