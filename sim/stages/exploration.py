"""Cooperative mapping: robots choose views by expected information, move there, look.

Each robot first looks at the target from its start pose. Then, round by round, every
robot (only the first with strategy ``single``) samples candidate camera poses in its
arm's reach, looking into the target region; mink moves the arm there (the base stays);
the candidates it can reach without touching anything are rated by the chosen gain,
and the robot takes the best. With strategy ``cooperative`` each robot's candidates
are rated knowing every view already chosen in the round. The chosen views are then
taken: rendered and integrated. Exploration stops when the target region's mean
entropy falls below the threshold, or after ``max_views`` views.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from taskcam.mapping import (
    FloorMap,
    GainModel,
    OccupancyGrid,
    Pinhole,
    View,
    integrate_depth,
    mean_entropy,
    opencv_pose,
    region_mask,
)
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.stages.world import World
from taskcam.sim.world.base_scanner import scan_into
from taskcam.sim.world.collision import Proximity
from taskcam.sim.world.ik import IKSettings, solve_camera_pose
from taskcam.sim.world.render import Renderer, camera_pose
from taskcam.sim.world.scene import Robot, Scene
from taskcam.sim.world.sensing import DepthSensor

# Mapping views need not be exact: the view is rated where the camera really is.
VIEW_IK = IKSettings(max_iterations=60, position_tolerance_m=0.005,
                     orientation_tolerance_deg=1.0)
REACH_M = (0.35, 1.0)  # camera distance from the shoulder (UR5e reach about 0.85 m + head)
CLOSE_ENOUGH_M = 0.05  # a candidate counts as reached within this of where it was sampled


def gain_model(s: Scenario, grid: OccupancyGrid, pinhole: Pinhole, interest: np.ndarray
               ) -> GainModel:
    """Expected information of views about the voxels of ``interest``, as the scenario's
    mapping measures it."""
    m = s.mapping
    return GainModel(grid, pinhole, interest, s.grid.max_range_m, m.gain_stride,
                     m.unknown_occupancy, s.rating.free_threshold)


@dataclass(frozen=True)
class Survey:
    """What mapping did: the views each robot took, the target region's mean entropy
    (bits) after each, and why it stopped; ``summary()`` is ``summary.json``'s
    ``mapping``."""

    depth_source: str
    strategy: str
    gain: str
    views: dict[str, int]  # by robot
    region_entropy_history_bits: list[float]  # before the first view, then after each
    region_known_fraction: float  # of the region's voxels, entropy below 0.5 bit
    region_voxels: int
    stopped_by: str  # "threshold", "max_views" or "no_reachable_view"
    taken: list[dict[str, Any]]  # each view: robot, position, axis, gain, entropy after
    time_s: float

    @property
    def views_total(self) -> int:
        return len(self.taken)

    def summary(self) -> dict[str, Any]:
        history = self.region_entropy_history_bits
        return {
            "depth_source": self.depth_source, "strategy": self.strategy, "gain": self.gain,
            "views": self.views, "views_total": self.views_total,
            "region_entropy_bits": {"before": history[0], "after": history[-1]},
            "region_entropy_history_bits": history,
            "region_known_fraction": self.region_known_fraction,
            "region_voxels": self.region_voxels, "stopped_by": self.stopped_by,
            "taken": self.taken, "time_s": self.time_s}


def explore(world: World, renderer: Renderer) -> Survey:
    """Stage 1: the robots map the target region into the world's grid, choosing views
    by expected information; each view is recorded, and the map at the end."""
    s, pinhole, recorder = world.scenario, world.pinhole, world.recorder
    sensor = DepthSensor(renderer, pinhole, s.mapping.depth_source, s.camera.baseline_m,
                         world.scene.robot_geoms())

    def on_view(robot: Robot, T: np.ndarray, gain: float, depth: np.ndarray,
                entropy_bits: float) -> None:
        recorder.tick()
        recorder.bodies(world.data)
        recorder.entropy(entropy_bits)
        recorder.camera(robot.name, camera_pose(world.data, robot.camera), pinhole, depth=depth)
        recorder.view(robot.name, T, pinhole, s.camera.far_m, gain)

    with world.timer("mapping"):
        survey = Exploration(world.scene, world.data, world.grid, sensor, pinhole, world.rng,
                             on_view, world.model,
                             world.floor if s.search.planner_world != "model" else None).run()
    recorder.grid(world.grid)
    recorder.mapped([r.name for r in world.scene.robots])
    return survey


@dataclass(frozen=True)
class Candidate:
    robot: Robot
    qpos: np.ndarray  # full configuration with the robot at the candidate
    view: View
    motion_m: float  # camera displacement from where it is now


@dataclass(frozen=True)
class _Chosen:
    robot: Robot
    qpos: np.ndarray
    gain: float


# called after each view: the robot, its camera's pose (OpenCV, world), the view's gain
# (bits; NaN for a start view), its depth image (m) and the region's entropy after it
OnView = Callable[[Robot, np.ndarray, float, np.ndarray, float], None]


class Exploration:
    """Runs the mapping stage of an episode on its scene, data and grid."""

    def __init__(self, scene: Scene, data: mujoco.MjData, grid: OccupancyGrid,
                 sensor: DepthSensor, pinhole: Pinhole, rng: np.random.Generator,
                 on_view: OnView | None = None,
                 world: mujoco.MjModel | None = None, floor: FloorMap | None = None) -> None:
        """``data`` belongs to ``world``, the simulated world (default: the nominal
        model); the views are taken there. The bases' scanners scan the ``floor``
        wherever the robots go."""
        self.scene, self.data, self.grid, self.sensor = scene, data, grid, sensor
        self.floor = floor
        self.world = scene.model if world is None else world
        self.pinhole, self.rng = pinhole, rng
        self.s: Scenario = scene.scenario
        m = self.s.mapping
        self.interest = region_mask(grid, scene.primary.position, np.array(m.region_half_m))
        self.history: list[float] = [mean_entropy(grid, self.interest)]
        self.taken: list[dict[str, Any]] = []
        self.on_view = on_view
        self.proximity = {r.name: Proximity(scene.model, r, scene.robots) for r in scene.robots}

    # ------------------------------------------------------------ public

    def run(self) -> Survey:
        start = time.perf_counter()
        m = self.s.mapping
        robots = self.scene.robots if m.strategy != "single" else self.scene.robots[:1]
        for robot in robots:  # the start views: look at the target
            if self.done():
                break
            ik = solve_camera_pose(self.scene.model, self.data.qpos, robot,
                                   self.scene.primary.position, move_base=False)
            self.observe(robot, ik.qpos, gain=math.nan)
        while not self.done():
            chosen = self.choose_round(robots)
            if not chosen:
                break  # nowhere left to go
            for c in chosen:
                if self.done():
                    break
                self.observe(c.robot, c.qpos, c.gain)
        known = self.grid.entropy()[self.interest] < 0.5
        per_robot = {r.name: sum(v["robot"] == r.name for v in self.taken)
                     for r in self.scene.robots}
        stopped_by = ("threshold" if self.history[-1] < m.entropy_threshold_bits
                      else "max_views" if len(self.taken) >= m.max_views
                      else "no_reachable_view")
        return Survey(m.depth_source, m.strategy, m.gain, per_robot, self.history,
                      float(known.mean()), int(self.interest.sum()), stopped_by, self.taken,
                      time.perf_counter() - start)

    def done(self) -> bool:
        m = self.s.mapping
        return self.history[-1] < m.entropy_threshold_bits or len(self.taken) >= m.max_views

    def observe(self, robot: Robot, qpos: np.ndarray, gain: float) -> None:
        """Move ``robot`` to ``qpos``, measure depth and integrate it."""
        self.scene.set_robot(self.data, robot, qpos, self.world)
        if self.floor is not None:  # mapping's moves are made as planned: no errors yet
            scan_into(self.floor, self.world, self.data, self.data, [robot],
                      self.sensor.robot_geoms)
        depth = self.sensor.depth(self.data, robot)
        T = opencv_pose(camera_pose(self.data, robot.camera))
        integrate_depth(self.grid, depth, self.pinhole, T, self.s.grid.max_range_m,
                        self.s.mapping.pixel_stride)
        self.history.append(mean_entropy(self.grid, self.interest))
        self.taken.append({"robot": robot.name, "position": T[:3, 3].tolist(),
                           "axis": T[:3, 2].tolist(),
                           "gain": None if math.isnan(gain) else gain,
                           "region_entropy_bits": self.history[-1]})
        if self.on_view is not None:
            self.on_view(robot, T, gain, depth, self.history[-1])

    # ------------------------------------------------------------ choosing

    def choose_round(self, robots: tuple[Robot, ...]) -> list[_Chosen]:
        m = self.s.mapping
        model = gain_model(self.s, self.grid, self.pinhole, self.interest)
        chosen = []
        for robot in robots:
            options = self.candidates(robot)
            if not options:
                continue
            if m.strategy == "random":
                best, gain = int(self.rng.integers(len(options))), math.nan
            else:
                gains = model.gains([c.view for c in options], m.gain)
                score = gains / (1.0 + m.motion_weight * np.array([c.motion_m for c in options]))
                best = int(np.argmax(score))  # first best on ties
                gain = float(gains[best])
                if m.strategy == "cooperative":
                    model.expect(options[best].view)
            c = options[best]
            chosen.append(_Chosen(c.robot, c.qpos, gain))
        return chosen

    def candidates(self, robot: Robot) -> list[Candidate]:
        """Reachable, collision-free camera poses looking into the target region."""
        m, scene, data = self.s.mapping, self.scene, self.data
        here = data.qpos.copy()
        pan = self.world.joint(f"{robot.name}/shoulder_pan").id  # turns the arm's first link
        shoulder = data.xpos[self.world.jnt_bodyid[pan]].copy()
        camera_now = data.camera(robot.camera).xpos.copy()
        z_lo, z_hi = self.s.search.camera_z_m
        half = np.array(m.region_half_m)
        out = []
        for _ in range(m.candidates_per_robot):
            direction = self.rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            position = shoulder + self.rng.uniform(*REACH_M) * direction
            look_at = scene.primary.position + self.rng.uniform(-0.5, 0.5, 3) * half
            if not z_lo <= position[2] <= z_hi:
                continue
            ik = solve_camera_pose(scene.model, here, robot, look_at, position,
                                   move_base=False, settings=VIEW_IK)
            if ik.position_error_m > CLOSE_ENOUGH_M or ik.orientation_error_deg > 5.0:
                continue
            scene.set_robot(data, robot, ik.qpos, self.world)
            near = self.proximity[robot.name].measure(data)
            if near.others >= self.s.search.clearance_m and near.own > 0:
                T = opencv_pose(camera_pose(data, robot.camera))
                out.append(Candidate(robot, ik.qpos, View(T),
                                     float(np.linalg.norm(T[:3, 3] - camera_now))))
        scene.set_robot(data, robot, here, self.world)
        return out
