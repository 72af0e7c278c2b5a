"""Random scenarios over the scenario schema (sim/config/), for the soak of
unfamiliar scenes (sim/experiments/soak/scenes.py, bench/studies/soak.py, tests/test_soak.py).

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

from taskcam.sim.experiments.soak.draw_obstacles import (
    PANEL_RADIUS,
    TABLE_HALF,
    Frame,
    Solid,
    draw_obstacles,
    over_table,
    rounded,
)

SIZES = ((160, 120), (240, 180), (320, 240), (320, 240))  # image sizes drawn (px)
HEAVY_SHARE = 10  # every HEAVY_SHARE-th scene index is heavy (see is_heavy)

# The work-piece's plate (models/workpiece.xml), in its own frame (m): its half extents
# and the rails' x span, which holes keep off.
PLATE_HALF = (0.3, 0.2)
RAILS_X = (-0.18, -0.12)
ROBOT_RADIUS = 0.7  # a robot at its start pose stays within this of its base (m)
HEAD_Z = 1.3  # and below this height (m)
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
                                  "role": role, "offset_m": [rounded(x), rounded(y)],
                                  "radius_m": rounded(r)}
        if role == "secondary":
            target["st_error_m"] = rounded(rng.uniform(0.0, 0.002), 5)
        chosen.append(target)
    return chosen, [f"targets{len(chosen)}"]


def draw_yaw(rng: np.random.Generator, angle: float) -> float:
    """A base's heading (deg) at ``angle`` (rad) round the work-piece: facing it, give or
    take 25 deg, or (one in five) any way."""
    facing = math.degrees(angle + math.pi)
    yaw = (float(rng.uniform(-180, 180)) if rng.random() < 0.2
           else facing + float(rng.normal(0, 25)))
    return math.degrees(math.remainder(math.radians(yaw), 2 * math.pi))


def base_clear(x: float, y: float, frame: Frame, solids: list[Solid],
               panel: tuple[float, float], bases: list[dict[str, Any]]) -> bool:
    """Whether a robot at (x, y) (m) keeps clear of the table, the obstacles below its
    head, the panel and the other ``bases``."""
    return (not over_table(frame, Solid(x, y, (ROBOT_RADIUS, ROBOT_RADIUS), 0.0, 0.0, HEAD_Z,
                                        True), margin=0.1)
            and all(s.distance(x, y) > ROBOT_RADIUS + 0.05 for s in solids if s.bottom < HEAD_Z)
            and math.hypot(x - panel[0], y - panel[1]) > ROBOT_RADIUS + PANEL_RADIUS + 0.1
            and all(math.hypot(x - b["x"], y - b["y"]) > 2 * ROBOT_RADIUS + 0.05 for b in bases))


def _bases(rng: np.random.Generator, frame: Frame, count: int, solids: list[Solid],
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
            yaw = draw_yaw(rng, angle)
            clear = (tight and i == 0) or base_clear(x, y, frame, solids, panel, bases)
            if clear:
                bases.append({"x": rounded(x), "y": rounded(y), "yaw_deg": rounded(yaw, 2)})
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
    t["camera"] = {"fovy_deg": rounded(rng.uniform(45, 75), 2), "width": width, "height": height,
                   "baseline_m": rounded(rng.uniform(0.08, 0.16)), "near_m": rounded(near),
                   "far_m": rounded(rng.uniform(1.3, 2.0)),
                   "samples": int(rng.choice([0, 0, 0, 2, 4]))}

    wx, wy = (float(v) for v in rng.uniform(-0.3, 0.3, 2))
    yaw = float(rng.uniform(-180, 180))
    frame = Frame(wx, wy, math.radians(yaw))
    targets, target_features = _targets(rng)
    features += target_features
    workpiece: dict[str, Any] = {"position": [rounded(wx), rounded(wy)], "yaw_deg": rounded(yaw, 2)}
    if targets:
        workpiece["targets"] = targets
    if rng.random() < 0.4:
        workpiece["position_error_m"] = rounded(rng.uniform(0, 0.01), 5)
        workpiece["yaw_error_deg"] = rounded(rng.uniform(0, 2), 3)
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
    t["panel"] = {"position": [rounded(panel[0]), rounded(panel[1]), 0.0],
                  "yaw_deg": rounded(rng.uniform(-180, 180), 2)}

    obstacles, solids, obstacle_features = draw_obstacles(rng, frame, (primary[0], primary[1]),
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
                 "bounds_min": [rounded(wx - 1.5), rounded(wy - 1.5), 0.0],
                 "bounds_max": [rounded(wx + 1.5), rounded(wy + 1.5), 1.8]}

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
        t["grid"]["miss"] = rounded(rng.uniform(0.15, 0.35), 3)
    if rng.random() < 0.5:
        mapping["entropy_threshold_bits"] = rounded(rng.uniform(0.1, 0.4), 3)
    if rng.random() < 0.2:
        mapping["unknown_occupancy"] = rounded(rng.uniform(0.05, 0.5), 3)
    t["mapping"] = mapping

    rating: dict[str, Any] = {"tfv_directions": int(rng.choice([2048, 4096, 8192])),
                              "expansion": str(rng.choice(["cone", "paper"])),
                              "unknown_occludes": bool(rng.random() < 0.85),
                              "hull_block": int(rng.integers(3, 7))}
    if rng.random() < 0.2:
        for key in ("alpha", "beta", "gamma", "delta"):
            rating[key] = rounded(rng.uniform(0.5, 2.0), 3)
    t["rating"] = rating

    method = str(rng.choice(["rating", "rating", "biased_random", "information_gain"]))
    strategy = str(rng.choice(["exhaustive", "exhaustive", "coarse", "bounded", "random"]))
    features += [method, strategy]
    low = float(rng.uniform(0.3, 0.5))
    t["search"] = {"method": method, "strategy": strategy,
                   "coarse_step": int(rng.integers(2, 4)),
                   "max_distance_m": rounded(rng.uniform(0.8, 1.4)),
                   "samples": int(rng.integers(500, 2001)),
                   "gain_samples": int(rng.integers(50, 201)),
                   "informed_max_angle_deg": rounded(rng.uniform(30, 75), 2),
                   "check_sight": bool(rng.random() < 0.8),
                   "ik_candidates": int(rng.integers(5, 21)),
                   "robot_separation_m": rounded(rng.uniform(0.3, 0.6)),
                   "camera_z_m": [rounded(low), rounded(rng.uniform(1.2, 1.6))],
                   "drive_path_m": rounded(rng.uniform(0.0, 2.0))}

    motion: dict[str, Any] = {"settle_s": rounded(rng.uniform(0.2, 0.8), 3),
                              "speed_scale": rounded(rng.uniform(0.5, 1.0), 3)}
    if heavy:  # the default scenario's positioning errors, scaled
        scale = float(rng.uniform(0.5, 1.5))
        motion.update({k: rounded(v * scale, 5) for k, v in DEFAULT_ERRORS.items()})
    elif rng.random() < 0.3:
        scale = float(rng.uniform(0.2, 1.0))
        motion.update({k: rounded(v * scale, 5) for k, v in DEFAULT_ERRORS.items()})
        features.append("motion_errors")
    t["motion"] = motion

    if heavy:
        t["correction"] = {"enabled": True,
                           "estimator": str(rng.choice(["sqpnp", "sqpnp", "kabsch", "linear"])),
                           "fiducials": int(rng.integers(16, 33)),
                           "features": int(rng.integers(400, 801)),
                           "frame_every_deg": rounded(rng.uniform(3, 5), 2),
                           "frame_every_m": rounded(rng.uniform(0.03, 0.05))}
        t["task"] = {"enabled": True, "max_steps": int(rng.integers(3, 9)),
                     "lost_limit": int(rng.integers(1, 3)), "replace": True,
                     "gain": rounded(rng.uniform(0.8, 1.0), 3),
                     "max_step_m": rounded(rng.uniform(0.03, 0.1)),
                     "stereo_margin_px": int(rng.integers(16, 49))}
    # drawn last, so that every other key draws as it did before the key existed
    world = str(rng.choice(["map", "map", "map_seen", "model"]))
    t["search"]["planner_world"] = world
    features.append(f"planner_{world}")
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
