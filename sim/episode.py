"""One episode: scan from the start poses, map, place each camera, move there, look.

The stages, in order:
1. every robot looks from its start pose (base still, gaze by IK) at points around
   the primary target and integrates the rendered depth into the occupancy grid;
2. robot by robot, the rating function is searched over known-free voxels; the best
   candidates are tried in turn until one is reachable by IK (base and arm), keeps
   clear of everything, and sees its target with no geometry in the way;
3. the scene is re-rendered from the reached poses and each target is located in the
   image.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from calibration import locate_hole
from mapping import (
    OccupancyGrid,
    Pinhole,
    SensorModel,
    integrate_depth,
    opencv_pose,
    world_to_camera,
)
from placement import CameraModel, Region, TargetModel, Weights, search, target_points

from .ik import IKResult, solve_camera_pose
from .record import Recorder
from .render import Renderer, camera_pinhole, camera_pose
from .scenario import Scenario
from .scene import Robot, Scene, Target, build_scene

VERSION = "0.1.0"


class Timer:
    """Accumulates wall-clock seconds per stage."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.totals[stage] += time.perf_counter() - start


@dataclass
class Placement:
    """How one robot was placed."""

    robot: Robot
    target: Target | None = None
    commanded: np.ndarray | None = None
    rating: dict[str, float] = field(default_factory=dict)
    ik: IKResult | None = None
    candidates_tried: int = 0
    rejections: dict[str, int] = field(default_factory=lambda: defaultdict(int))


