"""One episode: map cooperatively, place each camera, move there, look.

The stages, in order:
1. the robots map the target region into the occupancy grid, choosing views by
   expected information (sim/stages/exploration.py);
2. robot by robot, the rating function is searched over known-free voxels (the robots
   placed before count as occluders, at their commanded poses); the best candidates
   from which the hole detector can find the target (placement.detectable) are
   tried in turn until one is reachable by collision-avoiding IK (base and arm) along a
   path that keeps clear of everything, and sees its target with no geometry in the
   way; the robot then follows that path in physics, through its position actuators,
   with its positioning errors (sim/world/motion.py), before the next robot plans;
3. the scene is re-rendered from the reached poses and each target is located in the
   image.

Planning uses the nominal model and the commanded joints (``belief``); the simulated
world (``model``, ``data``) holds the truth, which only the evaluation reads.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from calibration import locate_hole
from calibration.pose import rotation_deg
from mapping import (
    GainModel,
    OccupancyGrid,
    Pinhole,
    SensorModel,
    opencv_pose,
    region_mask,
)
from placement import (
    CameraModel,
    Hull,
    RatingField,
    Region,
    SearchSettings,
    TargetModel,
    Weights,
    biased_random,
    detectable,
    information_gain,
    line_of_sight,
    search,
    target_points,
)
from sim.config.scenario import Scenario
from sim.stages.correction import ARM_REACH_M, Correction, PoseCorrector, prior_pose_sd
from sim.stages.exploration import Exploration, gain_model
from sim.stages.record import Recorder
from sim.stages.target_frame import Sighting, common_frame, in_measured_frame, projected_disk, sight
from sim.stages.task import Camera, InsertionTask, TaskResult
from sim.world.collision import blocked_rays, robot_points
from sim.world.ik import IKResult
from sim.world.motion import ErrorModel, MotionResult, Mover
from sim.world.optics import Lens
from sim.world.planning import ArmPlanner
from sim.world.render import Renderer, camera_pinhole, camera_pose
from sim.world.scene import Robot, Scene, Target, build_scene, yaw_quat
from sim.world.sensing import DepthSensor

VERSION = "0.1.0"
REJECTED_RADIUS_M = 0.08  # after a candidate fails, skip the ones this close to it
# A line of sight to a target is checked in the map up to this many voxels short of it:
# the plate around the hole fills the last voxels (about 3 along a line 70 deg oblique).
SIGHT_STOP_VOXELS = 3


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
    """One placement of one robot: the first (``step`` None) or a re-placement during the
    task; ``pose`` is where its camera truly was when the move ended (evaluation only)."""

    robot: Robot
    index: int = 0  # in the robot's placements
    step: int | None = None  # the task step of a re-placement
    reason: str = "initial"
    target: Target | None = None
    commanded: np.ndarray | None = None  # the candidate position (m)
    commanded_pose: np.ndarray | None = None  # the camera at the IK solution (4x4)
    pose: np.ndarray | None = None  # the camera's true pose after the move (4x4)
    rating: dict[str, float] = field(default_factory=dict)
    ik: IKResult | None = None
    motion: MotionResult | None = None
    correction: Correction | None = None
    strategy: str = "exhaustive"
    evaluated: int = 0  # candidates the search rated
    candidates_tried: int = 0  # of them, tried with IK
    undetectable: int = 0  # candidates skipped: the detector could not find the target
    rejections: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    unreachable: list[dict[str, Any]] = field(default_factory=list)  # residuals, first few

    @property
    def placed(self) -> bool:
        return self.target is not None

    def refused(self) -> str:
        """Why no candidate was taken (empty when placed)."""
        if self.placed:
            return ""
        if self.evaluated == 0:
            return "no known-free candidate in the robot's region"
        if self.candidates_tried == 0:
            return ("no candidate with a positive rating from which the detector can find "
                    f"the target ({self.undetectable} refused as undetectable)")
        why = ", ".join(f"{k} {v}" for k, v in sorted(self.rejections.items()))
        return f"every candidate tried was rejected ({why})"

    def summary(self) -> dict[str, Any]:
        """This placement's record in ``summary.json``'s ``placements``."""
        out: dict[str, Any] = {
            "index": self.index, "step": self.step, "reason": self.reason,
            "placed": self.placed,
            "search": {"strategy": self.strategy, "candidates_evaluated": self.evaluated,
                       "refused_undetectable": self.undetectable},
            "candidates_tried": self.candidates_tried, "rejections": dict(self.rejections),
            "unreachable": self.unreachable}
        if not self.placed:
            return {**out, "refused": self.refused()}
        assert (self.target is not None and self.commanded is not None and self.ik is not None
                and self.commanded_pose is not None and self.pose is not None)
        return {**out,
                "candidate_position": self.commanded.tolist(),
                "commanded_pose": pose_dict(self.commanded_pose),
                "pose": pose_dict(self.pose),
                "positioning_error": pose_error(self.commanded_pose, self.pose),
                "target": self.target.summary(), "rating": self.rating,
                "ik": self.ik.summary(),
                "motion": None if self.motion is None else self.motion.summary(),
                **correction_summary(self.correction, self.commanded_pose, self.pose)}


@dataclass(frozen=True)
class Snapshot:
    """What :meth:`Episode.restore` returns to."""

    qpos: np.ndarray
    ctrl: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    time: float
    grid: OccupancyGrid


def pose_dict(T: np.ndarray) -> dict[str, list[float]]:
    """World position and quaternion (w, x, y, z) of a pose (4x4)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, T[:3, :3].ravel())
    return {"position": T[:3, 3].tolist(), "quat_wxyz": quat.tolist()}


