"""Where generated clutter may stand: what it must keep clear of, and what it stands on.

Clutter is solid: it may not pass through the work-piece (its table, plate and rails),
and it stands on the floor or on the work-piece's top with its centre over it (else it
would tip over). It must leave room where the task physically needs it: the panel's
carry to its slot (the task's corridor: the panel's box along the carry, grown by three
standard deviations of where the carrier puts it), each robot's start (room to turn
and reach, at every height), and each hole's mouth on the plate (a hole covered by an
object is no feature). Everything else, the table beside the plate included, is room
for clutter.

Obstacles are checked as their bounding boxes (a cylinder's and a sphere's are a
little larger than they are: the check errs toward room).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from taskcam.sim.config.scene import ObstacleConfig

ROBOT_ROOM_M = 0.7  # about each robot's start: its base turns and its arm reaches there
HOLE_MARGIN_M = 0.01  # beyond a hole's rim, so that its edge stays in sight


@dataclass(frozen=True)
class Boxes:
    """Oriented boxes (world, m): centres (n, 3), rotations (n, 3, 3: box to world) and
    half extents (n, 3)."""

    centres: np.ndarray
    rotations: np.ndarray
    halves: np.ndarray

    @staticmethod
    def of(centres: list[np.ndarray], rotations: list[np.ndarray], halves: list[np.ndarray]
           ) -> Boxes:
        return Boxes(np.reshape(centres, (-1, 3)), np.reshape(rotations, (-1, 3, 3)),
                     np.reshape(halves, (-1, 3)))

    def overlaps(self, centre: np.ndarray, rotation: np.ndarray, half: np.ndarray) -> bool:
        """Whether the box (``centre``, ``rotation``, ``half``) overlaps any of these, by
        the separating axis theorem (touching faces do not overlap)."""
        if len(self.centres) == 0:
            return False
        n = len(self.centres)
        mine = np.repeat(rotation.T[None], n, axis=0)  # (n, 3 axes, 3)
        theirs = np.transpose(self.rotations, (0, 2, 1))
        crossed = np.cross(mine[:, :, None, :], theirs[:, None, :, :]).reshape(n, 9, 3)
        axes = np.concatenate([mine, theirs, crossed], axis=1)  # (n, 15, 3)
        length = np.linalg.norm(axes, axis=2)
        axes = axes / np.maximum(length, 1e-12)[..., None]
        gap = np.abs(np.einsum("nkj,nj->nk", axes, self.centres - centre))
        reach_mine = np.abs(np.einsum("nkj,ij->nki", axes, rotation.T)) @ half
        reach_theirs = np.einsum("nki,ni->nk", np.abs(np.einsum("nkj,nji->nki", axes,
                                                                 self.rotations)), self.halves)
        separated = (gap >= reach_mine + reach_theirs - 1e-9) & (length > 1e-9)
        return bool((~separated.any(axis=1)).any())


def obstacle_box(o: ObstacleConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The obstacle's bounding box: centre, rotation and half extents (m)."""
    c, s = math.cos(math.radians(o.yaw_deg)), math.sin(math.radians(o.yaw_deg))
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    if o.shape == "box":
        half = np.asarray(o.size, float)
    elif o.shape == "cylinder":
        half = np.array([o.size[0], o.size[0], o.size[1]])
    else:
        half = np.full(3, o.size[0])
    return np.asarray(o.position, float), rotation, half


@dataclass(frozen=True)
class ClutterRoom:
    """What clutter keeps clear of (``solids``: the work-piece; ``corridor``: the panel's
    way; ``columns``: (x, y, radius, top) cylinders from the floor, the robots' starts
    and the holes' mouths) and what it stands on (``supports``: the work-piece's boxes
    seen from above)."""

    solids: Boxes
    corridor: Boxes
    columns: tuple[tuple[float, float, float, float], ...]
    floor_z: float = 0.0

    def support(self, x: float, y: float) -> float:
        """The height (m) of the surface under (x, y): the highest top of the work-piece
        boxes there, else the floor."""
        top = self.floor_z
        for centre, rotation, half in zip(self.solids.centres, self.solids.rotations,
                                          self.solids.halves, strict=True):
            local = rotation.T @ (np.array([x, y, centre[2]]) - centre)
            if abs(local[0]) <= half[0] and abs(local[1]) <= half[1]:
                top = max(top, float(centre[2] + np.abs(rotation[2]) @ half))
        return top

    def clear(self, o: ObstacleConfig) -> bool:
        """Whether the obstacle keeps out of the work-piece, the panel's way, the robots'
        starts and the holes' mouths."""
        centre, rotation, half = obstacle_box(o)
        bottom = float(centre[2] - half[2])
        reach = float(np.hypot(half[0], half[1]))
        for x, y, radius, top in self.columns:
            if math.hypot(centre[0] - x, centre[1] - y) < reach + radius and bottom < top:
                return False
        return not (self.solids.overlaps(centre, rotation, half)
                    or self.corridor.overlaps(centre, rotation, half))


def workpiece_solids(model: mujoco.MjModel, data: mujoco.MjData) -> Boxes:
    """The work-piece's collidable boxes (its table, plate and rails) in the world."""
    body = model.body("workpiece/workpiece").id
    picked = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
              and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
              and (model.geom_contype[g] or model.geom_conaffinity[g])]
    return Boxes.of([data.geom_xpos[g].copy() for g in picked],
                    [data.geom_xmat[g].reshape(3, 3).copy() for g in picked],
                    [model.geom_size[g].copy() for g in picked])
