"""Scenes for the benchmark of placement generality (bench/studies/placement_reach.py): the
soak's random scenarios (sim/experiments/soak/draw_scenario.py) made harder to reach, with
every placement setting left at the project's defaults.

A draw is a scenario table a user could write. Over the soak's draw it adds:

- far starts: each robot's base, with probability FAR_SHARE, 2.1-3.0 m from the
  work-piece (beyond the arm's reach plus 1 m), the others 1.1-1.9 m as the soak's;
- walls between a base and the work-piece: a thin tall box across the straight way from
  a base at least WALL_BASE_M away, short enough to leave a way round it;
- enclosures: three walls round the work-piece's table, open on one side (facing any of
  the table's four sides), sometimes with a roof plate on them; the soak's obstacles near
  the table are dropped and the panel is moved outside;
- the arm: taskcam's own, Menagerie's UR5e or the compact arm of
  ``models/arms/compact_arm.xml`` (about 0.65 m from shoulder to flange).

The robots are 1 to 4, their depth source rendered or stereo, the bases always free to
drive. The pose correction and the task are off. The tables ``[search]`` and
``[rating]`` are not written (what the benchmark compares is the pipeline at its
defaults, :data:`ORACLE` being the oracle's settings). A draw does not guarantee the
scene builder accepts it (robots at their start configuration may still touch
something): the benchmark redraws those, as the soak does.

Features are recorded per scene (``enclosure``, ``stereo``, ``ur5e``, ``robots3``, ...)
and per robot (``far_start``: its base over FAR_LIMIT_M from the work-piece; ``wall``: a
wall drawn across its straight way to the work-piece). Nothing here imports mujoco.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from taskcam.sim.experiments.soak.draw_obstacles import (
    PANEL_RADIUS,
    TABLE_HALF,
    Frame,
    Solid,
    over_table,
    rounded,
)
from taskcam.sim.experiments.soak.draw_scenario import (
    ROBOT_RADIUS,
    base_clear,
    draw_scenario,
    draw_yaw,
)

COMPACT_ARM = Path(__file__).resolve().parents[2] / "models" / "arms" / "compact_arm.xml"
UR5E = "menagerie:universal_robots_ur5e"
ARMS = ("taskcam", "ur5e", "compact_arm")  # the arm kinds, as features
ARM_SHARES = (0.4, 0.3, 0.3)
FAR_SHARE = 0.35  # of the robots, each drawn far
FAR_M = (2.1, 3.0)  # a far start's distance from the work-piece (m)
FAR_LIMIT_M = 2.0  # a robot whose base starts farther than this is a far start (m)
WALL_SHARE = 0.4  # of the scenes, with one or two walls between a base and the work-piece
WALL_BASE_M = 1.7  # a wall is drawn only before a base at least this far away (m)
ENCLOSURE_SHARE = 0.3
ROOF_SHARE = 0.4  # of the enclosures
# Image sizes drawn (px): the soak's smallest (160 x 120) leave the hole detector (which
# needs a projected radius of 1 px: placement/detectability.py) few views of a 1-3 cm
# hole, so that even the oracle places few robots; these are what users run
SIZES = ((320, 240), (480, 360), (640, 480))
# the soak's features that name its placement settings: not this draw's
SOAK_SETTINGS = ("rating", "biased_random", "information_gain", "exhaustive", "coarse",
                 "bounded", "random", "planner_map", "planner_map_seen", "planner_model",
                 "tight_base", "stereo", "render")
SOAK_OBSTACLES = ("roof", "shelf", "walls1", "walls2", "walls3", "floating_sphere", "clutter")
# the oracle's placement settings: the planner knows the scene as it is, a view is
# checked against the true geometry, and the search tries up to the schema's maximum
ORACLE = {"planner_world": "model", "check_sight": True, "ik_candidates": 1000}


@dataclass(frozen=True)
class ReachScene:
    """A drawn scenario: its TOML table, the scene's features, each robot's own, each
    robot's start distance from the work-piece (m) and what was drawn where (walls,
    enclosure: ``layout``)."""

    table: dict[str, Any]
    features: tuple[str, ...]
    robot_features: tuple[tuple[str, ...], ...]
    start_distances_m: tuple[float, ...]
    layout: dict[str, Any]

    def features_of(self, robot: int) -> tuple[str, ...]:
        """Robot ``robot``'s features: the scene's and its own."""
        return self.features + self.robot_features[robot]


def oracle_table(table: dict[str, Any]) -> dict[str, Any]:
    """The same scene with the oracle's placement settings (:data:`ORACLE`)."""
    out = copy.deepcopy(table)
    out["search"] = {**out.get("search", {}), **ORACLE}
    return out