def pose_dict(data: mujoco.MjData, camera: str) -> dict[str, list[float]]:
    """World position and quaternion (w, x, y, z) of a named camera's MuJoCo frame."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.camera(camera).xmat)
    return {"position": data.camera(camera).xpos.tolist(), "quat_wxyz": quat.tolist()}


def target_model(t: Target) -> TargetModel:
    return TargetModel(t.name, t.position, t.normal, t.radius, t.st_error)


def new_grid(s: Scenario) -> OccupancyGrid:
    g = s.grid
    return OccupancyGrid.from_bounds(np.array(g.bounds_min), np.array(g.bounds_max),
                                     g.resolution_m,
                                     SensorModel(g.hit, g.miss, g.clamp_min, g.clamp_max))


def scan_points(target: np.ndarray, views: int, spread: float) -> np.ndarray:
    """Look-at points of the initial scan: the target, then a ring around it."""
    points = [target]
    for i in range(views - 1):
        a = 2 * math.pi * i / max(views - 1, 1)
        points.append(target + spread * np.array([math.cos(a), math.sin(a), 0.3 * (-1) ** i]))
    return np.array(points)


def _collision_geoms(model: mujoco.MjModel, bodies: frozenset[int]) -> list[int]:
    return [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies
            and (model.geom_contype[g] or model.geom_conaffinity[g])]


def clearance(model: mujoco.MjModel, data: mujoco.MjData, robot: Robot,
              limit: float = 1.0) -> tuple[float, float]:
    """Smallest distances (m), up to ``limit``: from the robot to any other collidable
    geometry but the floor, and between its own links that are not neighbours.
    Negative when penetrating."""
    own = _collision_geoms(model, robot.body_ids)
    floor = model.geom("floor").id
    others = [g for g in _collision_geoms(model, frozenset(range(model.nbody)) - robot.body_ids)
              if g != floor]
    fromto = np.zeros(6)
    to_others = to_self = limit
    for g in own:
        for h in others:
            to_others = min(to_others, mujoco.mj_geomDistance(model, data, g, h, limit, fromto))
    for i, g in enumerate(own):
        for h in own[i + 1:]:
            bg, bh = model.geom_bodyid[g], model.geom_bodyid[h]
            if bg == bh or model.body_parentid[bg] == bh or model.body_parentid[bh] == bg:
                continue
            to_self = min(to_self, mujoco.mj_geomDistance(model, data, g, h, limit, fromto))
    return float(to_others), float(to_self)


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


def find_target(rgb: np.ndarray, seg: np.ndarray, target: Target, target_geom: int,
                T_world_mjcam: np.ndarray, pinhole: Pinhole) -> dict[str, Any]:
    """Locate the target in the image by LoG and template matching, near where the camera
    pose puts it; the segmentation image says how much of it is really in view."""
    T = opencv_pose(T_world_mjcam)
    in_cam = world_to_camera(T, target.position[None])[0]
    visible_px = int((seg == target_geom).sum())
    if in_cam[2] <= 0:
        return {"seen": False, "pixel": None, "target_pixels": visible_px}
    expected = pinhole.project(in_cam[None])[0]
    tilt = max(float(target.normal @ (T[:3, 3] - target.position))
               / float(np.linalg.norm(T[:3, 3] - target.position)), 0.05)
    radius_px = pinhole.fy * target.radius / float(in_cam[2])
    full_area = math.pi * radius_px ** 2 * tilt
    found = locate_hole(rgb, (float(expected[0]), float(expected[1])),
                        radius_px * math.sqrt(tilt), search_px=max(3 * radius_px, 10.0))
    seen = found is not None and visible_px >= 0.5 * full_area
    return {"seen": seen,
            "pixel": None if found is None else [found.u, found.v],
            "expected_pixel": expected.tolist(),
            "detection_score": None if found is None else found.score,
            "target_pixels": visible_px, "expected_target_pixels": round(full_area, 1)}


class Episode:
    """Runs the stages of one episode on one scenario."""

    def __init__(self, scenario: Scenario) -> None:
        """Builds the scene: raises ScenarioError for geometry the scenario cannot hold."""
        self.s = scenario
        self.rng = np.random.default_rng(scenario.seed)
        self.timer = Timer()
        with self.timer("build"):
            self.scene: Scene = build_scene(scenario)
        self.model = self.scene.model
        self.data = self.scene.make_data()
        self.grid = new_grid(scenario)
        self.recorder = Recorder(None, "")
        self.step = 0
        cam = scenario.camera
        self.camera_model = CameraModel(math.radians(cam.fovy_deg), cam.height, cam.near_m,
                                        cam.far_m)

    # ------------------------------------------------------------ stages

    def scan(self) -> dict[str, Any]:
        """Stage 1: each robot looks around the target from its start pose; map the depth."""
        s, scene = self.s, self.scene
        points = scan_points(scene.primary.position, s.mapping.views_per_robot,
                             s.mapping.scan_spread_m)
        pinhole = camera_pinhole(self.model, scene.robots[0].camera)
        views = {}
        with Renderer(self.model, pinhole.width, pinhole.height) as renderer:
            for robot in scene.robots:
                taken = 0
                for look in points:
                    with self.timer("ik"):
                        ik = solve_camera_pose(self.model, self.data.qpos, robot, look,
                                               move_base=False)
                    self._set_robot(robot, ik.qpos)
                    with self.timer("render"):
                        depth = renderer.depth(self.data, robot.camera)
                    T = camera_pose(self.data, robot.camera)
                    with self.timer("mapping"):
                        integrate_depth(self.grid, depth, pinhole, opencv_pose(T),
                                        s.grid.max_range_m, s.mapping.pixel_stride)
                    self._tick()
                    self.recorder.camera(robot.name, T, pinhole, depth=depth)
                    taken += 1
                self._set_robot(robot, scene.start_qpos)
                views[robot.name] = taken
        self.recorder.grid(self.grid)
        p = self.grid.probability()
        return {"views": views, "known_free_fraction": float((p < s.rating.free_threshold).mean()),
                "occupied_fraction": float((p > 0.5).mean())}

    def place(self, robot: Robot, taken: list[np.ndarray]) -> Placement:
        """Stage 2 for one robot, given the camera positions already taken."""
        s = self.s
        targets = self.scene.targets
        keep_out = tuple((tuple(p), s.search.robot_separation_m) for p in taken)
        region = Region(s.search.camera_z_m[0], s.search.camera_z_m[1], keep_out)
        r = s.rating
        with self.timer("placement"):
            field_ = search(self.grid, [target_model(t) for t in targets], self.camera_model,
                            Weights(r.alpha, r.beta, r.gamma, r.delta), r.free_threshold,
                            r.occluding_threshold, region)
        self.recorder.candidates(robot.name, field_.ratings.positions, field_.ratings.total)
        result = Placement(robot)
        start = self.data.qpos.copy()
        for i in field_.ranked()[: s.search.ik_candidates]:
            result.candidates_tried += 1
            target = targets[int(field_.target[i])]
            position = field_.ratings.positions[i]
            with self.timer("ik"):
                ik = solve_camera_pose(self.model, start, robot, target.position, position,
                                       move_base=s.robots.move_base)
            if not ik.converged:
                result.rejections["unreachable"] += 1
                continue
            self._set_robot(robot, ik.qpos)
            to_others, to_self = clearance(self.model, self.data, robot)
            if to_others < s.search.clearance_m or to_self <= 0.0:
                result.rejections["collision"] += 1
                continue
            if blocked_rays(self.model, self.data, robot, target_points(target_model(target))):
                result.rejections["occluded"] += 1
                continue
            result.target, result.commanded, result.ik = target, position, ik
            result.rating = field_.ratings.terms(int(i))
            self.recorder.chosen(robot.name, position, target.position, target.name)
            return result
        self._set_robot(robot, start)
        return result

    def look(self, placements: list[Placement]) -> list[dict[str, Any]]:
        """Stage 3: render from the reached poses and find each target in the image."""
        pinhole = camera_pinhole(self.model, self.scene.robots[0].camera)
        rows = []
        with Renderer(self.model, pinhole.width, pinhole.height) as renderer:
            self._tick()
            for p in placements:
                robot = p.robot
                with self.timer("render"):
                    rgb = renderer.rgb(self.data, robot.camera)
                    depth = renderer.depth(self.data, robot.camera)
                    seg = renderer.segmentation(self.data, robot.camera)
                self.recorder.camera(robot.name, camera_pose(self.data, robot.camera), pinhole,
                                     rgb, depth)
                row: dict[str, Any] = {"name": robot.name, "camera": robot.camera,
                                       "placed": p.target is not None,
                                       "pose": pose_dict(self.data, robot.camera)}
                if p.target is not None and p.ik is not None and p.commanded is not None:
                    row.update({
                        "commanded_pose": {"position": p.commanded.tolist()},
                        "target": p.target.summary(),
                        "rating": p.rating,
                        "ik": p.ik.summary(),
                        **find_target(rgb, seg, p.target, self.model.geom(p.target.geom).id,
                                      camera_pose(self.data, robot.camera), pinhole),
                    })
                else:
                    row.update({"seen": False, "pixel": None})
                row["candidates_tried"] = p.candidates_tried
                row["rejections"] = dict(p.rejections)
                rows.append(row)
        return rows

    def run(self, recorder: Recorder | None = None) -> tuple[dict[str, Any], str]:
        """All stages; returns ``summary.json``'s content and the scene's MJCF."""
        t0 = time.perf_counter()
        if recorder is not None:
            self.recorder = recorder
        targets = self.scene.targets
        self.recorder.targets([t.name for t in targets], np.array([t.position for t in targets]),
                              [t.radius for t in targets])
        mapping = self.scan()
        placements: list[Placement] = []
        taken: list[np.ndarray] = []
        for robot in self.scene.robots:
            self._tick()
            p = self.place(robot, taken)
            placements.append(p)
            if p.commanded is not None:
                taken.append(p.commanded)
        robots = self.look(placements)
        xml = self.scene.to_xml(self.data.qpos.copy())
        self.timer.totals["total"] = time.perf_counter() - t0
        summary = {
            "version": VERSION, "scenario": self.s.name, "seed": self.s.seed,
            "robots": robots, "mapping": mapping,
            "timings_s": {k: round(v, 4) for k, v in self.timer.totals.items()},
        }
        return summary, xml

    # ------------------------------------------------------------ helpers

    def _set_robot(self, robot: Robot, qpos: np.ndarray) -> None:
        """Put one robot's joints at their values in ``qpos`` (a full configuration)."""
        self.data.qpos[robot.qpos_adr] = qpos[robot.qpos_adr]
        mujoco.mj_forward(self.model, self.data)

    def _tick(self) -> None:
        self.step += 1
        self.recorder.step(self.step)
