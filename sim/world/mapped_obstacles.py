"""The maps in the planner's world: what the robots do not know exactly (the clutter)
the planner knows only as the robots mapped it, and a robot is kept clear of it as a
set of spheres that cover its collision geoms.

- The arm and the head keep clear of the camera map's occupied and never-observed
  voxels.
- The base keeps clear of the occupied voxels and of the floor plan's occupied and
  never-scanned cells (its laser scanner's plane, sim/world/base_scanner.py): the
  cameras look at the work-piece, not at the floor the bases drive on.

The planner's model still holds what it knows exactly: the floor, the work-piece, the
panel and the robots at their commanded configurations. The voxels those explain are
left out of the fields (their cubes meet one of their geoms). So is the room a robot's
planning model needs where it stands (see :func:`map_fields`). An obstacle of the scene
is left to the maps when it lies wholly inside the camera map's grid; one that does not
is kept in the planner's model (the map cannot say where it ends: as if from a plan of
the room beyond the mapped workspace).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import mujoco
import numba as nb
import numpy as np

from taskcam.mapping import FloorMap, ObstacleField, OccupancyGrid
from taskcam.sim.world.collision import collision_geoms
from taskcam.sim.world.scene import Robot

SPHERE, CAPSULE, CYLINDER, BOX = (int(k) for k in (
    mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_BOX))
# A box is covered by the spheres round sub-boxes at most this half-wide (m): a sphere
# round a cubic piece bulges past the box's face by (sqrt(3) - 1) of it, 3.7 cm (one
# sphere round a whole 0.72 x 0.58 x 0.3 m chassis would bulge 0.3 m)
BOX_PIECE_M = 0.05


@dataclass(frozen=True)
class Spheres:
    """Spheres covering geoms: the geom each belongs to (k,), its centre in that geom's
    frame (k, 3; m) and its radius (k,; m)."""

    geoms: np.ndarray
    local: np.ndarray
    radii: np.ndarray

    def centres(self, data: mujoco.MjData) -> np.ndarray:
        """The spheres' centres in the world (k, 3; m) as ``data`` places the geoms."""
        return _centres(data.geom_xpos, data.geom_xmat, self.geoms, self.local)


def covering_spheres(model: mujoco.MjModel, geoms: Iterable[int]) -> Spheres:
    """Spheres whose union holds each geom: a sphere is itself; capsules and cylinders
    are spheres along the axis, their radius spaced apart; a box (and any other geom,
    by its bounding box) is cut into equal sub-boxes at most BOX_PIECE_M half-wide (as
    thin as the box where it is thinner, down to a fifth of that), and
    the sub-boxes on its surface are covered each by its circumscribed sphere (what
    reaches the inside passes the surface first)."""
    ids, local, radii = [], [], []
    for g in geoms:
        size, kind = model.geom_size[g], int(model.geom_type[g])
        if kind == SPHERE:
            pts, r = np.zeros((1, 3)), np.full(1, float(size[0]))
        elif kind in (CAPSULE, CYLINDER):
            radius, half = float(size[0]), float(size[1])
            n = math.ceil(2 * half / radius) + 1
            pts = np.zeros((n, 3))
            pts[:, 2] = np.linspace(-half, half, n)
            r = np.full(n, math.hypot(radius, half / (n - 1)))
        else:
            if kind == BOX:
                centre, halves = np.zeros(3), np.asarray(size, float)
            else:
                centre, halves = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
            # thin boxes in thinner pieces: a sphere round a flat piece bulges far
            target = min(BOX_PIECE_M, max(float(halves.min()), BOX_PIECE_M / 5))
            counts = np.maximum(np.ceil(halves / target - 1e-9), 1).astype(int)
            piece = halves / counts
            idx = np.stack(np.meshgrid(*[np.arange(int(k)) for k in counts], indexing="ij"),
                           -1).reshape(-1, 3)
            surface = np.any((idx == 0) | (idx == counts - 1), axis=1)
            pts = centre - halves + (2 * idx[surface] + 1) * piece
            r = np.full(len(pts), float(np.linalg.norm(piece)))
        ids += [g] * len(pts)
        local.append(pts)
        radii.append(r)
    return Spheres(np.array(ids, int), np.concatenate(local).reshape(-1, 3) if local
                   else np.zeros((0, 3)), np.concatenate(radii) if radii else np.zeros(0))


@dataclass(frozen=True)
class RobotSpheres:
    """Spheres covering a robot's collision geoms: its base's first (``base`` of them),
    then the rest's."""

    spheres: Spheres
    base: int


def robot_spheres(model: mujoco.MjModel, robot: Robot) -> RobotSpheres:
    """The spheres covering ``robot``'s collision geoms, its base's first."""
    body = model.body(robot.base_body).id
    geoms = collision_geoms(model, robot.body_ids)
    base = [g for g in geoms if model.geom_bodyid[g] == body]
    spheres = covering_spheres(model, base + [g for g in geoms if g not in base])
    return RobotSpheres(spheres, int(np.isin(spheres.geoms, base).sum()))


