"""Clearance and lines of sight in the simulated world (the truth, not the map)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numba as nb
import numpy as np

from taskcam.sim.world.scene import Robot


@dataclass(frozen=True)
class KeepOutBoxes:
    """Oriented boxes (world, m) robots keep out of: centres (n, 3), rotations (n, 3, 3:
    box to world), half extents (n, 3)."""

    centres: np.ndarray
    rotations: np.ndarray
    halves: np.ndarray

    def __post_init__(self) -> None:  # as the compiled distance takes them
        for name in ("centres", "rotations", "halves"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), float))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Each point's (k, 3) distance to the nearest box (m; 0 inside one); a
        validity check's share, so compiled (about 2 µs for a robot's geoms)."""
        return _box_distances(self.centres, self.rotations, self.halves,
                              np.ascontiguousarray(points, dtype=float))

    def apart(self, xpos: np.ndarray, geoms: np.ndarray, radii: np.ndarray) -> float:
        """The least distance (m) of the geoms' bounding spheres (centres ``xpos[geoms]``,
        radii ``radii``) to the boxes: a validity check's share, so compiled."""
        return float(_spheres_apart(self.centres, self.rotations, self.halves, xpos, geoms,
                                    radii))


def collision_geoms(model: mujoco.MjModel, bodies: frozenset[int]) -> list[int]:
    """Ids of the collidable geoms of ``bodies``."""
    return [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies
            and (model.geom_contype[g] or model.geom_conaffinity[g])]


@dataclass(frozen=True)
class Clearance:
    """Smallest distances (m) from one robot, up to the probe's limit; negative when
    penetrating."""

    robots: float  # to the other robots
    world: float  # to everything else but the floor: obstacles, work-piece, panel
    own: float  # between its own links that are not neighbours

    @property
    def others(self) -> float:
        return min(self.robots, self.world)

    def summary(self) -> dict[str, float]:
        return {"to_robots_m": round(self.robots, 5), "to_obstacles_m": round(self.world, 5),
                "between_own_links_m": round(self.own, 5)}


class Proximity:
    """Measures one robot's clearance: its collision geoms against the other robots',
    against the rest of the world (not the floor, nor the geoms in ``skip``), and
    against its own."""

    def __init__(self, model: mujoco.MjModel, robot: Robot, robots: Sequence[Robot],
                 limit: float = 1.0, skip: frozenset[int] = frozenset()) -> None:
        self.model, self.limit = model, limit
        self.own = collision_geoms(model, robot.body_ids)
        self.own_array = np.array(self.own, int)
        self.own_radii = model.geom_rbound[self.own_array]  # their bounding spheres' (m)
        other_bodies = frozenset().union(*(r.body_ids for r in robots if r is not robot))
        self.robots = collision_geoms(model, other_bodies)
        floor = model.geom("floor").id
        self.world = [g for g in collision_geoms(
            model, frozenset(range(model.nbody)) - robot.body_ids - other_bodies)
            if g != floor and g not in skip]
        self.pairs_robots = _pairs(self.own, self.robots)
        self.pairs_world = _pairs(self.own, self.world)
        self.pairs_own = _pairs(self.own, self.own, lambda g, h: g < h and not _neighbours(
            model, g, h))
        # bounding spheres; a plane's (radius 0) bounds nothing
        self._radius = np.where(model.geom_rbound > 0, model.geom_rbound, np.inf)
        self._fromto = np.zeros(6)
        self._all: np.ndarray | None = None  # every pair, for clear()
        self._own_count = 0
        self._reach = np.zeros(0)

    @property
    def avoid(self) -> list[int]:
        """Every geom the robot must keep clear of."""
        return self.robots + self.world

    def _min(self, pairs: np.ndarray, data: mujoco.MjData) -> float:
        """The smallest distance of the geom pairs (k, 2), nearest bounding spheres
        first: a pair whose spheres are farther apart than the best so far is skipped."""
        best = self.limit
        for bound, g, h in _nearest_first(data.geom_xpos, pairs, self._radius):
            if bound >= best:
                break
            best = min(best, mujoco.mj_geomDistance(self.model, data, g, h, self.limit,
                                                    self._fromto))
        return float(best)

    def clear(self, data: mujoco.MjData, clearance_m: float) -> bool:
        """Is the robot ``clearance_m`` from the other robots and the world, and its own
        links apart? (What :meth:`measure` would say, at a fraction of its cost: only the
        pairs whose bounding spheres come that close are measured, nearest first.)"""
        if self._all is None:
            self._all = np.concatenate([self.pairs_own, self.pairs_robots, self.pairs_world])
            self._own_count = len(self.pairs_own)
            self._reach = self._radius[self._all[:, 0]] + self._radius[self._all[:, 1]]
        close = _close_pairs(data.geom_xpos, self._all, self._reach, self._own_count,
                             clearance_m)
        for g, h, need in close:
            if mujoco.mj_geomDistance(self.model, data, g, h, need, self._fromto) < need:
                return False
        return True

    def measure(self, data: mujoco.MjData) -> Clearance:
        return Clearance(self._min(self.pairs_robots, data), self._min(self.pairs_world, data),
                         self._min(self.pairs_own, data))