def obstacle_solid(o: dict[str, Any]) -> Solid:
    """The footprint of an obstacle table (``shape``, ``position``, ``size`` in m)."""
    x, y, z = o["position"]
    size = o["size"]
    if o["shape"] == "box":
        return Solid(x, y, (size[0], size[1]), math.radians(o.get("yaw_deg", 0.0)),
                     z - size[2], z + size[2])
    half = size[1] if o["shape"] == "cylinder" else size[0]
    return Solid(x, y, (size[0], size[0]), 0.0, z - half, z + half, True)


def _box(frame: Frame, local: tuple[float, float], z: float,
         half: tuple[float, float, float], yaw: float) -> dict[str, Any]:
    """A box obstacle at ``local`` (m, the work-piece's frame), height ``z`` (m), turned
    by ``yaw`` (rad, world)."""
    x, y = frame.world(*local)
    return {"shape": "box", "position": [rounded(x), rounded(y), rounded(z)],
            "size": [rounded(h) for h in half], "yaw_deg": rounded(math.degrees(yaw), 2)}


def _enclosure(rng: np.random.Generator, frame: Frame) -> tuple[list[dict[str, Any]],
                                                                  dict[str, Any]]:
    """Three walls round the table, 0.12-0.3 m from its edges, 1.0-1.6 m tall, open on
    one side; with ROOF_SHARE, a plate on them. Returns the obstacles and the layout
    (``open_side``: +x, -x, +y or -y of the work-piece; ``open_deg``: its direction in
    the world; ``margin_m``: the walls' outer faces beyond the table's edges)."""
    gap = float(rng.uniform(0.12, 0.3))
    thick = float(rng.uniform(0.015, 0.04))  # half (m)
    half_z = float(rng.uniform(0.5, 0.8))
    open_side = int(rng.integers(4))  # 0 +x, 1 -x, 2 +y, 3 -y
    hx, hy = TABLE_HALF
    out = []
    for side in range(4):
        if side == open_side:
            continue
        sign = 1.0 if side % 2 == 0 else -1.0
        if side < 2:  # across the table's x end
            local, half = (sign * (hx + gap + thick), 0.0), (thick, hy + gap + 2 * thick, half_z)
        else:
            local, half = (0.0, sign * (hy + gap + thick)), (hx + gap + 2 * thick, thick, half_z)
        out.append(_box(frame, local, half_z, half, frame.yaw))
    roof = bool(rng.random() < ROOF_SHARE)
    if roof:
        plate = float(rng.uniform(0.01, 0.02))
        out.append(_box(frame, (0.0, 0.0), 2 * half_z + plate,
                        (hx + gap + 2 * thick, hy + gap + 2 * thick, plate), frame.yaw))
    open_deg = math.degrees(frame.yaw) + (0.0, 180.0, 90.0, -90.0)[open_side]
    layout = {"open_side": ("+x", "-x", "+y", "-y")[open_side],
              "open_deg": rounded(math.degrees(math.remainder(math.radians(open_deg),
                                                              2 * math.pi)), 2),
              "margin_m": rounded(gap + 2 * thick), "height_m": rounded(2 * half_z),
              "roof": roof}
    return out, layout


def _panel_outside(rng: np.random.Generator, frame: Frame, margin: float,
                   open_side: str) -> tuple[float, float]:
    """A place for the panel outside the enclosure, beyond a closed side (world, m)."""
    hx, hy = TABLE_HALF
    side = str(rng.choice([s for s in ("+x", "-x", "+y", "-y") if s != open_side]))
    sign = 1.0 if side[0] == "+" else -1.0
    out = PANEL_RADIUS + float(rng.uniform(0.15, 0.3))
    if side[1] == "x":
        return frame.world(sign * (hx + margin + out), float(rng.uniform(-0.2, 0.2)))
    return frame.world(float(rng.uniform(-0.25, 0.25)), sign * (hy + margin + out))