def inside_geom(model: mujoco.MjModel, data: mujoco.MjData, g: int, points: np.ndarray,
                margin: float) -> np.ndarray:
    """Which points (n, 3; m) lie within ``margin`` (m) of geom ``g`` (boxes, spheres,
    capsules and cylinders exactly; other shapes by their bounding box)."""
    local = (points - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
    size, kind = model.geom_size[g], int(model.geom_type[g])
    if kind == SPHERE:
        return np.linalg.norm(local, axis=1) <= size[0] + margin
    if kind == CAPSULE:
        along = np.clip(local[:, 2], -size[1], size[1])
        return np.hypot(np.hypot(local[:, 0], local[:, 1]), local[:, 2] - along) <= size[0] + margin
    if kind == CYLINDER:
        radial = np.maximum(np.hypot(local[:, 0], local[:, 1]) - size[0], 0.0)
        axial = np.maximum(np.abs(local[:, 2]) - size[1], 0.0)
        return np.hypot(radial, axial) <= margin
    if kind == BOX:
        centre, halves = np.zeros(3), size
    else:
        centre, halves = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
    outside = np.maximum(np.abs(local - centre) - halves, 0.0)
    return np.linalg.norm(outside, axis=1) <= margin


def known_voxels(grid: OccupancyGrid, model: mujoco.MjModel,
                 placed: Iterable[tuple[mujoco.MjData, Iterable[int]]]) -> np.ndarray:
    """The voxels (bool, the grid's shape) whose content the planner's model explains:
    those reaching down to the floor, and those whose cube meets one of the geoms as
    each data of ``placed`` places them."""
    known = np.zeros(grid.shape, bool)
    floor = model.geom("floor").id
    floor_z = float(model.geom_pos[floor][2])
    lowest = grid.origin[2] + np.arange(grid.shape[2]) * grid.resolution
    known[:, :, lowest < floor_z + 1e-9] = True
    half_diagonal = grid.resolution * math.sqrt(3) / 2
    shape = np.array(grid.shape)
    for data, geoms in placed:
        for g in geoms:
            reach = model.geom_rbound[g] + half_diagonal
            if reach <= half_diagonal:  # a plane: unbounded, the floor's handled above
                continue
            centre = data.geom_xpos[g]
            lo = np.clip(grid.index(centre - reach), 0, shape)
            hi = np.clip(grid.index(centre + reach) + 1, 0, shape)
            if np.any(hi <= lo):
                continue
            block = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi, strict=True)],
                                         indexing="ij"), -1).reshape(-1, 3)
            hit = block[inside_geom(model, data, g, grid.centers(block), half_diagonal)]
            known[tuple(hit.T)] = True
    return known


def left_to_map(model: mujoco.MjModel, data: mujoco.MjData, grid: OccupancyGrid) -> frozenset[int]:
    """The scene's obstacle geoms (bodies named ``obstacle…``) whose bounding boxes lie
    wholly inside the grid: the planner knows them only from the maps."""
    lo = grid.origin
    hi = grid.origin + np.array(grid.shape) * grid.resolution
    out = set()
    for g in range(model.ngeom):
        if not model.body(int(model.geom_bodyid[g])).name.startswith("obstacle"):
            continue
        rot = data.geom_xmat[g].reshape(3, 3)
        centre = data.geom_xpos[g] + rot @ model.geom_aabb[g, :3]
        half = np.abs(rot) @ model.geom_aabb[g, 3:]
        if np.all(centre - half >= lo) and np.all(centre + half <= hi):
            out.add(g)
    return frozenset(out)


@dataclass(frozen=True)
class MapFields:
    """What the maps leave room for (taskcam.mapping.ObstacleField each)."""

    unknown: ObstacleField  # 3-D: occupied and never-observed voxels (arm and head)
    occupied: ObstacleField  # 3-D: occupied voxels (the base), on the same grid
    floor: ObstacleField  # 2-D: occupied and never-scanned floor (the base)
    # both 3-D fields' bounds, one after the other: one lookup serves the whole robot
    _both: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_both", np.concatenate([self.unknown.bounds,
                                                          self.occupied.bounds]))

    def clearance(self, robot: RobotSpheres, data: mujoco.MjData,
                  exact_below: float = -math.inf) -> float:
        """A lower bound (m) of the robot's distance to what the maps hold, its spheres
        placed as ``data`` has them (a validity check's share: about 30 µs), exact to
        the maps' cells wherever it is below ``exact_below`` (m; ObstacleField.least)."""
        c, r, n = robot.spheres.centres(data), robot.spheres.radii, robot.base
        # the base's spheres looked up in the occupied voxels' bounds, the rest's in all
        spatial = self.unknown.least(c, r, self._both, n, len(self.unknown.bounds), exact_below)
        return min(spatial, self.floor.least(c[:n, :2], r[:n], exact_below=exact_below))


