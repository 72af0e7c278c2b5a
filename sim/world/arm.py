"""The arm on the robots' bases, as one value: its joints, its mount, and its reach — the
capability map of its camera (placement/reach.py), built once per arm from the arm's own
kinematics and joint limits, and cached in the user's cache directory by the arm's
content.

The map is built on the robot of the scene (base, arm and stereo head as the scenario
makes them: taskcam's arm, Menagerie's or the user's MJCF), its base at the origin:
configurations are drawn within the joint limits, and a cell of the map is reached by
the first that keeps the robot's own links apart and its arm and head off the floor.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from taskcam.placement.reach import Chain, ReachCells, ReachMap, build_reach_map
from taskcam.sim.world.collision import Proximity
from taskcam.sim.world.robot_model import ARM_JOINTS
from taskcam.sim.world.scene import Robot, Scene

# Configurations drawn per map: with them 95 % of the arm's reachable cells are found
# (tests/test_reach.py holds the map against IK). A draw costs ~1 us of forward
# kinematics; a new cell ~30 us of MuJoCo's distance queries (the map's build time and
# size are in docs/placement.md)
SAMPLES = 4_000_000
# The map is built for the left camera at the default stereo baseline (m), whatever the
# scenario's: at another (0.2 m at most) the left camera sits up to 4 cm (a cell) to the
# side of where the map puts it, which IK then makes up; one map serves every baseline
MAP_BASELINE_M = 0.12
VERSION = 1  # of the map's format and build: a change builds every arm's map anew
_MEMO: dict[str, ReachMap] = {}  # maps loaded in this process, by key


@dataclass(frozen=True)
class Arm:
    """The arm every robot of a scene carries: its joints' names (base to flange), the
    site the stereo head mounts on, and its camera's capability map."""

    joints: tuple[str, ...]
    mount: str
    reach: ReachMap
    build_s: float  # what building the map took (s; 0 when it came from the cache)

    @property
    def reach_m(self) -> float:
        """How far the camera gets from the base's pivot, horizontally (m)."""
        return self.reach.reach_m


