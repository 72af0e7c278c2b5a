"""Random scenarios over the scenario schema (sim/config/scenario.py), for the soak of
unfamiliar scenes (sim/experiments/soak.py, bench/soak.py, tests/test_soak.py).

A draw is a TOML table a user could have written: 1 to 4 robots with bases near and
far at any yaw, the work-piece anywhere near the origin at any yaw (sometimes with
other holes, sometimes misplaced), obstacles of every shape and height (low crates,
pillars, floating spheres, walls, a roof on posts or a shelf over the target), either
depth source, every mapping strategy and gain, every placement method and search
strategy, on small images with few views. A ``heavy`` draw also corrects the camera
poses from fiducials (with the default scenario's kind of positioning errors) and runs
the insertion task with a short loss limit, so that re-placements happen.

The draw keeps obviously impossible geometry out (obstacles through the table, bases
inside obstacles or each other), except that a share of the draws puts one base
closer than is safe: whether the scene builder accepts those is for it to say.
Nothing here imports mujoco.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

SIZES = ((160, 120), (240, 180), (320, 240), (320, 240))  # image sizes drawn (px)
HEAVY_SHARE = 10  # every HEAVY_SHARE-th scene index is heavy (see is_heavy)

# The work-piece (models/workpiece.xml), in its own frame (m): table half extents, the
# plate's half extents, the height everything on it stays below, the rails' x span.
TABLE_HALF = (0.4, 0.3)
PLATE_HALF = (0.3, 0.2)
TOP_Z = 0.56
RAILS_X = (-0.18, -0.12)
ROBOT_RADIUS = 0.7  # a robot at its start pose stays within this of its base (m)
HEAD_Z = 1.3  # and below this height (m)
PANEL_RADIUS = 0.12  # the panel lying on the floor (m)
# The default scenario's positioning errors ([motion]), given to heavy draws.
DEFAULT_ERRORS = {"joint_offset_deg": 0.5, "joint_noise_deg": 0.05, "base_offset_m": 0.015,
                  "base_yaw_deg": 0.8, "suspension_deg": 0.8}


@dataclass(frozen=True)
class Draw:
    """A random scenario: its TOML table and what it was drawn with."""

    table: dict[str, Any]
    features: tuple[str, ...]  # e.g. "roof", "walls2", "tight_base", "stereo", "heavy"


def is_heavy(index: int) -> bool:
    """Whether scene ``index`` of a soak has correction and task on (one in HEAVY_SHARE)."""
    return index % HEAVY_SHARE == HEAVY_SHARE - 1


@dataclass(frozen=True)
class _Solid:
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


class _Frame:
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


def _r(v: float, digits: int = 4) -> float:
    return round(float(v), digits)


def _over_table(frame: _Frame, solid: _Solid, margin: float = 0.05) -> bool:
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


def _targets(rng: np.random.Generator) -> tuple[list[dict[str, Any]], list[str]]:
    """The default two holes (most draws), or 1 to 3 random ones on the plate, off the
    rails, apart from each other."""
    if rng.random() < 0.65:
        return [], []  # the default targets
    chosen: list[dict[str, Any]] = []
    want = int(rng.integers(1, 4))
    for _ in range(200):
        if len(chosen) == want:
            break
        r = float(rng.uniform(0.01, 0.03))
        x = float(rng.uniform(-PLATE_HALF[0] + r, PLATE_HALF[0] - r))
        y = float(rng.uniform(-PLATE_HALF[1] + r, PLATE_HALF[1] - r))
        if RAILS_X[0] - r < x < RAILS_X[1] + r:
            continue
        if any(math.hypot(x - c["offset_m"][0], y - c["offset_m"][1])
               < r + c["radius_m"] + 0.02 for c in chosen):
            continue
        role = "primary" if not chosen else "secondary"
        target: dict[str, Any] = {"name": role if not chosen else f"secondary{len(chosen)}",
                                  "role": role, "offset_m": [_r(x), _r(y)], "radius_m": _r(r)}
        if role == "secondary":
            target["st_error_m"] = _r(rng.uniform(0.0, 0.002), 5)
        chosen.append(target)
    return chosen, [f"targets{len(chosen)}"]


def _box(x: float, y: float, z: float, half: tuple[float, float, float], yaw_rad: float
         ) -> tuple[dict[str, Any], _Solid]:
    o = {"shape": "box", "position": [_r(x), _r(y), _r(z)], "size": [_r(h) for h in half],
         "yaw_deg": _r(math.degrees(yaw_rad), 2)}
    return o, _Solid(x, y, (half[0], half[1]), yaw_rad, z - half[2], z + half[2])


def _cylinder(x: float, y: float, z: float, radius: float, half_height: float
              ) -> tuple[dict[str, Any], _Solid]:
    o = {"shape": "cylinder", "position": [_r(x), _r(y), _r(z)],
         "size": [_r(radius), _r(half_height)]}
    return o, _Solid(x, y, (radius, radius), 0.0, z - half_height, z + half_height, True)


def _sphere(x: float, y: float, z: float, radius: float) -> tuple[dict[str, Any], _Solid]:
    o = {"shape": "sphere", "position": [_r(x), _r(y), _r(z)], "size": [_r(radius)]}
    return o, _Solid(x, y, (radius, radius), 0.0, z - radius, z + radius, True)


def _roof(rng: np.random.Generator, frame: _Frame, target: tuple[float, float]
          ) -> list[tuple[dict[str, Any], _Solid]]:
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


def _shelf(rng: np.random.Generator, frame: _Frame, target: tuple[float, float]
           ) -> list[tuple[dict[str, Any], _Solid]]:
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


def _walls(rng: np.random.Generator, frame: _Frame, count: int
           ) -> list[tuple[dict[str, Any], _Solid]]:
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


def _clutter(rng: np.random.Generator, frame: _Frame) -> tuple[dict[str, Any], _Solid]:
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


def _floating_sphere(rng: np.random.Generator, frame: _Frame, target: tuple[float, float]
                     ) -> tuple[dict[str, Any], _Solid]:
    """A sphere hanging over the target."""
    x, y = frame.world(target[0] + float(rng.uniform(-0.1, 0.1)),
                       target[1] + float(rng.uniform(-0.1, 0.1)))
    radius = float(rng.uniform(0.04, 0.15))
    return _sphere(x, y, TOP_Z + radius + float(rng.uniform(0.12, 0.5)), radius)


def _obstacles(rng: np.random.Generator, frame: _Frame, target: tuple[float, float],
               panel: tuple[float, float]) -> tuple[list[dict[str, Any]], list[_Solid],
                                                    list[str]]:
    groups: list[tuple[str, list[tuple[dict[str, Any], _Solid]]]] = []
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
    solids: list[_Solid] = []
    features = []
    for name, items in groups:
        kept = 0
        for o, solid in items:
            if solid.bottom < TOP_Z + 0.05 and _over_table(frame, solid):
                continue  # through the table: a roof's posts and walls never are
            if solid.bottom < 0.3 and solid.distance(*panel) < PANEL_RADIUS + 0.1:
                continue  # on the panel
            obstacles.append(o)
            solids.append(solid)
            kept += 1
        if kept:
            features.append(name)
    return obstacles, solids, features


def _bases(rng: np.random.Generator, frame: _Frame, count: int, solids: list[_Solid],
           panel: tuple[float, float], tight: bool) -> list[dict[str, Any]]:
    """Start poses near (1.1-1.3 m), mid (1.3-1.9 m) and far (1.9-2.6 m) from the
    work-piece, facing it roughly or at any yaw, clear of obstacles, the panel and each
    other; with ``tight``, the first one 0.75-1.1 m away, without those checks."""
    bases: list[dict[str, Any]] = []
    for i in range(count):
        for _ in range(400):
            if tight and i == 0:
                distance = float(rng.uniform(0.75, 1.1))
            else:
                distance = float(rng.choice([rng.uniform(1.1, 1.3), rng.uniform(1.3, 1.9),
                                             rng.uniform(1.9, 2.6)], p=[0.25, 0.5, 0.25]))
            angle = float(rng.uniform(0, 2 * math.pi))
            x, y = frame.x + distance * math.cos(angle), frame.y + distance * math.sin(angle)
            facing = math.degrees(angle + math.pi)
            yaw = (float(rng.uniform(-180, 180)) if rng.random() < 0.2
                   else facing + float(rng.normal(0, 25)))
            yaw = math.degrees(math.remainder(math.radians(yaw), 2 * math.pi))
            clear = (tight and i == 0) or (
                not _over_table(frame, _Solid(x, y, (ROBOT_RADIUS, ROBOT_RADIUS), 0.0, 0.0,
                                              HEAD_Z, True), margin=0.1)
                and all(s.distance(x, y) > ROBOT_RADIUS + 0.05 for s in solids
                        if s.bottom < HEAD_Z)
                and math.hypot(x - panel[0], y - panel[1]) > ROBOT_RADIUS + PANEL_RADIUS + 0.1
                and all(math.hypot(x - b["x"], y - b["y"]) > 2 * ROBOT_RADIUS + 0.05
                        for b in bases))
            if clear:
                bases.append({"x": _r(x), "y": _r(y), "yaw_deg": _r(yaw, 2)})
                break
    return bases


def draw_scenario(rng: np.random.Generator, name: str, heavy: bool = False,
                  sizes: tuple[tuple[int, int], ...] = SIZES) -> Draw:
    """One random scenario table (every key the schema knows may be drawn). ``heavy``
    turns on the pose correction and the task; ``sizes`` are the image sizes (px) to
    draw from."""
    features: list[str] = ["heavy"] if heavy else []
    t: dict[str, Any] = {"name": name, "seed": int(rng.integers(0, 2**31 - 1))}

    width, height = sizes[int(rng.integers(len(sizes)))]
    near = float(rng.uniform(0.25, 0.45))
    t["camera"] = {"fovy_deg": _r(rng.uniform(45, 75), 2), "width": width, "height": height,
                   "baseline_m": _r(rng.uniform(0.08, 0.16)), "near_m": _r(near),
                   "far_m": _r(rng.uniform(1.3, 2.0)),
                   "samples": int(rng.choice([0, 0, 0, 2, 4]))}

    wx, wy = (float(v) for v in rng.uniform(-0.3, 0.3, 2))
    yaw = float(rng.uniform(-180, 180))
    frame = _Frame(wx, wy, math.radians(yaw))
    targets, target_features = _targets(rng)
    features += target_features
    workpiece: dict[str, Any] = {"position": [_r(wx), _r(wy)], "yaw_deg": _r(yaw, 2)}
    if targets:
        workpiece["targets"] = targets
    if rng.random() < 0.4:
        workpiece["position_error_m"] = _r(rng.uniform(0, 0.01), 5)
        workpiece["yaw_error_deg"] = _r(rng.uniform(0, 2), 3)
        features.append("misplaced")
    t["workpiece"] = workpiece
    primary = next((tg["offset_m"] for tg in targets if tg["role"] == "primary"), [0.05, 0.0])

    # the panel lies beside the table, clear of it
    if rng.random() < 0.5:
        local = (float(rng.uniform(-0.35, 0.35)),
                 float(rng.choice([-1, 1])) * (TABLE_HALF[1] + float(rng.uniform(0.2, 0.4))))
    else:
        local = (float(rng.choice([-1, 1])) * (TABLE_HALF[0] + float(rng.uniform(0.2, 0.4))),
                 float(rng.uniform(-0.25, 0.25)))
    panel = frame.world(*local)
    t["panel"] = {"position": [_r(panel[0]), _r(panel[1]), 0.0],
                  "yaw_deg": _r(rng.uniform(-180, 180), 2)}

    obstacles, solids, obstacle_features = _obstacles(rng, frame, (primary[0], primary[1]),
                                                      panel)
    features += obstacle_features
    if obstacles:
        t["obstacles"] = obstacles

    count = int(rng.integers(1, 5))
    tight = rng.random() < 0.05
    bases = _bases(rng, frame, count, solids, panel, tight)
    if tight:
        features.append("tight_base")
    features.append(f"robots{len(bases)}")
    t["robots"] = {"count": len(bases), "bases": bases,
                   "move_base": bool(rng.random() < 0.85)}

    t["grid"] = {"resolution_m": float(rng.choice([0.05, 0.05, 0.06, 0.08])),
                 "bounds_min": [_r(wx - 1.5), _r(wy - 1.5), 0.0],
                 "bounds_max": [_r(wx + 1.5), _r(wy + 1.5), 1.8]}

    source = "stereo" if rng.random() < 0.3 else "render"
    features.append(source)
    # Rendered depth marks a voxel free in one view; stereo's sensor model takes about five
    # agreeing views (two with a lower miss probability), so stereo gets more of them.
    # (A view costs about 0.1 s at these sizes; with fewer than about five views the
    # target region stays largely unknown, and unknown voxels occlude.)
    views = len(bases) + int(rng.integers(1, 6) if source == "render" else rng.integers(3, 7))
    mapping: dict[str, Any] = {
        "depth_source": source,
        "strategy": str(rng.choice(["cooperative", "cooperative", "single", "random"])),
        "gain": str(rng.choice(["entropy", "unobserved", "rear_side"])),
        "max_views": min(8 if source == "render" else 10, views),
        "candidates_per_robot": int(rng.integers(8, 25)),
        "gain_stride": int(rng.choice([16, 24, 32])),
        "pixel_stride": int(rng.integers(1, max(2, width // 80) + 1)),  # 40 px wide or more
    }
    if source == "stereo" and rng.random() < 0.5:
        t["grid"]["miss"] = _r(rng.uniform(0.15, 0.35), 3)
    if rng.random() < 0.5:
        mapping["entropy_threshold_bits"] = _r(rng.uniform(0.1, 0.4), 3)
    if rng.random() < 0.2:
        mapping["unknown_occupancy"] = _r(rng.uniform(0.05, 0.5), 3)
    t["mapping"] = mapping

    rating: dict[str, Any] = {"tfv_directions": int(rng.choice([2048, 4096, 8192])),
                              "expansion": str(rng.choice(["cone", "paper"])),
                              "unknown_occludes": bool(rng.random() < 0.85),
                              "hull_block": int(rng.integers(3, 7))}
    if rng.random() < 0.2:
        for key in ("alpha", "beta", "gamma", "delta"):
            rating[key] = _r(rng.uniform(0.5, 2.0), 3)
    t["rating"] = rating

    method = str(rng.choice(["rating", "rating", "biased_random", "information_gain"]))
    strategy = str(rng.choice(["exhaustive", "exhaustive", "coarse", "bounded", "random"]))
    features += [method, strategy]
    low = float(rng.uniform(0.3, 0.5))
    t["search"] = {"method": method, "strategy": strategy,
                   "coarse_step": int(rng.integers(2, 4)),
                   "max_distance_m": _r(rng.uniform(0.8, 1.4)),
                   "samples": int(rng.integers(500, 2001)),
                   "gain_samples": int(rng.integers(50, 201)),
                   "random_max_angle_deg": _r(rng.uniform(30, 75), 2),
                   "check_sight": bool(rng.random() < 0.8),
                   "ik_candidates": int(rng.integers(5, 21)),
                   "robot_separation_m": _r(rng.uniform(0.3, 0.6)),
                   "camera_z_m": [_r(low), _r(rng.uniform(1.2, 1.6))],
                   "reach_m": _r(rng.uniform(1.0, 1.5))}

    motion: dict[str, Any] = {"settle_s": _r(rng.uniform(0.2, 0.8), 3),
                              "speed_scale": _r(rng.uniform(0.5, 1.0), 3)}
    if heavy:  # the default scenario's positioning errors, scaled
        scale = float(rng.uniform(0.5, 1.5))
        motion.update({k: _r(v * scale, 5) for k, v in DEFAULT_ERRORS.items()})
    elif rng.random() < 0.3:
        scale = float(rng.uniform(0.2, 1.0))
        motion.update({k: _r(v * scale, 5) for k, v in DEFAULT_ERRORS.items()})
        features.append("motion_errors")
    t["motion"] = motion

    if heavy:
        t["correction"] = {"enabled": True,
                           "estimator": str(rng.choice(["sqpnp", "sqpnp", "kabsch", "linear"])),
                           "fiducials": int(rng.integers(16, 33)),
                           "features": int(rng.integers(400, 801)),
                           "frame_every_deg": _r(rng.uniform(3, 5), 2),
                           "frame_every_m": _r(rng.uniform(0.03, 0.05))}
        t["task"] = {"enabled": True, "max_steps": int(rng.integers(3, 9)),
                     "lost_limit": int(rng.integers(1, 3)), "replace": True,
                     "gain": _r(rng.uniform(0.8, 1.0), 3),
                     "max_step_m": _r(rng.uniform(0.03, 0.1)),
                     "stereo_margin_px": int(rng.integers(16, 49))}
    return Draw(t, tuple(features))


def _value(v: Any) -> str:
    """A TOML inline value."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"no TOML for {v}")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"no TOML for {type(v).__name__}")


def to_toml(table: dict[str, Any]) -> str:
    """A scenario table as TOML text: scalars first, then one section per sub-table,
    and lists of tables as arrays of tables (``[[obstacles]]``)."""
    lines = [f"{k} = {_value(v)}" for k, v in table.items() if not isinstance(v, dict | list)]
    for k, v in table.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]", *(f"{kk} = {_value(vv)}" for kk, vv in v.items())]
        elif isinstance(v, list):
            for item in v:
                lines += ["", f"[[{k}]]", *(f"{kk} = {_value(vv)}" for kk, vv in item.items())]
    return "\n".join(lines) + "\n"