def pose_error(commanded: np.ndarray, achieved: np.ndarray) -> dict[str, float]:
    """Position (m) and rotation angle (deg) from a commanded camera pose to the achieved
    one (4x4 each)."""
    return {"position_m": float(np.linalg.norm(achieved[:3, 3] - commanded[:3, 3])),
            "orientation_deg": rotation_deg(commanded, achieved)}


def target_model(t: Target) -> TargetModel:
    return TargetModel(t.name, t.position, t.normal, t.radius, t.st_error)


def new_grid(s: Scenario) -> OccupancyGrid:
    g = s.grid
    return OccupancyGrid.from_bounds(np.array(g.bounds_min), np.array(g.bounds_max),
                                     g.resolution_m, SensorModel(*s.sensor()))


def find_target(rgb: np.ndarray, seg: np.ndarray, target: Target, target_geom: int,
                T_world_mjcam: np.ndarray, pinhole: Pinhole) -> dict[str, Any]:
    """Locate the target in the image by LoG and template matching, near where the camera
    pose puts it; the segmentation image says how much of it is really in view."""
    visible_px = int((seg == target_geom).sum())
    disk = projected_disk(target, opencv_pose(T_world_mjcam), pinhole)
    if disk is None:
        return {"seen": False, "pixel": None, "target_pixels": visible_px}
    expected, shape = disk
    full_area = math.pi * abs(float(np.linalg.det(shape)))
    radius_px = math.sqrt(full_area / math.pi)
    found = locate_hole(rgb, (float(expected[0]), float(expected[1])), radius_px,
                        search_px=max(3 * radius_px, 10.0), shape=shape)
    seen = found is not None and visible_px >= 0.5 * full_area
    return {"seen": seen,
            "pixel": None if found is None else [found.u, found.v],
            "expected_pixel": expected.tolist(),
            "detection_score": None if found is None else found.score,
            "target_pixels": visible_px, "expected_target_pixels": round(full_area, 1)}


def believed_pose(p: Placement) -> np.ndarray:
    """Where the robot believes its camera is: the correction's estimate unless it failed,
    else as commanded (4x4, MuJoCo camera convention)."""
    if p.correction is not None and p.correction.pose is not None:
        return p.correction.pose
    assert p.commanded_pose is not None, "only placed robots have a camera pose"
    return p.commanded_pose


