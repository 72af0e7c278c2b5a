"""Where a robot's base can stand: the places it gets to along clear floor (a raster of
cells, each with the shortest drive there), and, for one camera pose, the places from
which its arm reaches it (inverse reachability through the arm's capability map),
ranked as a stand-off is chosen."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from taskcam.mapping import drive_lengths
from taskcam.sim.world.arm import Arm

STAND_CELL_M = 0.1  # the grid of places a base may stand on (m), see clear_places
# Stands are taken side by side round the camera, behind it (as seen from the target)
# first, in sides this wide (deg): the sides a stand-off from behind turns through
STAND_SIDE_DEG = 30.0
# A base turns 1 rad in the time it drives this far (m): its speeds, 0.5 m/s and 1 rad/s
BASE_M_PER_RAD = 0.5


@dataclass(frozen=True)
class Places:
    """Where a robot's base can get to: a raster of cells ``cell_m`` wide, the first's
    centre at ``origin`` (x, y; m), each holding the shortest drive there (m; inf where
    it cannot get, or not within the limit)."""

    origin: np.ndarray
    cell_m: float
    drive: np.ndarray  # (nx, ny)
    xy: np.ndarray = field(init=False)  # (n, 2) the centres of the cells it gets to
    drive_m: np.ndarray = field(init=False)  # (n,) and the drive to each
    tree: cKDTree = field(init=False)
    # per cell (i, j) from (-1, -1): is one of the cells (i..i+1, j..j+1) got to?
    _beside: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        cells = np.argwhere(np.isfinite(self.drive))
        object.__setattr__(self, "xy", self.origin + cells * self.cell_m)
        object.__setattr__(self, "drive_m", self.drive[tuple(cells.T)])
        object.__setattr__(self, "tree", cKDTree(self.xy.reshape(-1, 2)))
        got = np.zeros((self.drive.shape[0] + 2, self.drive.shape[1] + 2), bool)
        got[1:-1, 1:-1] = np.isfinite(self.drive)
        object.__setattr__(self, "_beside", got[:-1, :-1] | got[1:, :-1] | got[:-1, 1:]
                           | got[1:, 1:])

    def within(self, xy: np.ndarray, radius_m: float) -> np.ndarray:
        """Indices into ``xy`` of the places within ``radius_m`` of a point (x, y; m)."""
        return np.array(sorted(self.tree.query_ball_point(xy, radius_m)), int)

    def reached(self, xy: np.ndarray) -> bool:
        """Is the base at ``xy`` (m) on a place it gets to, or on a cell beside one (the
        raster's resolution: between cell centres the base is as clear as at them)?"""
        i = math.floor((float(xy[0]) - float(self.origin[0])) / self.cell_m) + 1
        j = math.floor((float(xy[1]) - float(self.origin[1])) / self.cell_m) + 1
        return 0 <= i < self._beside.shape[0] and 0 <= j < self._beside.shape[1] and bool(
            self._beside[i, j])  # a validity check's share: table lookups, no arrays


@dataclass(frozen=True)
class Stands:
    """Base poses from which the arm reaches one camera pose, nearest drive first: the
    base's place (n, 2; m) and yaw (n,; rad), the arm's seed joints (n, 6; rad) and the
    drive to each (n,; m)."""

    xy: np.ndarray
    yaw: np.ndarray
    joints: np.ndarray
    drive_m: np.ndarray


def clear_places(clear: Callable[[np.ndarray], bool], home: np.ndarray, here: np.ndarray,
                 room: tuple[np.ndarray, np.ndarray], drive_m: float) -> Places:
    """The places a base at ``here`` (x, y, yaw; m, rad) gets to: cells every
    STAND_CELL_M of the ``room`` (min and max corner, x, y; m) within ``drive_m`` of it
    where the robot at ``home`` (9 joints; its base moved there) is ``clear``, facing any
    of four ways, that a drive of at most ``drive_m`` through clear cells reaches from
    the clear cell nearest it."""
    lo = np.maximum(room[0], here[:2] - drive_m)  # no farther than the drive
    hi = np.minimum(room[1], here[:2] + drive_m)
    xs = np.arange(lo[0] + STAND_CELL_M / 2, hi[0], STAND_CELL_M)
    ys = np.arange(lo[1] + STAND_CELL_M / 2, hi[1], STAND_CELL_M)
    free = np.zeros((len(xs), len(ys)), bool)
    q = home.copy()
    for i, j in np.ndindex(free.shape):
        if math.hypot(xs[i] - here[0], ys[j] - here[1]) > drive_m:
            continue  # farther than any drive
        q[:2] = xs[i], ys[j]
        free[i, j] = any(clear(q) for q[2] in here[2] + np.arange(4) * math.pi / 2)
    origin = np.array([xs[0] if len(xs) else lo[0], ys[0] if len(ys) else lo[1]])
    drive = np.full(free.shape, np.inf)
    if free.any():  # from the clear cell nearest the robot
        cells = np.argwhere(free)
        start = cells[np.argmin(np.hypot(*(origin + cells * STAND_CELL_M - here[:2]).T))]
        drive = drive_lengths(free, (int(start[0]), int(start[1])), STAND_CELL_M, drive_m)
    return Places(origin, STAND_CELL_M, drive)


def ranked_stands(places: Places, arm: Arm, look_at: np.ndarray, position: np.ndarray,
                  yaw_now: float) -> Stands:
    """Where a base can stand to put the camera at ``position`` looking at ``look_at``
    (m): the ``places`` from which the ``arm``'s capability map reaches the pose, behind
    the camera first, then the quickest to get to (the drive and the turn from
    ``yaw_now``, rad), with the base's yaw and the arm's joints of the map's seed."""
    direction = np.asarray(look_at, float) - position
    direction = direction / max(float(np.linalg.norm(direction)), 1e-12)
    near = places.within(position[:2], arm.reach_m)
    ok, yaw, joints = arm.reach.stands(position, direction, places.xy[near])
    near, yaw = near[ok], yaw[ok]
    # behind the camera as seen from the target first, the arm out of the views (its
    # own and the others': the task's panel comes from the target's side), by sides
    # STAND_SIDE_DEG wide; on each side the quickest first: the drive and the base's
    # turn, at the base's speeds
    back = np.arctan2(*(position[1::-1] - np.asarray(look_at, float)[1::-1]))
    side = np.arctan2(places.xy[near, 1] - position[1], places.xy[near, 0] - position[0])
    off = np.abs(np.mod(side - back + math.pi, 2 * math.pi) - math.pi)
    turn = np.abs(np.mod(yaw - yaw_now + math.pi, 2 * math.pi) - math.pi)
    order = np.lexsort((places.drive_m[near] + turn * BASE_M_PER_RAD,
                        np.round(np.degrees(off) / STAND_SIDE_DEG)))
    return Stands(places.xy[near][order], yaw[order], joints[ok][order],
                  places.drive_m[near][order])