def _bases(rng: np.random.Generator, frame: Frame, count: int, solids: list[Solid],
           panel: tuple[float, float]) -> list[dict[str, Any]]:
    """Start poses: each far (FAR_M) with FAR_SHARE, else near (1.1-1.3 m) or mid
    (1.3-1.9 m) as the soak's; facing the work-piece roughly, or at any yaw; clear of
    everything (:func:`base_clear`). A robot with no clear place in 400 tries is left
    out."""
    bases: list[dict[str, Any]] = []
    for _ in range(count):
        far = bool(rng.random() < FAR_SHARE)
        for _ in range(400):
            if far:
                distance = float(rng.uniform(*FAR_M))
            else:
                distance = float(rng.uniform(1.1, 1.3) if rng.random() < 1 / 3
                                 else rng.uniform(1.3, 1.9))
            angle = float(rng.uniform(0, 2 * math.pi))
            x, y = frame.x + distance * math.cos(angle), frame.y + distance * math.sin(angle)
            yaw = draw_yaw(rng, angle)
            if base_clear(x, y, frame, solids, panel, bases):
                bases.append({"x": rounded(x), "y": rounded(y), "yaw_deg": rounded(yaw, 2)})
                break
    return bases


def _wall(rng: np.random.Generator, frame: Frame, base: dict[str, Any], keep_out: float
          ) -> tuple[dict[str, Any], Solid]:
    """A thin wall 1.0-1.8 m tall and 0.7-1.4 m long across the straight way from
    ``base`` to the work-piece, turned up to 20 degrees off square, at least ``keep_out``
    (m) beyond the table's edges and 0.15 m clear of the robot's reach."""
    dx, dy = base["x"] - frame.x, base["y"] - frame.y
    distance, heading = math.hypot(dx, dy), math.atan2(dy, dx)
    near = TABLE_HALF[0] + keep_out + 0.1
    far = max(near, distance - ROBOT_RADIUS - 0.15)
    along = float(rng.uniform(near, far))
    half_len = float(rng.uniform(0.35, 0.7))
    half_thick = float(rng.uniform(0.02, 0.05))
    half_z = float(rng.uniform(0.5, 0.9))
    side = float(rng.uniform(-0.6, 0.6)) * (half_len - 0.15)  # the wall still crosses the way
    yaw = heading + math.radians(float(rng.uniform(-20, 20)))  # its thin side to the base
    x = frame.x + along * math.cos(heading) - side * math.sin(heading)
    y = frame.y + along * math.sin(heading) + side * math.cos(heading)
    o = {"shape": "box", "position": [rounded(x), rounded(y), rounded(half_z)],
         "size": [rounded(half_thick), rounded(half_len), rounded(half_z)],
         "yaw_deg": rounded(math.degrees(math.remainder(yaw, 2 * math.pi)), 2)}
    return o, obstacle_solid(o)


def crosses(solid: Solid, start: tuple[float, float], end: tuple[float, float],
            step: float = 0.01) -> bool:
    """Whether the straight segment from ``start`` to ``end`` (m, floor) passes through
    the footprint (sampled every ``step`` m)."""
    n = max(2, math.ceil(math.dist(start, end) / step) + 1)
    return any(solid.distance(start[0] + (end[0] - start[0]) * k / (n - 1),
                              start[1] + (end[1] - start[1]) * k / (n - 1)) == 0.0
               for k in range(n))