def correction_summary(c: Correction | None, commanded: np.ndarray,
                       achieved: np.ndarray) -> dict[str, Any]:
    """The pose correction's outcome (``estimated_pose`` and ``correction``), with its
    error against the simulator's truth before (the commanded pose) and after."""
    if c is None:
        return {}
    out = {**c.summary(), "error_before": pose_error(commanded, achieved)}
    if c.pose is not None:
        out["error_after"] = pose_error(c.pose, achieved)
    if c.bundle_pose is not None:
        out["bundle_error"] = pose_error(c.bundle_pose, achieved)
    out["other_estimators_error"] = {m: pose_error(T, achieved) for m, T in c.others.items()}
    estimated = {} if c.pose is None else {"estimated_pose": pose_dict(c.pose)}
    return {**estimated, "correction": out}


class Episode:
    """Runs the stages of one episode on one scenario."""

    def __init__(self, scenario: Scenario) -> None:
        """Builds the scene: raises ScenarioError for geometry the scenario cannot hold."""
        self.s = scenario
        self.rng = np.random.default_rng(scenario.seed)
        self.timer = Timer()
        with self.timer("build"):
            self.scene: Scene = build_scene(scenario)
        self.nominal = self.scene.model  # what the planner knows
        self.model = copy.deepcopy(self.nominal)  # the simulated world: errors go here
        self.workpiece_error = self._misplace_workpiece()
        self.data = self.scene.make_data()
        self.belief = self.scene.make_data()  # the commanded configuration
        self.errors = ErrorModel(scenario.motion, self.scene.robots, self.rng)
        self.mover = Mover(self.model, self.data, self.scene.robots, scenario.motion)
        self.grid = new_grid(scenario)
        self.recorder = Recorder(None, "")
        self.corrector: PoseCorrector | None = None  # with a renderer, in run()
        self.sightings: list[Sighting] = []  # of the targets, by the placed cameras
        self.targets: tuple[Target, ...] = self.scene.targets  # the ones placement may use
        self._fields: dict[tuple[object, ...], RatingField] = {}  # searched, by question
        self._grid_hulls: dict[tuple[object, ...], dict[tuple[float, ...], list[Hull]]] = {}
        self.pinhole = camera_pinhole(self.model, self.scene.robots[0].camera)
        self.step = 0
        self.prior_sd = prior_pose_sd(scenario.motion)  # of a camera pose not corrected
        self.look_state = self.world_state()  # the world when the targets were looked for
        self.look_bodies = self.world_bodies()  # ... and its bodies that keyframes cannot hold
        # where each robot that has moved believes its camera rests (MuJoCo convention) and
        # that belief's standard deviation (m, deg): the next correction starts from it
        self.at_rest: dict[str, tuple[np.ndarray, tuple[float, float]]] = {}
        cam = scenario.camera
        self.camera_model = CameraModel(math.radians(cam.fovy_deg), cam.height, cam.near_m,
                                        cam.far_m)

    # ------------------------------------------------------------ stages

    def map(self, renderer: Renderer) -> dict[str, Any]:
        """Stage 1: cooperative mapping by expected information (sim/stages/exploration.py)."""
        s = self.s
        sensor = DepthSensor(renderer, self.pinhole, s.mapping.depth_source, s.camera.baseline_m,
                             self.scene.robot_geoms())

        def on_view(robot: Robot, T: np.ndarray, gain: float, depth: np.ndarray) -> None:
            self._tick()
            self.recorder.camera(robot.name, camera_pose(self.data, robot.camera),
                                 self.pinhole, depth=depth)
            self.recorder.view(robot.name, T, self.pinhole, s.camera.far_m, gain)

        with self.timer("mapping"):
            summary = Exploration(self.scene, self.data, self.grid, sensor, self.pinhole,
                                  self.rng, on_view, self.model).run()
        self.recorder.grid(self.grid)
        return summary

    def place(self, robot: Robot, taken: list[np.ndarray], index: int = 0,
              step: int | None = None, reason: str = "initial") -> Placement:
        """Stage 2 for one robot, given the camera positions already taken: search, plan,
        and move there in the world. ``index``, ``step`` and ``reason`` say which of the
        robot's placements this is (a re-placement during the task has a step)."""
        s = self.s
        targets = self.targets
        belief = self.belief
        keep_out = tuple((tuple(p), s.search.robot_separation_m) for p in taken)
        base = belief.qpos[robot.qpos_adr[:2]]
        region = Region(s.search.camera_z_m[0], s.search.camera_z_m[1], keep_out,
                        ((float(base[0]), float(base[1])), s.search.reach_m))
        r, q = s.rating, s.search
        settings = SearchSettings(q.strategy, q.coarse_step, q.max_distance_m, q.samples,
                                  r.unknown_occludes, r.hull_block,
                                  directions=r.tfv_directions, cone=r.expansion == "cone")
        others = [pts for other in self.scene.robots if other is not robot
                  for pts in robot_points(self.nominal, belief, other)]
        # The same question gets the same answer: methods started from one mapped state
        # share their first robot's rating field (a deterministic search draws nothing),
        # and every search of one map its occluders' hulls.
        grid_key = (hashlib.sha1(self.grid.log_odds.tobytes()).hexdigest(),
                    settings.unknown_occludes, settings.block)
        key = (robot.name, tuple(t.name for t in targets), keep_out, belief.qpos.tobytes(),
               grid_key)
        field_ = self._fields.get(key) if q.strategy != "random" else None
        if field_ is None:
            with self.timer("placement"):
                field_ = search(self.grid, [target_model(t) for t in targets],
                                self.camera_model, Weights(r.alpha, r.beta, r.gamma, r.delta),
                                r.free_threshold, region, settings, self.rng, others,
                                self._grid_hulls.setdefault(grid_key, {}))
            self._fields[key] = field_
        if q.method == "biased_random":
            field_ = biased_random(field_, [target_model(t) for t in targets], self.camera_model,
                                   self.rng, q.random_max_angle_deg)
        elif q.method == "information_gain":
            primary = self.scene.primary
            with self.timer("placement"):
                field_ = information_gain(field_, targets.index(primary), primary.position,
                                          self._gain_model(), self.rng, q.gain_samples)
        self.recorder.candidates(robot.name, field_.ratings.positions, field_.ratings.total)
        result = Placement(robot, index, step, reason, strategy=field_.strategy,
                           evaluated=field_.evaluated)
        start = belief.qpos.copy()
        planner = ArmPlanner(self.scene, belief, q.clearance_m,
                             q.clearance_m + s.motion.ik_margin_m, s.robots.move_base)
        rejected: list[np.ndarray] = []
        for i in field_.ranked():
            if result.candidates_tried >= s.search.ik_candidates:
                break
            target = targets[int(field_.target[i])]
            position = field_.ratings.positions[i]
            if any(np.linalg.norm(position - p) < REJECTED_RADIUS_M for p in rejected):
                continue  # next to a candidate that failed: try somewhere else
            if not detectable(position[None], target_model(target), self.camera_model,
                              baseline_m=s.camera.baseline_m)[0]:
                result.undetectable += 1  # too far or too oblique for the hole detector
                continue  # (in either stereo image: sightings need both)
            result.candidates_tried += 1
            rejected.append(position)
            with self.timer("ik"):
                plan = planner.plan(robot, target.position, position)
            why = plan.reason
            if why is None and q.check_sight and blocked_rays(
                    self.nominal, belief, robot, target_points(target_model(target))):
                why = "occluded"
                self._set_belief(robot, start)
            if why is not None:
                result.rejections[why] += 1
                if why == "unreachable" and len(result.unreachable) < 5:
                    result.unreachable.append({
                        "position": position.round(4).tolist(),
                        "position_error_m": round(plan.ik.position_error_m, 5),
                        "orientation_error_deg": round(plan.ik.orientation_error_deg, 4)})
                continue
            ik = plan.ik
            result.target, result.commanded, result.ik = target, position, ik
            result.commanded_pose = camera_pose(belief, robot.camera)
            result.rating = field_.ratings.terms(int(i))
            self.recorder.chosen(robot.name, position, target.position, target.name)
            self.recorder.hulls(robot.name, field_.hulls[target.name])
            result.motion, result.correction = self._move(robot, ik.path)
            result.pose = camera_pose(self.data, robot.camera)
            return result
        return result

    def _move(self, robot: Robot, path: np.ndarray) -> tuple[MotionResult, Correction | None]:
        """Follow the path in the world, logging the robot and, with correction on,
        taking the frames the camera's pose is corrected from at the end."""
        links = sorted(robot.body_ids)
        corrector = self.corrector
        frames: Callable[[float, np.ndarray], None] | None = None
        if corrector is not None:
            with self.timer("correction"):
                corrector.begin(robot, path[0], self.at_rest.get(robot.name))
            frames = corrector.on_sample(robot)

        framing = 0.0  # wall time (s) spent on frames during the move

        def on_sample(t: float, measured: np.ndarray) -> None:
            nonlocal framing
            self.recorder.motion(robot.name, t, self.data.xpos[links],
                                 camera_pose(self.data, robot.camera))
            if frames is not None:
                start = time.perf_counter()
                frames(t, measured)
                framing += time.perf_counter() - start

        error = self.errors.draw(robot)
        with self.timer("motion"):
            motion = self.mover.follow(robot, path, error, on_sample)
        if corrector is None:
            self.timer.totals["motion"] -= framing
            self.timer.totals["correction"] += framing
            return motion, None
        with self.timer("correction"):
            correction = corrector.finish(robot, last_try=len(path) < 2)
        if correction.retrace_from is not None:  # back to where a frame was located, and forth
            again = corrector.retrace(path, correction.retrace_from)
            with self.timer("motion"):
                self.mover.follow(robot, again, error, on_sample)
            with self.timer("correction"):
                correction = corrector.finish(robot)
        believed = (correction.pose if correction.pose is not None
                    else camera_pose(self.belief, robot.camera))
        self.at_rest[robot.name] = (believed, correction.believed_sd(self.prior_sd))
        self.timer.totals["motion"] -= framing
        self.timer.totals["correction"] += framing
        self.recorder.fiducials(robot.name, correction)
        return motion, correction

    def look(self, placements: list[Placement], renderer: Renderer) -> dict[str, dict[str, Any]]:
        """Stage 3: render from the reached poses and find each target in the image; per
        robot, what it saw (``seen``, ``pixel``, ``sightings``) and from which of its
        placements. The world as it is now is kept for ``scene.xml``'s keyframe ``look``."""
        pinhole = self.pinhole
        rows: dict[str, dict[str, Any]] = {}
        self.sightings = []
        self.look_state, self.look_bodies = self.world_state(), self.world_bodies()
        self._tick()
        for p in placements:
            robot = p.robot
            with self.timer("render"):
                rgb, depth = renderer.rgb_and_depth(self.data, robot.camera)
                right = renderer.rgb(self.data, robot.right_camera)
                seg = renderer.segmentation(self.data, robot.camera)
            achieved = camera_pose(self.data, robot.camera)  # the truth, for evaluation
            self.recorder.camera(robot.name, achieved, pinhole, rgb, depth)
            row: dict[str, Any] = {"seen": False, "pixel": None, "seen_from_placement": p.index}
            if p.target is not None:
                row.update(find_target(rgb, seg, p.target, self.model.geom(p.target.geom).id,
                                       achieved, pinhole))
                row["sightings"] = self._sight(robot, rgb, right, p)
            rows[robot.name] = row
        return rows

    def _sight(self, robot: Robot, left: np.ndarray, right: np.ndarray, p: Placement
               ) -> list[dict[str, Any]]:
        """Every target the camera finds in stereo, placed through its believed pose (the
        corrected one, else the commanded one), with that pose's uncertainty carried to
        the target."""
        rows: list[dict[str, Any]] = []
        if p.commanded_pose is None:
            return rows
        believed = believed_pose(p)
        position_sd, rotation_sd = self.believed_sd(p)
        hidden = self._hidden_in_map(believed[:3, 3])
        for t in self.targets:
            if hidden[t.name]:
                continue  # whatever is seen there, it is not the target
            found = sight(robot.name, left, right, t, believed, self.pinhole,
                          self.s.camera.baseline_m,
                          position_sd_m=math.hypot(position_sd, self.target_sd(t)),
                          rotation_sd_deg=rotation_sd,
                          others=tuple(o for o in self.targets if o is not t))
            if found is not None:
                reach = float(np.linalg.norm(found.position - believed[:3, 3]))
                pose_sd = math.hypot(position_sd, reach * math.radians(rotation_sd))
                found = dataclasses.replace(found, sd_m=pose_sd,
                                            placement=p.index,
                                            pose_status=self.pose_status(p))
                self.sightings.append(found)
                rows.append(found.summary(t.position))
        return rows

    def _hidden_in_map(self, camera: np.ndarray) -> dict[str, bool]:
        """Per target, whether the map has seen something occupied (a voxel at the
        probability one hit gives, or above) on the line from ``camera`` (world, m) to it.
        A camera outside the map's bounds has no evidence."""
        g = self.grid
        if not g.inside(g.index(camera[None]))[0]:
            return {t.name: False for t in self.targets}
        points = np.array([t.position for t in self.targets])
        seen = line_of_sight(g, camera, points, stop_short=SIGHT_STOP_VOXELS * g.resolution,
                             blocked=g.probability() >= g.model.hit)[0]
        inside = g.inside(g.index(points))
        return {t.name: bool(i and not v) for t, i, v in zip(self.targets, inside, seen,
                                                           strict=True)}

    def target_sd(self, t: Target) -> float:
        """Standard deviation (m, root of the covariance's trace) of a target's true place
        about its nominal one: the work-piece's misplacement, x and y, and its yaw error
        swinging the target about the work-piece's origin."""
        w = self.s.workpiece
        lever = float(np.linalg.norm(t.position[:2] - np.asarray(w.position, float)))
        return math.sqrt(2 * w.position_error_m ** 2
                         + (lever * math.radians(w.yaw_error_deg)) ** 2)

    def believed_sd(self, p: Placement) -> tuple[float, float]:
        """Standard deviation of the robot's believed camera pose: position (m), rotation
        (deg)."""
        return self.prior_sd if p.correction is None else p.correction.believed_sd(self.prior_sd)

    def pose_status(self, p: Placement) -> str:
        """``corrected``, ``uncertain`` or ``failed`` (see Correction.status), or ``as
        commanded`` with correction off."""
        return "as commanded" if p.correction is None else p.correction.status

    def world_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The world's joints and mocap bodies (positions, quaternions) as they are now,
        its poses brought up to them (after a physics step they lag by that step)."""
        d = self.data
        mujoco.mj_forward(self.model, d)
        return d.qpos.copy(), d.mocap_pos.copy(), d.mocap_quat.copy()

    def run(self, recorder: Recorder | None = None
            ) -> tuple[dict[str, Any], dict[str, tuple[str, dict[str, bytes]]]]:
        """All stages; returns ``summary.json``'s content and the scenes to save, by file
        name (their MJCF and the files it reads): ``scene.xml``, the world as it ended
        (keyframes ``start`` and ``final``), and ``look.xml``, the world when the targets
        were looked for (keyframe ``look``; the arms' mounts tilted as they were then)."""
        t0 = time.perf_counter()
        if recorder is not None:
            self.recorder = recorder
        targets = self.scene.targets
        self.recorder.targets([t.name for t in targets], np.array([t.position for t in targets]),
                              [t.radius for t in targets])
        with Renderer(self.model, self.pinhole.width, self.pinhole.height) as renderer:
            mapping = self.map(renderer)
            self.hold()
            robots, frame, task = self.place_and_do(renderer)
        scenes = {"scene.xml": self.scene.to_xml({"final": self.world_state()},
                                                 self.world_bodies()),
                  "look.xml": self.scene.to_xml({"look": self.look_state}, self.look_bodies)}
        self.timer.totals["total"] = time.perf_counter() - t0
        summary = {
            "version": VERSION, "scenario": self.s.name, "seed": self.s.seed,
            "robots": robots, "mapping": mapping, "target_frame": frame, "task": task,
            "timings_s": {k: round(v, 4) for k, v in self.timer.totals.items()},
        }
        return summary, scenes

    def place_and_do(self, renderer: Renderer
                     ) -> tuple[list[dict[str, Any]], dict[str, Any], dict[str, Any] | None]:
        """Stages 2-4 on the mapped scene: place every robot in turn, look, and do the
        task; returns ``summary.json``'s ``robots``, ``target_frame`` and ``task``."""
        self.corrector = None
        if self.s.correction.enabled:
            self.corrector = PoseCorrector(self.scene, self.belief, self.data, renderer,
                                           self.pinhole, self.s.camera.baseline_m,
                                           self.grid, self.s.correction)
        placements: dict[str, list[Placement]] = {}
        taken: list[np.ndarray] = []
        for robot in self.scene.robots:
            self._tick()
            p = self.place(robot, taken)
            placements[robot.name] = [p]
            if p.commanded is not None:
                taken.append(p.commanded)
        looks = self.look([h[0] for h in placements.values()], renderer)
        frame = common_frame(self.sightings, self.targets)
        task = None
        if self.s.task.enabled:
            with self.timer("task"):
                task = self.task(placements, frame, renderer).summary()
        return [self.robot_summary(h, looks[name]) for name, h in placements.items()], frame, task

    def robot_summary(self, placements: list[Placement], look: dict[str, Any]
                      ) -> dict[str, Any]:
        """``summary.json``'s record of one robot: where its camera ended (``pose``, the
        truth, as in ``scene.xml``'s keyframe ``final``) and the placement it ended at,
        every placement in order, and what it saw from the placement it looked from."""
        robot = placements[0].robot
        mujoco.mj_forward(self.model, self.data)  # poses where the joints now are
        final = camera_pose(self.data, robot.camera)
        ended = next((p for p in reversed(placements) if p.placed), None)
        current = (ended or placements[-1]).summary()
        for key in ("index", "step", "reason", "pose"):
            current.pop(key, None)
        if ended is not None and ended.commanded_pose is not None:
            current["positioning_error"] = pose_error(ended.commanded_pose, final)
        return {"name": robot.name, "camera": robot.camera, **current,
                "placed": ended is not None, "pose": pose_dict(final),
                "placement": None if ended is None else ended.index,
                **look, "placements": [p.summary() for p in placements]}

    def task(self, placements: dict[str, list[Placement]], frame: dict[str, Any],
             renderer: Renderer) -> TaskResult:
        """Stage 4: guide the panel into its slot with the placed cameras (sim/stages/task.py);
        a camera that keeps losing the panel is placed again on the updated map. Not
        attempted when no camera located the primary target: there is no slot to go to."""
        s = self.s
        current = {name: next((p for p in reversed(h) if p.placed), h[0])
                   for name, h in placements.items()}
        cameras = [self._camera(p) for p in current.values() if p.placed]
        lens = Lens(s.camera.near_m, s.camera.far_m, s.camera.coc_px)
        run = InsertionTask(self.scene, self.model, self.data, renderer, self.pinhole,
                            s.camera.baseline_m, lens, self.grid, s.task, self.rng,
                            self.recorder)
        if frame.get("frame") is None:
            return run.not_attempted(cameras, "no camera located the primary target")
        slot = in_measured_frame(self.nominal_slot(), self.targets, frame)

        def replace(cam: Camera, step: int) -> dict[str, Any] | None:
            if not s.task.replace:
                return None
            history = placements[cam.robot.name]
            others = [p.commanded for name, p in current.items()
                      if name != cam.robot.name and p.commanded is not None]
            reason = f"lost the panel {cam.lost_in_a_row} steps running"
            again = self.place(cam.robot, others, len(history), step, reason)
            history.append(again)
            record: dict[str, Any] = {"step": step, "robot": cam.robot.name, "reason": reason,
                                      "placed": again.placed, "placement": again.index}
            if again.placed:
                current[cam.robot.name] = again
                fresh = self._camera(again)
                cam.believed, cam.pose_sd_m, cam.pose_status = (
                    fresh.believed, fresh.pose_sd_m, fresh.pose_status)
            return record

        return run.run(cameras, slot, replace,
                       sorted({s.robot for s in self.sightings
                               if s.target == self.scene.primary.name}))

    def _camera(self, p: Placement) -> Camera:
        """A placed camera as the task knows it: believed pose, its uncertainty and status."""
        position_sd, rotation_sd = self.believed_sd(p)
        return Camera(p.robot, believed_pose(p),
                      math.hypot(position_sd, ARM_REACH_M * math.radians(rotation_sd)),
                      self.pose_status(p))

    def nominal_slot(self) -> np.ndarray:
        """The slot's place in the work-piece's CAD model (world, m)."""
        return np.array(self.belief.site("workpiece/slot").xpos)

    # ------------------------------------------------------------ helpers

    def _misplace_workpiece(self) -> np.ndarray:
        """Move the work-piece in the world off where the planner believes it (by the
        scenario's errors); returns (dx, dy, dyaw) in m, m, rad."""
        w = self.s.workpiece
        if w.position_error_m == 0 and w.yaw_error_deg == 0:
            return np.zeros(3)
        dx, dy = self.rng.normal(0.0, w.position_error_m, 2)
        dyaw = math.radians(float(self.rng.normal(0.0, w.yaw_error_deg)))
        body = self.model.body("workpiece/workpiece").id
        self.model.body_pos[body, :2] += (dx, dy)
        self.model.body_quat[body] = yaw_quat(math.radians(w.yaw_deg) + dyaw)
        return np.array([dx, dy, dyaw])

    def world_bodies(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Bodies where the world has them, not the plan (pos, quat relative to their
        parent frame in the scene's spec): the arms' mounts and the work-piece."""
        bodies = self.mover.mount_overrides()
        dx, dy, dyaw = self.workpiece_error
        if dx or dy or dyaw:
            back = -math.radians(self.s.workpiece.yaw_deg)  # into the work-piece's frame
            c, s = math.cos(back), math.sin(back)
            bodies["workpiece/workpiece"] = (np.array([c * dx - s * dy, s * dx + c * dy, 0.0]),
                                   np.array(yaw_quat(dyaw)))
        return bodies

    def _gain_model(self) -> GainModel:
        """Expected information about the target region, as mapping measures it."""
        interest = region_mask(self.grid, self.scene.primary.position,
                               np.array(self.s.mapping.region_half_m))
        return gain_model(self.s, self.grid, self.pinhole, interest)

    def hold(self) -> None:
        """After mapping's kinematic moves: the actuators hold where the robots are, and
        the planner knows it (no error has been made yet)."""
        self.data.ctrl[:] = self.scene.ctrl_for(self.data.qpos)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.belief.qpos[:] = self.data.qpos
        mujoco.mj_forward(self.nominal, self.belief)

    def snapshot(self) -> Snapshot:
        """The world, the plan and the map as they are now (after mapping, say), for
        :meth:`restore` to start another method from."""
        d = self.data
        return Snapshot(d.qpos.copy(), d.ctrl.copy(), d.mocap_pos.copy(), d.mocap_quat.copy(),
                        float(d.time), copy.deepcopy(self.grid))

    def restore(self, snap: Snapshot, rng: np.random.Generator) -> None:
        """Back to ``snap``, at rest, drawing from ``rng`` from now on (the robots'
        calibration errors are drawn afresh from it)."""
        d = self.data
        d.qpos[:], d.ctrl[:], d.time = snap.qpos, snap.ctrl, snap.time
        d.mocap_pos[:], d.mocap_quat[:] = snap.mocap_pos, snap.mocap_quat
        d.qvel[:] = 0.0
        d.act[:] = 0.0
        self.mover.reset()
        self.at_rest = {}
        mujoco.mj_forward(self.model, d)
        self.belief.qpos[:] = snap.qpos
        mujoco.mj_forward(self.nominal, self.belief)
        self.grid = copy.deepcopy(snap.grid)
        self.rng = rng
        self.errors = ErrorModel(self.s.motion, self.scene.robots, rng)
        self.sightings = []

    def _set_belief(self, robot: Robot, qpos: np.ndarray) -> None:
        self.scene.set_robot(self.belief, robot, qpos)

    def _tick(self) -> None:
        self.step += 1
        self.recorder.step(self.step)
