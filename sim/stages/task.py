"""The visually guided insertion task (sec. 3): the placed cameras guide the panel into
its slot, and success is judged from where it really ends.

1. **Carry.** The panel (a mocap body: carried kinematically) goes open-loop from where
   it lies to a point ``approach_m`` above its slot, arriving ``carry_error_m`` off.
2. **Measure.** Every placed camera renders its stereo pair through its lens (defocus
   from the circle of confusion of each pixel's depth, sim/world/optics.py); stereo matching
   gives depth; the panel's pixels are found by their colour (the hull of its yellow
   squares) and carried into the world through the camera's corrected pose; the panel's
   CAD model is fitted to the points of all cameras together, or, if they disagree,
   of the best camera alone (mapping/cad.py). A step where no camera sees enough of
   the panel, or the fit is poor, is a failed measurement: the panel waits, nothing is
   guessed. Only the pixels this uses are rendered: around the panel's silhouette in
   a coarse segmentation (the whole image when the panel reaches that window's edge),
   and the right camera's window through its part of the frustum.
3. **Update the map.** Each fitted pose moves the panel's voxels in the map, from its
   last fitted pose to the new one (sec. 3, steps 1-4), without remapping.
4. **Steer.** The slot's place comes from the common target frame the cameras measured
   (its offset from the targets is known from the work-piece's CAD model). The panel is
   moved by ``gain`` of the measured displacement (at most ``max_step_m``), staying
   ``approach_m`` above the slot until it is over it (then it goes down, and is not
   lifted again); each move errs by ``step_scale`` and ``step_noise_m``.
5. **Re-place.** A camera that fails ``lost_limit`` steps running may be re-placed: the
   rating function is searched again on the updated map (the episode does it).

It stops when the measured displacement is below ``stop_m``, after ``max_steps``, or
when no camera can see the panel any more. Success for each tolerance (a fraction of
the panel's size) is judged on the true final displacement. With no target frame
measured (no camera located the primary target) the task is not attempted and fails
every tolerance: there is no measured slot to guide to.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import mujoco
import numpy as np

from mapping import BoxModel, OccupancyGrid, Pinhole, fit_model, move_object, opencv_pose
from mapping.cad import to_object
from mapping.stereo import StereoSettings, stereo_depth
from sim.config.scenario import TaskConfig
from sim.stages.record import Recorder
from sim.world.optics import Lens, defocus
from sim.world.render import Renderer
from sim.world.scene import Robot, Scene

MIN_POINTS = 150  # panel points a measurement needs, over all cameras
# A fit is good when half the points are this close to it and this many within 1 cm,
# for the default camera (640 x 480, 60 deg: fx 416 px); stereo depth noise, and so the
# first bound, grows as 1 / fx for smaller images.
MAX_FIT_MEDIAN_M = 0.004
MIN_ON_MODEL = 0.6
# A fit this many times that far off after its coarse stage is not refined: in six scenes
# the 260 good fits of 324 were at most 7.7 mm off after it, and no finer stage turned
# a fit from 16 mm to good (docs/benchmarks.md).
GIVE_UP_FACTOR = 4.0
REFERENCE_FX_PX = 415.7
MAX_POINTS_PER_CAMERA = 3000
STEP_S = 1.0  # simulated time per steering step, for the recording
OVER_SLOT_M = 0.005  # the panel descends once measured this close above the slot (m)
BLUR_MARGIN_PX = 48  # blurred around the panel: 3 sigma of the widest blur level and more
SETTINGS = StereoSettings()
# Where the panel is in a view comes from a segmentation at 1/COARSE of the resolution;
# only the pixels measuring uses around it are then rendered in full.
COARSE = 2


TRUSTED = ("corrected", "as commanded")  # pose statuses measured with at full weight


@dataclass
class Camera:
    """A placed camera: its robot, believed pose (4x4, MuJoCo camera convention), that
    pose's uncertainty (m, at a metre) and status (``corrected``, ``uncertain``,
    ``failed``: not corrected, or ``as commanded`` with correction off)."""

    robot: Robot
    believed: np.ndarray
    pose_sd_m: float = 0.0
    pose_status: str = "as commanded"
    lost_in_a_row: int = 0

    @property
    def trusted(self) -> bool:
        return self.pose_status in TRUSTED


@dataclass
class TaskResult:
    """What happened; ``summary()`` is ``summary.json``'s ``task``."""

    size_m: float
    tolerances: tuple[float, ...]
    attempted: bool = True  # False: no slot to guide to (the target was not located)
    frame_robots: list[str] = field(default_factory=list)  # whose sightings placed the slot
    cameras: list[dict[str, Any]] = field(default_factory=list)  # robot, pose status, sd
    final_displacement: np.ndarray | None = None  # true, panel minus slot (m)
    measured_displacement: np.ndarray | None = None  # the last measurement's
    steps: int = 0
    measurements: int = 0
    failed: list[dict[str, Any]] = field(default_factory=list)  # step, reason per camera
    lost_views: int = 0
    replacements: list[dict[str, Any]] = field(default_factory=list)
    stopped_by: str = ""
    voxels_freed: int = 0
    voxels_occupied: int = 0

    def success(self) -> dict[str, bool]:
        error = (np.inf if self.final_displacement is None or not self.attempted
                 else float(np.linalg.norm(self.final_displacement)))
        return {f"{t:g}": error <= t * self.size_m for t in self.tolerances}

    def summary(self) -> dict[str, Any]:
        final, measured = self.final_displacement, self.measured_displacement

        def norm(v: np.ndarray | None) -> float | None:
            return None if v is None else round(float(np.linalg.norm(v)), 6)

        return {
            "attempted": self.attempted,
            "target_frame": {"measured": bool(self.frame_robots), "robots": self.frame_robots},
            "cameras": self.cameras,
            "object_size_m": self.size_m,
            "final_displacement": None if final is None else final.round(5).tolist(),
            "final_displacement_m": norm(final), "measured_displacement_m": norm(measured),
            "success": self.success(), "steps": self.steps,
            "measurements": self.measurements, "failed_measurements": len(self.failed),
            "lost_views": self.lost_views, "replacements": self.replacements,
            "stopped_by": self.stopped_by, "failures": self.failed[:10],
            "map_update": {"voxels_freed": self.voxels_freed,
                           "voxels_occupied": self.voxels_occupied}}