def _walls(rng: np.random.Generator, frame: Frame, bases: list[dict[str, Any]],
           panel: tuple[float, float], keep_out: float) -> list[tuple[dict[str, Any], Solid]]:
    """One or two walls, each before a different base at least WALL_BASE_M from the
    work-piece, kept clear of every base, the panel and the table (``keep_out`` m beyond
    its edges); none when no wall fits in 50 tries."""
    far = [b for b in bases if math.hypot(b["x"] - frame.x, b["y"] - frame.y) >= WALL_BASE_M]
    chosen = rng.permutation(len(far))[:int(rng.integers(1, 3))] if far else np.zeros(0, int)
    walls: list[tuple[dict[str, Any], Solid]] = []
    for i in chosen:
        for _ in range(50):
            o, solid = _wall(rng, frame, far[int(i)], keep_out)
            if (not over_table(frame, solid, margin=keep_out)
                    and solid.distance(*panel) > PANEL_RADIUS + 0.1
                    and all(solid.distance(b["x"], b["y"]) > ROBOT_RADIUS + 0.05 for b in bases)):
                walls.append((o, solid))
                break
    return walls


def draw_reach_scene(rng: np.random.Generator, name: str,
                     compact_arm: Path = COMPACT_ARM) -> ReachScene:
    """One scene: the soak's draw, its placement settings dropped, with far starts,
    walls, an enclosure, 1-4 robots and an arm drawn as the module says. ``compact_arm``:
    the compact arm's MJCF (written into the table as it is given)."""
    soak = draw_scenario(rng, name, heavy=False, sizes=SIZES)
    t = copy.deepcopy(soak.table)
    t.pop("search", None)
    t.pop("rating", None)
    features = [f for f in soak.features if f not in SOAK_SETTINGS and not f.startswith("robots")]
    wx, wy = t["workpiece"]["position"]
    frame = Frame(wx, wy, math.radians(t["workpiece"]["yaw_deg"]))
    obstacles: list[dict[str, Any]] = list(t.get("obstacles", []))
    panel = tuple(t["panel"]["position"][:2])
    layout: dict[str, Any] = {}
    keep_out = 0.15  # walls keep this far beyond the table's edges (m)

    if rng.random() < ENCLOSURE_SHARE:
        walls, layout["enclosure"] = _enclosure(rng, frame)
        margin = layout["enclosure"]["margin_m"]
        obstacles = [o for o in obstacles
                     if not over_table(frame, obstacle_solid(o), margin=margin + 0.15)]
        panel = _panel_outside(rng, frame, margin, layout["enclosure"]["open_side"])
        t["panel"]["position"] = [rounded(panel[0]), rounded(panel[1]), 0.0]
        obstacles = [o for o in obstacles if obstacle_solid(o).bottom >= 0.3
                     or obstacle_solid(o).distance(*panel) >= PANEL_RADIUS + 0.1]
        # the soak's obstacles left are beyond the walls: its kinds no longer say what
        features = [f for f in features if f not in SOAK_OBSTACLES]
        features += ["enclosure", "clutter"] if obstacles else ["enclosure"]
        if layout["enclosure"]["roof"]:
            features.append("enclosure_roof")
        obstacles += walls
        keep_out = margin + 0.15

    solids = [obstacle_solid(o) for o in obstacles]
    bases = _bases(rng, frame, int(t["robots"]["count"]), solids, (panel[0], panel[1]))
    between = (_walls(rng, frame, bases, (panel[0], panel[1]), keep_out)
               if rng.random() < WALL_SHARE else [])
    obstacles += [o for o, _ in between]
    layout["walls"] = len(between)
    if obstacles:
        t["obstacles"] = obstacles
    else:
        t.pop("obstacles", None)

    arm = str(rng.choice(ARMS, p=ARM_SHARES))
    t["robots"] = {"count": len(bases), "bases": bases, "move_base": True}
    if arm == "ur5e":
        t["robots"]["model"] = UR5E
    elif arm == "compact_arm":
        t["robots"]["model"] = str(compact_arm)
    t["correction"] = {"enabled": False}
    t["task"] = {"enabled": False}
    features += [t["mapping"]["depth_source"], arm, f"robots{len(bases)}"]

    distances = tuple(rounded(math.hypot(b["x"] - wx, b["y"] - wy), 3) for b in bases)
    own = []
    for b, d in zip(bases, distances, strict=True):
        mine = ["far_start"] if d > FAR_LIMIT_M else []
        if any(crosses(solid, (b["x"], b["y"]), (wx, wy)) for _, solid in between):
            mine.append("wall")
        own.append(tuple(mine))
    return ReachScene(t, tuple(features), tuple(own), distances, layout)