def _pairs(a: list[int], b: list[int],
           keep: Callable[[int, int], bool] = lambda g, h: True) -> np.ndarray:
    """The pairs (k, 2) of a geom of ``a`` and one of ``b`` that ``keep`` keeps."""
    return np.array([(g, h) for g in a for h in b if keep(g, h)], int).reshape(-1, 2)


def _neighbours(model: mujoco.MjModel, g: int, h: int) -> bool:
    """Whether two geoms' bodies are neighbours as MuJoCo's contact filter has them: the
    same rigid piece (bodies welded together count as one, e.g. a stereo head bolted to
    the last link) or a piece and its parent piece, whose proxies overlap around the
    joint between them by construction."""
    wg, wh = model.body_weldid[model.geom_bodyid[g]], model.body_weldid[model.geom_bodyid[h]]
    parent_g = model.body_weldid[model.body_parentid[wg]]
    parent_h = model.body_weldid[model.body_parentid[wh]]
    return bool(wg == wh or parent_g == wh or parent_h == wg)


def clearance(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot,
              robots: Sequence[Robot] = (), limit: float = 1.0) -> Clearance:
    """One robot's clearance now (see :class:`Proximity`)."""
    return Proximity(model, robot, robots, limit).measure(data)


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
    for g in collision_geoms(model, robot.body_ids):
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = centre + signs * half
        out.append(data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T)
    return out


@nb.njit(cache=True)
def _box_distance(centres: np.ndarray, rotations: np.ndarray, halves: np.ndarray,
                  point: np.ndarray) -> float:  # pragma: no cover - compiled
    out = np.inf
    for b in range(len(centres)):
        total = 0.0
        for i in range(3):  # the point in the box's frame, outside its half extent
            local = 0.0
            for j in range(3):
                local += rotations[b, j, i] * (point[j] - centres[b, j])
            over = abs(local) - halves[b, i]
            if over > 0.0:
                total += over * over
        out = min(out, np.sqrt(total))
    return out


@nb.njit(cache=True)
def _box_distances(centres: np.ndarray, rotations: np.ndarray, halves: np.ndarray,
                   points: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    out = np.empty(len(points))
    for k in range(len(points)):
        out[k] = _box_distance(centres, rotations, halves, points[k])
    return out


@nb.njit(cache=True)
def _spheres_apart(centres: np.ndarray, rotations: np.ndarray, halves: np.ndarray,
                   xpos: np.ndarray, geoms: np.ndarray,
                   radii: np.ndarray) -> float:  # pragma: no cover - compiled
    out = np.inf
    for k in range(len(geoms)):
        out = min(out, _box_distance(centres, rotations, halves, xpos[geoms[k]]) - radii[k])
    return out


# Own links need only be apart: this far (m)
APART_M = 1e-9


@nb.njit(cache=True)
def _close_pairs(xpos: np.ndarray, pairs: np.ndarray, reach: np.ndarray, own: int,
                 clearance_m: float) -> list[tuple[int, int, float]]:  # pragma: no cover
    """The geom pairs (k, 2) whose bounding spheres (``reach``: their radii summed) come
    nearer than each pair needs (the first ``own`` pairs APART_M, the others
    ``clearance_m``), nearest first, each with what it needs: a validity check's share,
    so compiled."""
    bound = np.empty(len(pairs))
    need = np.empty(len(pairs))
    for k in range(len(pairs)):
        g, h = pairs[k, 0], pairs[k, 1]
        dx = xpos[g, 0] - xpos[h, 0]
        dy = xpos[g, 1] - xpos[h, 1]
        dz = xpos[g, 2] - xpos[h, 2]
        bound[k] = np.sqrt(dx * dx + dy * dy + dz * dz) - reach[k]
        need[k] = APART_M if k < own else clearance_m
    close = np.flatnonzero(bound < need)
    return [(int(pairs[k, 0]), int(pairs[k, 1]), float(need[k]))
            for k in close[np.argsort(bound[close])]]


@nb.njit(cache=True)
def _nearest_first(xpos: np.ndarray, pairs: np.ndarray, radius: np.ndarray
                   ) -> list[tuple[float, int, int]]:  # pragma: no cover - compiled
    """The geom pairs (k, 2), each with the distance between their bounding spheres
    (``radius`` per geom; m), nearest first."""
    bound = np.empty(len(pairs))
    for k in range(len(pairs)):
        g, h = pairs[k, 0], pairs[k, 1]
        dx = xpos[g, 0] - xpos[h, 0]
        dy = xpos[g, 1] - xpos[h, 1]
        dz = xpos[g, 2] - xpos[h, 2]
        bound[k] = np.sqrt(dx * dx + dy * dy + dz * dz) - radius[g] - radius[h]
    return [(float(bound[k]), int(pairs[k, 0]), int(pairs[k, 1])) for k in np.argsort(bound)]