def _frame(pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """The 4x4 transform of a position (m) and a quaternion (w, x, y, z)."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(quat, float))
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation.reshape(3, 3), pos
    return out


def camera_chain(model: mujoco.MjModel, robot: Robot, baseline_m: float | None = None
                 ) -> Chain:
    """The chain from the robot's base (at the origin, unturned) to its left camera's
    optical frame, through the arm's six hinges, with their limits; with ``baseline_m``,
    the left camera as it sits on the head at that stereo baseline (m)."""
    site = model.site(robot.optical_site)
    base = model.body(robot.base_body).id
    bodies = [int(site.bodyid[0])]
    while bodies[-1] != base:
        bodies.append(int(model.body_parentid[bodies[-1]]))
    arm = {int(model.jnt_qposadr.tolist().index(a)) for a in robot.qpos_adr[3:]}
    fixed = np.eye(4)
    offsets, axes, anchors, lower, upper = [], [], [], [], []
    for b in reversed(bodies):
        fixed = fixed @ _frame(model.body_pos[b], model.body_quat[b])
        start, count = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        hinges = [j for j in range(start, start + count) if j in arm]
        if hinges:
            j = hinges[0]
            offsets.append(fixed)
            axes.append(model.jnt_axis[j].copy())
            anchors.append(model.jnt_pos[j].copy())
            limited = bool(model.jnt_limited[j])
            lower.append(model.jnt_range[j, 0] if limited else -math.pi)
            upper.append(model.jnt_range[j, 1] if limited else math.pi)
            fixed = np.eye(4)
    at = model.site_pos[site.id].copy()
    if baseline_m is not None:  # the head's cameras sit on its x axis, the left at -b/2
        at[0] = -baseline_m / 2
    tip = fixed @ _frame(at, model.site_quat[site.id])
    return Chain(np.array(offsets), np.array(axes), np.array(anchors), tip,
                 np.array(lower, float), np.array(upper, float))


class SelfClear:
    """Is the robot, its base at the origin and its arm at given angles, clear of itself
    (its links apart, as the planner keeps them) and of the floor (its arm and head)?"""

    def __init__(self, scene: Scene, robot: Robot) -> None:
        self.model, self.robot = scene.model, robot
        self.data = mujoco.MjData(scene.model)
        self.data.qpos[:] = scene.start_qpos
        self.proximity = Proximity(scene.model, robot, scene.robots)
        floor = scene.model.geom("floor").id
        base = scene.model.body(robot.base_body).id
        self.above = [g for g in self.proximity.own if scene.model.geom_bodyid[g] != base]
        self.floor = floor
        self.radius = scene.model.geom_rbound
        self._fromto = np.zeros(6)

    def __call__(self, angles: np.ndarray) -> bool:
        d = self.data
        d.qpos[self.robot.qpos_adr] = (0.0, 0.0, 0.0, *angles)
        mujoco.mj_kinematics(self.model, d)
        for geom in self.above:  # off the floor: a plane is at z = 0
            if d.geom_xpos[geom][2] < self.radius[geom] and mujoco.mj_geomDistance(
                    self.model, d, geom, self.floor, 1e-3, self._fromto) < 1e-9:
                return False
        pairs = self.proximity.pairs_own
        a, b = pairs[:, 0], pairs[:, 1]
        apart = np.linalg.norm(d.geom_xpos[a] - d.geom_xpos[b], axis=1)
        for k in np.flatnonzero(apart < self.radius[a] + self.radius[b]):
            if mujoco.mj_geomDistance(self.model, d, int(a[k]), int(b[k]), 1e-3,
                                      self._fromto) < 1e-9:
                return False
        return True


def arm_key(model: mujoco.MjModel, robot: Robot, home: np.ndarray, cells: ReachCells,
            samples: int) -> str:
    """The arm's content as the map depends on it: its chain, the collision geometry of
    the robot (shape, size, place in its body), its home posture (rad) and the map's
    cells and draws."""
    chain = camera_chain(model, robot, MAP_BASELINE_M)
    geoms = Proximity(model, robot, ()).own
    h = hashlib.blake2b(digest_size=16)
    for part in (chain.offsets, chain.axes, chain.anchors, chain.tip, chain.lower, chain.upper,
                 model.geom_type[geoms], model.geom_size[geoms], model.geom_pos[geoms],
                 model.geom_quat[geoms], model.geom_bodyid[geoms] - model.geom_bodyid[geoms].min(),
                 model.body_pos[sorted(robot.body_ids)], model.body_quat[sorted(robot.body_ids)]):
        h.update(np.ascontiguousarray(np.round(part, 9)).tobytes())
    h.update(np.round(home, 9).tobytes())
    h.update(repr((cells, samples, VERSION)).encode())
    return h.hexdigest()


def cache_dir() -> Path:
    """Where maps are kept: ``$TASKCAM_CACHE``, else the user's cache directory
    (``$XDG_CACHE_HOME`` or ``~/.cache``) under ``taskcam/reach``."""
    if os.environ.get("TASKCAM_CACHE"):
        return Path(os.environ["TASKCAM_CACHE"]) / "reach"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "taskcam" / "reach"


def load_reach_map(path: Path) -> ReachMap | None:
    try:
        with np.load(path) as f:
            cells = ReachCells(**json.loads(str(f["cells"])))
            return ReachMap(cells, f["keys"], f["joints"], f["bearings"], int(f["samples"]))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None  # missing, or cut short: built again


def save_reach_map(path: Path, reach: ReachMap) -> None:
    """Write atomically: a file of its own in the same folder, then renamed over the
    map's name (workers building the same map at once each write a whole file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as f:
        np.savez(f, cells=np.array(json.dumps(dataclasses.asdict(reach.cells))),
                 keys=reach.keys, joints=reach.joints, bearings=reach.bearings,
                 samples=reach.samples)
    os.replace(f.name, path)


def scene_arm(scene: Scene, samples: int = SAMPLES, cells: ReachCells | None = None) -> Arm:
    """The scene's arm, its map from the cache or built (seeded: the same arm, the same
    map) and cached."""
    robot, cells = scene.robots[0], cells or ReachCells()
    home = scene.start_qpos[robot.qpos_adr[3:]]
    key = arm_key(scene.model, robot, home, cells, samples)
    built = 0.0
    if key not in _MEMO:
        path = cache_dir() / f"{key}.npz"
        reach = load_reach_map(path)
        if reach is None:
            started = time.perf_counter()
            reach = build_reach_map(camera_chain(scene.model, robot, MAP_BASELINE_M),
                                    SelfClear(scene, robot),
                                    np.random.default_rng(int(key[:8], 16)), samples, cells,
                                    home=home)
            built = time.perf_counter() - started
            save_reach_map(path, reach)
        _MEMO[key] = reach
    return Arm(ARM_JOINTS, scene.scenario.robots.mount, _MEMO[key], built)
