"""The arm's reach: a capability map of a mobile manipulator's camera, and inverse
reachability for where its base can stand (Zacharias et al.'s capability map; Vahrenkamp
et al.'s inverse reachability for base placement).

A camera on an arm on a base that turns and drives on the floor: what the arm can do
does not change when the base turns about its pivot, so the map is kept in four
coordinates that a yaw of the base leaves alone: the camera's horizontal distance from
the base's pivot ``r`` and its height ``z`` (m), and the direction it looks along (roll
free, as the camera's pose is a position and a look-at point): the sine of its elevation
and its azimuth relative to the bearing from the pivot to the camera. A cell of that
space is reachable when a sampled configuration of the arm (within its joint limits,
clear of itself and the floor) puts the camera there; it keeps that configuration, a
seed for the inverse kinematics. Free of MuJoCo: the forward kinematics is a serial
chain of fixed transforms and hinges (:class:`Chain`), the validity a callable.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import PlacementError


def _rotation(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (n, 3, 3) by ``angles`` (n,; rad) about the unit ``axes`` (3,)."""
    x, y, z = axes
    c, s = np.cos(angles), np.sin(angles)
    t = 1.0 - c
    return np.stack([
        np.stack([t * x * x + c, t * x * y - s * z, t * x * z + s * y], -1),
        np.stack([t * x * y + s * z, t * y * y + c, t * y * z - s * x], -1),
        np.stack([t * x * z - s * y, t * y * z + s * x, t * z * z + c], -1)], -2)