def known_floor(floor: FloorMap, model: mujoco.MjModel,
                placed: Iterable[tuple[mujoco.MjData, Iterable[int]]], height_m: float
                ) -> np.ndarray:
    """The floor plan's cells (bool, its shape) whose square meets one of the geoms, as
    each data of ``placed`` places them, in the scan's plane ``height_m`` (m)."""
    known = np.zeros(floor.shape, bool)
    cells = floor.centers().reshape(-1, 2)
    points = np.column_stack([cells, np.full(len(cells), height_m)])
    half_diagonal = floor.resolution * math.sqrt(2) / 2
    for data, geoms in placed:
        for g in geoms:
            reach = model.geom_rbound[g] + half_diagonal
            if reach <= half_diagonal or abs(data.geom_xpos[g][2] - height_m) > reach:
                continue
            near = np.flatnonzero(np.hypot(*(cells - data.geom_xpos[g][:2]).T) <= reach)
            hit = near[inside_geom(model, data, g, points[near], half_diagonal)]
            known.reshape(-1)[hit] = True
    return known


def map_fields(grid: OccupancyGrid, floor: FloorMap, model: mujoco.MjModel,
               unmapped: frozenset[int], held: Iterable[mujoco.MjData],
               robots: Iterable[RobotSpheres], margin_m: float, scan_height_m: float,
               unobserved: bool = True) -> MapFields:
    """The maps' fields for planning. Left out: the cells of every geom but the floor
    and the obstacles ``unmapped`` (left to the maps; in the floor plan, where they
    cross the scan's plane ``scan_height_m``), and the cells within ``margin_m`` of the
    ``robots``' covering spheres, in each configuration ``held``. What the sensors never
    observed blocks the way if ``unobserved``; else only what they saw occupied does.
    A robot is where it holds a configuration, and was put there clear of everything
    (sim/world/scene.py checks it): the room its planning model needs there is taken as
    clear, though its own body hid some of it from its sensors."""
    floor_geom = model.geom("floor").id
    geoms = [g for g in range(model.ngeom) if g != floor_geom and g not in unmapped]
    held, robots = list(held), list(robots)
    known = known_voxels(grid, model, ((d, geoms) for d in held))
    floor_known = known_floor(floor, model, ((d, geoms) for d in held), scan_height_m)
    plane = floor_known[:, :, None]  # the floor plan as a grid one cell high about z = 0
    corner = np.array([*floor.origin, -floor.resolution / 2])
    for robot in robots:
        for d in held:
            centres, radii = robot.spheres.centres(d), robot.spheres.radii + margin_m
            _mark_within(known, grid.origin, grid.resolution, centres, radii)
            flat = np.column_stack([centres[:, :2], np.zeros(len(centres))])
            _mark_within(plane, corner, floor.resolution, flat, radii)
    return MapFields(ObstacleField.from_grid(grid, known, unobserved),
                     ObstacleField.from_grid(grid, known, unobserved=False),
                     floor.field(floor_known, unobserved))


@nb.njit(cache=True)
def _centres(xpos: np.ndarray, xmat: np.ndarray, geoms: np.ndarray,
             local: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    out = np.empty((len(geoms), 3))
    for i in range(len(geoms)):
        g = geoms[i]
        for a in range(3):
            out[i, a] = (xpos[g, a] + xmat[g, 3 * a] * local[i, 0]
                         + xmat[g, 3 * a + 1] * local[i, 1] + xmat[g, 3 * a + 2] * local[i, 2])
    return out


@nb.njit(cache=True)
def _mark_within(mask: np.ndarray, origin: np.ndarray, resolution: float, centres: np.ndarray,
                 radii: np.ndarray) -> None:  # pragma: no cover - compiled
    """Set the cells of ``mask`` (3-D) whose centres lie within one of the spheres."""
    n = mask.shape
    for s in range(len(centres)):
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for a in range(3):
            lo[a] = max(int(np.floor((centres[s, a] - radii[s] - origin[a]) / resolution)), 0)
            hi[a] = min(int(np.floor((centres[s, a] + radii[s] - origin[a]) / resolution)),
                        n[a] - 1)
        r2 = radii[s] * radii[s]
        for i in range(lo[0], hi[0] + 1):
            dx = origin[0] + (i + 0.5) * resolution - centres[s, 0]
            for j in range(lo[1], hi[1] + 1):
                dy = origin[1] + (j + 0.5) * resolution - centres[s, 1]
                for k in range(lo[2], hi[2] + 1):
                    dz = origin[2] + (k + 0.5) * resolution - centres[s, 2]
                    if dx * dx + dy * dy + dz * dz <= r2:
                        mask[i, j, k] = True