def panel_model(model: mujoco.MjModel) -> BoxModel:
    """The panel's CAD model (its box geoms, in its body frame)."""
    body = model.body("panel/panel").id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
             and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    return BoxModel(model.geom_pos[geoms].copy(), model.geom_size[geoms].copy())


def _window(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    """Rows and columns within ``margin`` pixels of ``mask``'s pixels."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    return (slice(max(0, ys.min() - margin), min(h, ys.max() + margin + 1)),
            slice(max(0, xs.min() - margin), min(w, xs.max() + margin + 1)))


def _measuring_window(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    """:func:`_window`, with the stereo's disparity range in front (left) of it."""
    rows, cols = _window(mask, margin)
    return rows, slice(max(0, cols.start - SETTINGS.num_disparities), cols.stop)


def panel_mask(rgb: np.ndarray) -> np.ndarray:
    """The panel's pixels: the convex hull of its yellow squares (largest blob)."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    yellow = cv2.inRange(hsv, (20, 100, 50), (38, 255, 255))  # not the orange bases (17)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        cv2.morphologyEx(yellow, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)))
    mask = np.zeros(rgb.shape[:2], np.uint8)
    if count <= 1:
        return mask.astype(bool)
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    ys, xs = np.nonzero(labels == biggest)
    hull = cv2.convexHull(np.column_stack([xs, ys]).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1)
    return cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)  # off its outline


class InsertionTask:
    """Runs the task in the world ``data`` with the placed cameras."""

    def __init__(self, scene: Scene, world: mujoco.MjModel, data: mujoco.MjData,
                 renderer: Renderer,
                 pinhole: Pinhole, baseline_m: float, lens: Lens, grid: OccupancyGrid,
                 cfg: TaskConfig, rng: np.random.Generator, recorder: Recorder) -> None:
        self.world, self.data, self.renderer, self.pinhole = world, data, renderer, pinhole
        self.baseline_m, self.lens, self.grid, self.cfg = baseline_m, lens, grid, cfg
        self.noise_scale = max(1.0, REFERENCE_FX_PX / pinhole.fx)
        self.rng, self.recorder = rng, recorder
        m = scene.model
        self.model = panel_model(m)  # the CAD model: the nominal one
        self.mocap = int(m.body_mocapid[m.body("panel/panel").id])
        self.panel_geom = m.geom("panel/panel").id
        self.slot_site = m.site("workpiece/slot").id

    # ------------------------------------------------------------ the world

    @property
    def panel(self) -> np.ndarray:
        """The panel's true pose (4x4): its bottom edge's centre and orientation."""
        T = np.eye(4)
        quat = self.data.mocap_quat[self.mocap]
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, quat)
        T[:3, :3] = mat.reshape(3, 3)
        T[:3, 3] = self.data.mocap_pos[self.mocap]
        return T

    def _move_panel(self, position: np.ndarray) -> None:
        self.data.mocap_pos[self.mocap] = position
        mujoco.mj_forward(self.world, self.data)

    # ------------------------------------------------------------ measuring

    def measure(self, cameras: list[Camera], guess: np.ndarray
                ) -> tuple[np.ndarray | None, dict[str, str]]:
        """The panel's pose fitted to what the cameras see (None if they cannot), and why
        each camera that contributed nothing failed. The points of every camera whose pose
        is trusted (corrected, or as commanded with correction off) are fitted together
        (all cameras' if none is); if the CAD model fits them poorly, each camera's alone
        (trusted ones first, then most points first), and the first good fit is taken:
        one poor view, or one uncorrected pose, does not spoil another."""
        seen: dict[str, np.ndarray] = {}
        eyes: dict[str, np.ndarray] = {}
        why: dict[str, str] = {}
        for cam in cameras:
            found = self._panel_points(cam)
            if isinstance(found, str):
                why[cam.robot.name] = found
            else:
                seen[cam.robot.name] = found
                eyes[cam.robot.name] = np.repeat(cam.believed[None, :3, 3], len(found), axis=0)
        trusted = {c.robot.name for c in cameras if c.trusted}
        together = [n for n in seen if n in trusted] or list(seen)
        alone = [n for n in sorted(seen, key=lambda n: (n not in trusted, -len(seen[n])))
                 if [n] != together]
        failure = "too few panel points"
        limit = MAX_FIT_MEDIAN_M * self.noise_scale
        for names in [together, *[[n] for n in alone]]:
            cloud = np.concatenate([seen[n] for n in names]) if names else np.zeros((0, 3))
            if len(cloud) < MIN_POINTS:
                continue
            pose, _ = fit_model(self.model, cloud, guess, np.concatenate([eyes[n] for n in names]),
                                give_up_median_m=GIVE_UP_FACTOR * limit)
            off = np.abs(self.model.distance(to_object(pose, cloud)))
            typical, on = float(np.median(off)), float(np.mean(off < 0.01))
            if typical <= limit and on >= MIN_ON_MODEL:
                for n in seen.keys() - set(names):
                    if n in trusted or names != together:  # not merely left out, uncorrected
                        why[n] = "its points disagree with the other camera's and the CAD model"
                return pose, why
            failure = (f"the CAD model fits the points to {typical * 1e3:.1f} mm (median), "
                       f"{on:.0%} within 1 cm")
        return None, {**why, "fit": failure} if seen else why or {"all": failure}

    def _sharp_left(self, camera: str) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                 tuple[slice, slice]] | None:
        """A left camera's sharp colour and depth (m), where the panel is (its yellow
        pixels), and the window around them that measuring uses (rows, columns, with the
        stereo's disparity range in front); None if fewer than MIN_POINTS panel pixels
        are in view. Only a window around the panel's silhouette in a coarse segmentation
        is rendered (black, depth inf elsewhere); the whole image if the panel reaches
        that window's edge."""
        r, d = self.renderer, self.data
        h, w = self.pinhole.height, self.pinhole.width
        ys, xs = np.nonzero(r.segmentation(d, camera, COARSE) == self.panel_geom)
        if len(ys) == 0:
            return None
        sy, sx = h / (h // COARSE), w / (w // COARSE)
        silhouette = np.zeros((h, w), bool)  # its bounding box, in the image's pixels
        silhouette[int(ys.min() * sy):int(np.ceil((ys.max() + 1) * sy)),
                   int(xs.min() * sx):int(np.ceil((xs.max() + 1) * sx))] = True
        around = _measuring_window(silhouette, BLUR_MARGIN_PX + COARSE)
        for rendered in (around, (slice(0, h), slice(0, w))):
            sharp = np.zeros((h, w, 3), np.uint8)
            depth = np.full((h, w), np.inf, np.float32)
            sharp[rendered], depth[rendered] = r.rgb_and_depth(d, camera, rendered)
            near = panel_mask(sharp)  # where to look: the lens blurs only a few pixels
            if near.sum() < MIN_POINTS:
                return None
            rows, cols = _measuring_window(near, BLUR_MARGIN_PX)
            if all(outer.start <= inner.start and inner.stop <= outer.stop
                   for outer, inner in zip(rendered, (rows, cols), strict=True)):
                break
        return sharp, depth, near, (rows, cols)

    def _panel_points(self, cam: Camera) -> np.ndarray | str:
        """World points of the panel in one camera's view, or why there are none."""
        r, d, robot = self.renderer, self.data, cam.robot
        found = self._sharp_left(robot.camera)
        if found is None:
            return "panel not in view (occluded or outside the image)"
        sharp, sharp_depth, near, (rows, cols) = found
        left = np.zeros_like(sharp)
        left[rows, cols] = defocus(sharp[rows, cols], sharp_depth[rows, cols], self.lens)
        right = np.zeros_like(sharp)
        right[rows, cols] = defocus(*r.rgb_and_depth(d, robot.right_camera, (rows, cols)),
                                    self.lens)
        mask = np.zeros_like(near)
        mask[rows, cols] = panel_mask(left[rows, cols])
        if mask.sum() < MIN_POINTS:
            return "panel not in view (occluded or outside the image)"
        depth = stereo_depth(left, right, self.pinhole, self.baseline_m, SETTINGS,
                             _window(near, self.cfg.stereo_margin_px))
        v, u = np.nonzero(mask & np.isfinite(depth))
        if len(v) < MIN_POINTS // 2:
            return "no stereo depth on the panel"
        if len(v) > MAX_POINTS_PER_CAMERA:
            keep = self.rng.choice(len(v), MAX_POINTS_PER_CAMERA, replace=False)
            v, u = v[keep], u[keep]
        z = depth[v, u].astype(float)
        p = self.pinhole
        in_cam = np.column_stack([(u - p.cx) * z / p.fx, (v - p.cy) * z / p.fy, z])
        T = opencv_pose(cam.believed)
        return in_cam @ T[:3, :3].T + T[:3, 3]

    # ------------------------------------------------------------ the loop

    def not_attempted(self, cameras: list[Camera], why: str) -> TaskResult:
        """The outcome of a task that could not start: the panel stays where it lies."""
        result = self._result(cameras, [])
        result.attempted, result.stopped_by = False, why
        return result

    def _result(self, cameras: list[Camera], frame_robots: list[str]) -> TaskResult:
        return TaskResult(self.model.size, self.cfg.tolerances, frame_robots=frame_robots,
                          cameras=[{"robot": c.robot.name, "pose": c.pose_status,
                                    "pose_sd_m": round(c.pose_sd_m, 6)} for c in cameras])

    def run(self, cameras: list[Camera], slot: np.ndarray,
            replace: Callable[[Camera, int], dict[str, Any] | None] | None = None,
            frame_robots: list[str] | None = None) -> TaskResult:
        """Carry, then steer the panel into the slot believed at ``slot`` (world, m),
        which the sightings of ``frame_robots`` placed."""
        cfg = self.cfg
        result = self._result(cameras, frame_robots or [])
        above = np.array([0.0, 0.0, cfg.approach_m])
        lying = self.panel  # where it was picked up: its last known pose
        start = lying[:3, 3].copy()
        arrival = slot + above + self.rng.normal(0.0, cfg.carry_error_m, 3)
        t0 = float(self.data.time)
        for k, s in enumerate(np.linspace(0.0, 1.0, 11)):  # the open-loop carry
            lift = np.array([0.0, 0.0, 4 * s * (1 - s) * cfg.approach_m])
            self._move_panel((1 - s) * start + s * arrival + lift)
            self.recorder.panel(t0 + 0.2 * k, self.panel[:3, 3], None)
        guess = lying.copy()  # the carry keeps the orientation it was picked up with
        guess[:3, 3] = slot + above  # where the carrier believes it put the panel
        moved_from = lying
        descending = False
        for step in range(cfg.max_steps):
            result.steps = step + 1
            t = t0 + 2.0 + STEP_S * step
            pose, why = self.measure(cameras, guess)
            for cam in cameras:
                if cam.robot.name in why:
                    cam.lost_in_a_row += 1
                    result.lost_views += 1
                else:
                    cam.lost_in_a_row = 0
            seeing = self._recover(cameras, step, result, replace)
            if pose is None:
                result.failed.append({"step": step, "why": why})
                if not seeing:
                    result.stopped_by = "no camera sees the panel"
                    break
                continue
            result.measurements += 1
            freed, occupied = move_object(self.grid, self.model, moved_from, pose)
            result.voxels_freed += freed
            result.voxels_occupied += occupied
            moved_from = pose
            guess = pose
            displacement = pose[:3, 3] - slot
            result.measured_displacement = displacement
            self.recorder.panel(t, self.panel[:3, 3], pose[:3, 3],
                                float(np.linalg.norm(displacement)))
            if np.linalg.norm(displacement) < cfg.stop_m:
                result.stopped_by = "measured displacement below stop_m"
                break
            target = slot.copy()
            if not descending and np.linalg.norm(displacement[:2]) > OVER_SLOT_M:
                target[2] += cfg.approach_m  # not over the slot yet: stay above it
            else:
                descending = True  # once on its way down it is not lifted again
            step_vec = cfg.gain * (target - pose[:3, 3])
            length = float(np.linalg.norm(step_vec))
            if length > cfg.max_step_m:
                step_vec *= cfg.max_step_m / length
            executed = (step_vec * (1 + self.rng.normal(0.0, cfg.step_scale))
                        + self.rng.normal(0.0, cfg.step_noise_m, 3))
            self._move_panel(self.panel[:3, 3] + executed)
            guess = pose.copy()
            guess[:3, 3] += step_vec
        else:
            result.stopped_by = "max_steps"
        truth_slot = self.data.site_xpos[self.slot_site]
        result.final_displacement = self.panel[:3, 3] - truth_slot
        return result

    def _recover(self, cameras: list[Camera], step: int, result: TaskResult,
                 replace: Callable[[Camera, int], dict[str, Any] | None] | None) -> bool:
        """Re-place the cameras that lost the panel ``lost_limit`` steps running (once
        each); whether any camera may still see it."""
        for cam in cameras:
            if cam.lost_in_a_row >= self.cfg.lost_limit and replace is not None \
                    and not any(r["robot"] == cam.robot.name for r in result.replacements):
                record = replace(cam, step)
                if record is not None:
                    result.replacements.append(record)
                    cam.lost_in_a_row = 0
        return any(c.lost_in_a_row < self.cfg.lost_limit for c in cameras)