@dataclass(frozen=True)
class Chain:
    """A serial chain of hinges: link k's frame is link k-1's times ``offsets[k]``
    (4x4, at zero angle), turned by its angle about ``axes[k]`` through ``anchors[k]``
    (both in link k's frame; m); the tool's frame is the last link's times ``tip``."""

    offsets: np.ndarray  # (k, 4, 4)
    axes: np.ndarray  # (k, 3) unit
    anchors: np.ndarray  # (k, 3) m
    tip: np.ndarray  # (4, 4)
    lower: np.ndarray  # (k,) joint limits (rad)
    upper: np.ndarray  # (k,)

    def forward(self, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tool's position (n, 3; m) and rotation (n, 3, 3) for joint angles (n, k)."""
        n = len(angles)
        rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        pos = np.zeros((n, 3))
        for k in range(len(self.axes)):
            offset = self.offsets[k]
            pos = pos + rot @ offset[:3, 3]
            rot = rot @ offset[:3, :3]
            turn = _rotation(self.axes[k], angles[:, k])
            anchor = self.anchors[k]  # the hinge turns the link about its anchor
            pos = pos + np.einsum("nij,nj->ni", rot, anchor - turn @ anchor)
            rot = rot @ turn
        return pos + rot @ self.tip[:3, 3], rot @ self.tip[:3, :3]


@dataclass(frozen=True)
class ReachCells:
    """The cells of the map: ``r`` from 0 in steps of ``r_step`` (``n_r`` of them), ``z``
    from ``z_low`` in steps of ``z_step`` (``n_z``), the elevation from -90 to 90 deg in
    ``n_elevation`` equal steps, the relative azimuth round the
    circle in ``n_azimuth``."""

    r_step: float = 0.04  # m: a candidate voxel is 0.05 m
    z_low: float = -0.2  # m
    z_step: float = 0.04
    n_r: int = 40  # out to 1.6 m
    n_z: int = 65  # up to 2.4 m
    n_elevation: int = 18  # 10 deg
    n_azimuth: int = 36  # 10 deg

    @property
    def count(self) -> int:
        return self.n_r * self.n_z * self.n_elevation * self.n_azimuth

    def keys(self, r: np.ndarray, z: np.ndarray, direction: np.ndarray,
             bearing: np.ndarray) -> np.ndarray:
        """Each pose's cell (int64), -1 outside the map: the camera ``r`` (m) from the
        pivot at height ``z`` (m) and ``bearing`` (rad) from it, looking along the unit
        ``direction`` (n, 3)."""
        ir = np.floor(r / self.r_step).astype(np.int64)
        iz = np.floor((z - self.z_low) / self.z_step).astype(np.int64)
        elevation = np.arcsin(np.clip(direction[:, 2], -1.0, 1.0))
        ie = np.minimum(np.floor((elevation / math.pi + 0.5) * self.n_elevation).astype(np.int64),
                        self.n_elevation - 1)
        relative = np.mod(np.arctan2(direction[:, 1], direction[:, 0]) - bearing, 2 * math.pi)
        ia = np.floor(relative / (2 * math.pi) * self.n_azimuth).astype(np.int64) % self.n_azimuth
        inside = (ir >= 0) & (ir < self.n_r) & (iz >= 0) & (iz < self.n_z)
        key = ((ir * self.n_z + iz) * self.n_elevation + ie) * self.n_azimuth + ia
        return np.where(inside, key, -1)

    def r_of(self, keys: np.ndarray) -> np.ndarray:
        """The outer radius (m) of each cell's ``r`` range."""
        return (keys // (self.n_z * self.n_elevation * self.n_azimuth) + 1) * self.r_step


@dataclass(frozen=True)
class ReachMap:
    """A capability map: the reached cells (``keys``, sorted), and for each the arm's
    joint angles (k,; rad) that reached it and the camera's bearing there (rad, in the
    base's frame), seeds for IK."""

    cells: ReachCells
    keys: np.ndarray  # (m,) int64, sorted
    joints: np.ndarray  # (m, k) float32
    bearings: np.ndarray  # (m,) float32
    samples: int  # configurations drawn to build it

    @property
    def reach_m(self) -> float:
        """The farthest the camera gets from the base's pivot, horizontally (m; a cell's
        outer edge)."""
        return float(self.cells.r_of(self.keys).max()) if len(self.keys) else 0.0

    def reach_at(self, z: np.ndarray) -> np.ndarray:
        """The farthest the camera gets from the pivot, horizontally (m), at each height
        ``z`` (m), looking any way; 0 where it never gets."""
        c = self.cells
        per_column = c.n_elevation * c.n_azimuth
        column = self.keys // per_column
        farthest = np.zeros(c.n_z)
        np.maximum.at(farthest, column % c.n_z, (column // c.n_z + 1) * c.r_step)
        iz = np.floor((np.asarray(z, float) - c.z_low) / c.z_step).astype(np.int64)
        inside = (iz >= 0) & (iz < c.n_z)
        return np.where(inside, farthest[np.clip(iz, 0, c.n_z - 1)], 0.0)

    def _find(self, keys: np.ndarray) -> np.ndarray:
        """Each key's row in the map, -1 where it was never reached."""
        if not len(self.keys):
            return np.full(len(keys), -1)
        rows = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return np.where((keys >= 0) & (self.keys[rows] == keys), rows, -1)

    def rows(self, positions: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """For camera positions (n, 3; m) and viewing directions (n, 3; unit) in the base's
        frame (pivot at the origin, z up from the floor): each pose's row, -1 if out of
        reach."""
        positions, directions = np.atleast_2d(positions), np.atleast_2d(directions)
        r = np.hypot(positions[:, 0], positions[:, 1])
        bearing = np.arctan2(positions[:, 1], positions[:, 0])
        return self._lookup(r, positions[:, 2], directions, bearing)

    def _lookup(self, r: np.ndarray, z: np.ndarray, directions: np.ndarray,
                bearing: np.ndarray) -> np.ndarray:
        """Each pose's row (:meth:`cells`' arguments), -1 unless its cell and the cells
        half a step away in distance and height are all reached: a pose in a cell that
        the reachable space only partly fills (its edge) is called out of reach."""
        c = self.cells
        rows = self._find(c.keys(r, z, directions, bearing))
        for dr, dz in ((0.5, 0.0), (-0.5, 0.0), (0.0, 0.5), (0.0, -0.5)):
            near = self._find(c.keys(np.maximum(r + dr * c.r_step, 0.0), z + dz * c.z_step,
                                     directions, bearing))
            rows = np.where(near >= 0, rows, -1)
        return rows

    def reachable(self, positions: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether the arm reaches each pose (bool (n,)), in the base's frame."""
        return self.rows(positions, directions) >= 0

    def seeds(self, position: np.ndarray, direction: np.ndarray, count: int = 4
              ) -> tuple[np.ndarray, np.ndarray]:
        """IK seeds for a camera at ``position`` (3,; m) looking along ``direction`` (3,;
        unit), in the base's frame: the joints (<= count, k) and camera bearings (rad)
        of the reached cells at its distance and height whose direction is nearest (its
        own cell's first): poses a little off it, from which the arm's IK gets there."""
        c = self.cells
        r = float(np.hypot(position[0], position[1]))
        bearing = math.atan2(position[1], position[0])
        own = int(c.keys(np.array([r]), np.array([position[2]]), direction[None],
                         np.array([bearing]))[0])
        if own < 0:
            return np.zeros((0, self.joints.shape[1])), np.zeros(0)
        column = own - own % (c.n_elevation * c.n_azimuth)
        lo, hi = np.searchsorted(self.keys, [column, column + c.n_elevation * c.n_azimuth])
        keys = self.keys[lo:hi]
        # each cell's central direction, relative to the bearing; the query's likewise
        elevation = (((keys // c.n_azimuth) % c.n_elevation + 0.5) / c.n_elevation - 0.5) * math.pi
        azimuth = (keys % c.n_azimuth + 0.5) / c.n_azimuth * 2 * math.pi
        sine, cosine = np.sin(elevation), np.cos(elevation)
        relative = math.atan2(direction[1], direction[0]) - bearing
        wanted = np.array([math.cos(relative) * math.hypot(*direction[:2]),
                           math.sin(relative) * math.hypot(*direction[:2]), direction[2]])
        centres = np.column_stack([cosine * np.cos(azimuth), cosine * np.sin(azimuth), sine])
        order = np.lexsort((keys != own, -(centres @ wanted)))[:count]
        order = np.concatenate([order[keys[order] == own], order[keys[order] != own]])
        return self.joints[lo + order], self.bearings[lo + order]

    def stands(self, camera: np.ndarray, direction: np.ndarray, places: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse reachability: for a camera at ``camera`` (3,; m, world) looking along
        ``direction`` (3,; unit), which base positions ``places`` (m, 2; m) put it within
        the arm's reach, the base turned as it must be. Returns that mask (m,), and for
        each place the base's yaw (rad) and the arm's joints (m, k) of the seed that
        reached the cell (NaN where out of reach)."""
        places = np.atleast_2d(places)
        offset = camera[:2] - places
        r = np.hypot(offset[:, 0], offset[:, 1])
        bearing_world = np.arctan2(offset[:, 1], offset[:, 0])
        n = len(places)
        rows = self._lookup(r, np.full(n, camera[2]), np.broadcast_to(direction, (n, 3)),
                            bearing_world)
        ok = rows >= 0
        yaw = np.full(n, np.nan)
        joints = np.full((n, self.joints.shape[1]), np.nan)
        yaw[ok] = bearing_world[ok] - self.bearings[rows[ok]]
        joints[ok] = self.joints[rows[ok]]
        return ok, yaw, joints


def build_reach_map(chain: Chain, valid: Callable[[np.ndarray], bool],
                    rng: np.random.Generator, samples: int = 2_000_000,
                    cells: ReachCells = ReachCells(), batch: int = 100_000,
                    spread_rad: float = 0.15, home: np.ndarray | None = None) -> ReachMap:
    """Sample ``samples`` arm configurations, put the camera (the chain's tool; it looks
    along its -z axis, as a MuJoCo camera does) in its cell, and keep the first
    configuration in each cell that ``valid`` accepts (clear of itself and the floor;
    asked once per new cell, so it may be slow). Half the draws are uniform within the
    chain's limits (a joint with more than a whole turn of range over one turn: the same
    poses); the other half turn the configurations found so far by a normal draw of
    ``spread_rad`` a joint, which fills the cells next to those reached (the edges of the
    reachable space, where uniform draws land seldom). With a ``home`` configuration
    (k,; rad), each cell keeps instead the drawn configuration nearest it (joint space;
    a joint that turns round, the shorter way) that ``valid`` accepts: the posture the
    arm is brought to is then the most like its home, as a person would choose it,
    and the move there the shortest."""
    if samples < 1 or batch < 1:
        raise PlacementError(f"samples and batch must be >= 1, got {samples}, {batch}")
    lower = np.maximum(chain.lower, np.minimum(chain.upper - 2 * math.pi, -math.pi))
    upper = np.minimum(chain.upper, lower + 2 * math.pi)
    found: dict[int, tuple[np.ndarray, float]] = {}
    turns = (chain.upper - chain.lower) >= 2 * math.pi - 1e-9
    nearest = np.full(cells.count if home is not None else 0, np.inf)
    nearest_angles = np.zeros((len(nearest), len(lower)), np.float32)
    nearest_bearing = np.zeros(len(nearest), np.float32)
    drawn = 0
    while drawn < samples:
        size = min(batch, samples - drawn)
        if drawn < samples // 2 or not found:
            angles = rng.uniform(lower, upper, (size, len(lower)))
        else:
            known = np.array([v[0] for v in found.values()])
            angles = known[rng.integers(0, len(known), size)] + rng.normal(
                0.0, spread_rad, (size, len(lower)))
            angles = np.clip(angles, chain.lower, chain.upper)
        drawn += size
        pos, rot = chain.forward(angles)
        direction = -rot[:, :, 2]
        r = np.hypot(pos[:, 0], pos[:, 1])
        bearing = np.arctan2(pos[:, 1], pos[:, 0])
        keys = cells.keys(r, pos[:, 2], direction, bearing)
        fresh = np.flatnonzero(keys >= 0)
        if home is not None:
            off = angles[fresh] - home
            off[:, turns] = np.mod(off[:, turns] + math.pi, 2 * math.pi) - math.pi
            distance = np.linalg.norm(off, axis=1)
            by_distance = np.lexsort((distance, keys[fresh]))
            cell, first = np.unique(keys[fresh][by_distance], return_index=True)
            pick = by_distance[first]
            better = distance[pick] < nearest[cell]
            cell, pick = cell[better], fresh[pick[better]]
            nearest[cell] = distance[np.searchsorted(fresh, pick)]
            nearest_angles[cell] = angles[pick]
            nearest_bearing[cell] = bearing[pick]
        fresh = fresh[~np.isin(keys[fresh], np.fromiter(found, np.int64, len(found)))]
        for i in fresh:  # in draw order: the same seed, the same map
            key = int(keys[i])
            if key not in found and valid(angles[i]):
                found[key] = (angles[i], float(bearing[i]))
    for key in found if home is not None else ():
        if valid(nearest_angles[key]):  # the nearest home is kept if it is clear
            found[key] = (nearest_angles[key], float(nearest_bearing[key]))
    order = sorted(found)
    return ReachMap(cells, np.array(order, np.int64),
                    np.array([found[k][0] for k in order], np.float32).reshape(len(order), -1),
                    np.array([found[k][1] for k in order], np.float32), samples)
