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
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from calibration.panel import measuring_window, panel_mask, window
from mapping import BoxModel, OccupancyGrid, Pinhole, fit_model, move_object, opencv_pose
from mapping.cad import to_object
from mapping.stereo import StereoSettings, stereo_depth
from sim.config.scenario import TaskConfig
from sim.stages.record import Recorder
from sim.stages.task_result import Camera, TaskResult
from sim.world.optics import Lens, defocus
from sim.world.render import Renderer
from sim.world.scene import Scene

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


def panel_model(model: mujoco.MjModel) -> BoxModel:
    """The panel's CAD model (its box geoms, in its body frame)."""
    body = model.body("panel/panel").id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
             and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    return BoxModel(model.geom_pos[geoms].copy(), model.geom_size[geoms].copy())


@dataclass(frozen=True)
class Replacement:
    """A camera's re-placement during the task: its record in ``replacements``, and the
    camera as the task now knows it (None: it could not be placed again)."""

    record: dict[str, Any]
    camera: Camera | None


# Given a camera that lost the panel, the step and how many steps running it lost it:
# its re-placement, or None if cameras are not re-placed.
Replace = Callable[[Camera, int, int], Replacement | None]


def _measuring_window(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    """The window around ``mask`` measuring uses, with the stereo's disparity range."""
    return measuring_window(mask, margin, SETTINGS.num_disparities)


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
                             window(near, self.cfg.stereo_margin_px))
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
        return TaskResult(self.model.size, self.cfg.tolerances, attempted=False,
                          cameras=self._camera_rows(cameras), stopped_by=why)

    @staticmethod
    def _camera_rows(cameras: list[Camera]) -> list[dict[str, Any]]:
        return [{"robot": c.robot.name, "pose": c.pose_status,
                 "pose_sd_m": round(c.pose_sd_m, 6)} for c in cameras]

    def run(self, cameras: list[Camera], slot: np.ndarray, replace: Replace | None = None,
            frame_robots: list[str] | None = None) -> TaskResult:
        """Carry, then steer the panel into the slot believed at ``slot`` (world, m),
        which the sightings of ``frame_robots`` placed; ``replace`` places a camera
        that keeps losing the panel again."""
        cfg = self.cfg
        rows = self._camera_rows(cameras)
        cameras = list(cameras)  # a re-placed camera takes its predecessor's place
        lost = {c.robot.name: 0 for c in cameras}  # steps running without the panel
        steps = measurements = lost_views = freed = occupied = 0
        failed: list[dict[str, Any]] = []
        replacements: list[dict[str, Any]] = []
        measured: np.ndarray | None = None
        stopped_by = "max_steps"
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
            steps = step + 1
            t = t0 + 2.0 + STEP_S * step
            pose, why = self.measure(cameras, guess)
            for cam in cameras:
                missed = cam.robot.name in why
                lost[cam.robot.name] = lost[cam.robot.name] + 1 if missed else 0
                lost_views += missed
            seeing = self._recover(cameras, lost, step, replacements, replace)
            if pose is None:
                failed.append({"step": step, "why": why})
                if not seeing:
                    stopped_by = "no camera sees the panel"
                    break
                continue
            measurements += 1
            emptied, filled = move_object(self.grid, self.model, moved_from, pose)
            freed, occupied = freed + emptied, occupied + filled
            moved_from = pose
            guess = pose
            displacement = pose[:3, 3] - slot
            measured = displacement
            self.recorder.panel(t, self.panel[:3, 3], pose[:3, 3],
                                float(np.linalg.norm(displacement)))
            if np.linalg.norm(displacement) < cfg.stop_m:
                stopped_by = "measured displacement below stop_m"
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
        truth_slot = self.data.site_xpos[self.slot_site]
        return TaskResult(
            self.model.size, cfg.tolerances, frame_robots=frame_robots or [], cameras=rows,
            final_displacement=self.panel[:3, 3] - truth_slot, measured_displacement=measured,
            steps=steps, measurements=measurements, failed=failed, lost_views=lost_views,
            replacements=replacements, stopped_by=stopped_by, voxels_freed=freed,
            voxels_occupied=occupied)

    def _recover(self, cameras: list[Camera], lost: dict[str, int], step: int,
                 replacements: list[dict[str, Any]], replace: Replace | None) -> bool:
        """Re-place the cameras that lost the panel ``lost_limit`` steps running (once
        each); whether any camera may still see it."""
        limit = self.cfg.lost_limit
        for i, cam in enumerate(cameras):
            name = cam.robot.name
            if lost[name] >= limit and replace is not None \
                    and not any(r["robot"] == name for r in replacements):
                again = replace(cam, step, lost[name])
                if again is not None:
                    replacements.append(again.record)
                    lost[name] = 0
                    if again.camera is not None:
                        cameras[i] = again.camera
        return any(lost[c.robot.name] < limit for c in cameras)
