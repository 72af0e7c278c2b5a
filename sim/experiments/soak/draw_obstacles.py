"""Drawing a random scenario's obstacles around the work-piece: a roof on posts or a
shelf over the target, walls beside the table, a sphere hanging over the target, and
clutter further out; each kept clear of the table and the panel, with its footprint
(:class:`Solid`) for the robots' bases to keep clear of (sim/experiments/soak/draw_scenario.py).
Nothing here imports mujoco.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

# The work-piece (models/workpiece.xml), in its own frame (m): table half extents and
# the height everything on it stays below.
TABLE_HALF = (0.4, 0.3)
TOP_Z = 0.56
PANEL_RADIUS = 0.12  # the panel lying on the floor (m)


@dataclass(frozen=True)
class Solid:
    """An obstacle's footprint for clearance tests: a rectangle (half extents ``half``,
    turned by ``yaw`` rad) or a circle (``half`` = (radius, radius), ``round``) about
    (x, y), from ``bottom`` to ``top`` (m)."""

    x: float
    y: float
    half: tuple[float, float]
    yaw: float
    bottom: float
    top: float
    round: bool = False

    def distance(self, px: float, py: float) -> float:
        """From the point (m, floor) to the footprint; 0 inside it."""
        dx, dy = px - self.x, py - self.y
        if self.round:
            return max(math.hypot(dx, dy) - self.half[0], 0.0)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        return math.hypot(max(abs(lx) - self.half[0], 0.0), max(abs(ly) - self.half[1], 0.0))

    def corners(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hx, hy = self.half
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return local @ np.array([[c, s], [-s, c]]) + (self.x, self.y)


class Frame:
    """The work-piece's floor frame: position (m) and yaw (rad)."""

    def __init__(self, x: float, y: float, yaw: float) -> None:
        self.x, self.y, self.yaw = x, y, yaw

    def world(self, lx: float, ly: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * lx - s * ly, self.y + s * lx + c * ly

    def local(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        return c * dx + s * dy, -s * dx + c * dy


def rounded(v: float, digits: int = 4) -> float:
    """``v`` as a draw writes it: a Python float of ``digits`` decimals."""
    return round(float(v), digits)


def over_table(frame: Frame, solid: Solid, margin: float = 0.05) -> bool:
    """Whether a footprint reaches over the table grown by ``margin`` (separating axes
    for a rectangle, the nearest point for a circle)."""
    hx, hy = TABLE_HALF[0] + margin, TABLE_HALF[1] + margin
    if solid.round:
        lx, ly = frame.local(solid.x, solid.y)
        return math.hypot(max(abs(lx) - hx, 0.0), max(abs(ly) - hy, 0.0)) < solid.half[0]
    corners = np.array([frame.local(*c) for c in solid.corners()])
    table = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    for poly in (table, corners):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            a, b = table @ axis, corners @ axis
            if a.max() < b.min() or b.max() < a.min():
                return False  # a separating axis
    return True



def _box(x: float, y: float, z: float, half: tuple[float, float, float], yaw_rad: float
         ) -> tuple[dict[str, Any], Solid]:
    o = {"shape": "box", "position": [rounded(x), rounded(y), rounded(z)],
         "size": [rounded(h) for h in half], "yaw_deg": rounded(math.degrees(yaw_rad), 2)}
    return o, Solid(x, y, (half[0], half[1]), yaw_rad, z - half[2], z + half[2])


def _cylinder(x: float, y: float, z: float, radius: float, half_height: float
              ) -> tuple[dict[str, Any], Solid]:
    o = {"shape": "cylinder", "position": [rounded(x), rounded(y), rounded(z)],
         "size": [rounded(radius), rounded(half_height)]}
    return o, Solid(x, y, (radius, radius), 0.0, z - half_height, z + half_height, True)


def _sphere(x: float, y: float, z: float, radius: float) -> tuple[dict[str, Any], Solid]:
    o = {"shape": "sphere", "position": [rounded(x), rounded(y), rounded(z)],
         "size": [rounded(radius)]}
    return o, Solid(x, y, (radius, radius), 0.0, z - radius, z + radius, True)


def _roof(rng: np.random.Generator, frame: Frame, target: tuple[float, float]
          ) -> list[tuple[dict[str, Any], Solid]]:
    """A beam or roof over the target on two posts standing beside the table (the
    default scenario's beam, anywhere along the plate, at any height that hides the
    views from above)."""
    tx = target[0] + float(rng.uniform(-0.05, 0.05))
    post_y = TABLE_HALF[1] + float(rng.uniform(0.12, 0.35))
    height = float(rng.uniform(0.68, 1.1))
    thick = float(rng.uniform(0.01, 0.04))
    half_x = float(rng.uniform(0.05, 0.3))
    post_r = float(rng.uniform(0.025, 0.06))
    out = []
    x, y = frame.world(tx, 0.0)
    out.append(_box(x, y, height + thick, (half_x, post_y + post_r, thick), frame.yaw))
    for side in (-1.0, 1.0):
        px, py = frame.world(tx, side * post_y)
        out.append(_cylinder(px, py, height / 2, post_r, height / 2))
    return out


def _shelf(rng: np.random.Generator, frame: Frame, target: tuple[float, float]
           ) -> list[tuple[dict[str, Any], Solid]]:
    """A shelf over the target held by a wall behind one side of the table."""
    side = float(rng.choice([-1.0, 1.0]))
    along_x = bool(rng.random() < 0.5)  # the wall behind an end (x) or a side (y)
    half_table = TABLE_HALF[0] if along_x else TABLE_HALF[1]
    gap = float(rng.uniform(0.08, 0.3))
    wall_c = side * (half_table + gap)
    height = float(rng.uniform(0.7, 1.15))
    thick = float(rng.uniform(0.015, 0.04))
    wall_len = float(rng.uniform(0.3, 0.6))
    t_along = target[0] if along_x else target[1]
    reach = abs(wall_c - t_along) + float(rng.uniform(0.05, 0.2))  # past the target
    shelf_c = wall_c - side * reach / 2
    if along_x:
        wx, wy = frame.world(wall_c, target[1])
        sx, sy = frame.world(shelf_c, target[1])
        wall = _box(wx, wy, height / 2, (thick, wall_len, height / 2), frame.yaw)
        shelf = _box(sx, sy, height + thick, (reach / 2, wall_len, thick), frame.yaw)
    else:
        wx, wy = frame.world(target[0], wall_c)
        sx, sy = frame.world(target[0], shelf_c)
        wall = _box(wx, wy, height / 2, (wall_len, thick, height / 2), frame.yaw)
        shelf = _box(sx, sy, height + thick, (wall_len, reach / 2, thick), frame.yaw)
    return [wall, shelf]


def _walls(rng: np.random.Generator, frame: Frame, count: int
           ) -> list[tuple[dict[str, Any], Solid]]:
    """``count`` walls on different sides of the table (an L, a U), low or tall."""
    sides = rng.permutation(4)[:count]
    out = []
    for s in sides:
        along_x = s < 2  # the wall runs along x (beside the table's y side)
        sign = 1.0 if s % 2 == 0 else -1.0
        gap = float(rng.uniform(0.08, 0.4))
        half_h = float(rng.uniform(0.15, 0.6))
        thick = float(rng.uniform(0.015, 0.05))
        length = float(rng.uniform(0.3, 0.9))
        shift = float(rng.uniform(-0.2, 0.2))
        if along_x:
            x, y = frame.world(shift, sign * (TABLE_HALF[1] + gap + thick))
            out.append(_box(x, y, half_h, (length, thick, half_h), frame.yaw))
        else:
            x, y = frame.world(sign * (TABLE_HALF[0] + gap + thick), shift)
            out.append(_box(x, y, half_h, (thick, length, half_h), frame.yaw))
    return out


def _clutter(rng: np.random.Generator, frame: Frame) -> tuple[dict[str, Any], Solid]:
    """One box, cylinder or sphere 0.5 to 1.6 m from the work-piece: low, tall, or (a
    sphere) floating."""
    distance = float(rng.uniform(0.5, 1.6))
    angle = float(rng.uniform(0, 2 * math.pi))
    x, y = frame.x + distance * math.cos(angle), frame.y + distance * math.sin(angle)
    tall = rng.random() < 0.4
    shape = rng.choice(["box", "cylinder", "sphere"])
    if shape == "box":
        half_z = float(rng.uniform(0.3, 0.8) if tall else rng.uniform(0.04, 0.25))
        half = (float(rng.uniform(0.04, 0.25)), float(rng.uniform(0.04, 0.25)), half_z)
        return _box(x, y, half_z, half, float(rng.uniform(0, math.pi)))
    if shape == "cylinder":
        half_z = float(rng.uniform(0.3, 0.8) if tall else rng.uniform(0.04, 0.25))
        return _cylinder(x, y, half_z, float(rng.uniform(0.03, 0.15)), half_z)
    radius = float(rng.uniform(0.04, 0.2))
    z = float(rng.uniform(0.6, 1.4)) if tall else radius
    return _sphere(x, y, z, radius)


def _floating_sphere(rng: np.random.Generator, frame: Frame, target: tuple[float, float]
                     ) -> tuple[dict[str, Any], Solid]:
    """A sphere hanging over the target."""
    x, y = frame.world(target[0] + float(rng.uniform(-0.1, 0.1)),
                       target[1] + float(rng.uniform(-0.1, 0.1)))
    radius = float(rng.uniform(0.04, 0.15))
    return _sphere(x, y, TOP_Z + radius + float(rng.uniform(0.12, 0.5)), radius)


def draw_obstacles(rng: np.random.Generator, frame: Frame, target: tuple[float, float],
               panel: tuple[float, float]) -> tuple[list[dict[str, Any]], list[Solid],
                                                    list[str]]:
    """Obstacles around the work-piece (``frame``) by kind, each as a TOML table, with
    their footprints and the kinds kept; none through the table or on the ``panel``."""
    groups: list[tuple[str, list[tuple[dict[str, Any], Solid]]]] = []
    if rng.random() < 0.25:
        groups.append(("roof", _roof(rng, frame, target)))
    elif rng.random() < 0.2:
        groups.append(("shelf", _shelf(rng, frame, target)))
    if rng.random() < 0.3:
        count = int(rng.integers(1, 4))
        groups.append((f"walls{count}", _walls(rng, frame, count)))
    if rng.random() < 0.15:
        groups.append(("floating_sphere", [_floating_sphere(rng, frame, target)]))
    if rng.random() < 0.7:
        items = [_clutter(rng, frame) for _ in range(int(rng.integers(1, 6)))]
        groups.append(("clutter", items))
    obstacles: list[dict[str, Any]] = []
    solids: list[Solid] = []
    features = []
    for name, items in groups:
        kept = 0
        for o, solid in items:
            if solid.bottom < TOP_Z + 0.05 and over_table(frame, solid):
                continue  # through the table: a roof's posts and walls never are
            if solid.bottom < 0.3 and solid.distance(*panel) < PANEL_RADIUS + 0.1:
                continue  # on the panel
            obstacles.append(o)
            solids.append(solid)
            kept += 1
        if kept:
            features.append(name)
    return obstacles, solids, features
