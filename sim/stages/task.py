"""The visually guided insertion task (sec. 3): the placed cameras guide the panel into
its slot, and success is judged from where it really ends (docs/task.md).

1. **Carry.** The panel (a mocap body: carried kinematically) goes open-loop from where
   it lies to a point ``approach_m`` above its slot, arriving ``carry_error_m`` off; the
   task believes it picked it up where the robots perceived it lying.
2. **Measure.** Every placed camera renders its stereo pair through its lens around the
   panel and the slot (sim/stages/task_images.py). ``measurement = "relative"``: the
   panel's and the slot's CAD models are fitted to the edges of its own pair, and the
   displacement taken between them in its frame (sim/stages/relative.py); cameras are
   fused by inverse covariance. ``"absolute"`` (sim/stages/absolute_panel.py): stereo
   points of the panel, through the camera's pose, fitted with its CAD model (all
   cameras together, else the best alone),
   minus the slot where the holes' frame puts it; the relative measurement also uses it
   once to find the panel after the carry. A step no camera measures is a failed
   measurement: the panel waits, nothing is guessed.
3. **Update the map.** Each measured pose moves the panel's voxels in the map, from its
   last pose to the new one, each with its uncertainty (sec. 3, steps 1-4).
4. **Steer.** The panel is moved by ``gain`` of the measured displacement (at most
   ``max_step_m``), staying ``approach_m`` above the slot until it is over it (then it
   goes down, and is not lifted again); each move errs by ``step_scale`` and
   ``step_noise_m``.
5. **Re-place.** Each camera is rated on the insertion site every step (the panel one
   more occluder); one whose rating stays well below what it had, or that loses the
   panel ``lost_limit`` steps running (or twice while the panel stood still: looking
   again would see the same), is placed again (the episode does it).

It stops when the fused displacement is confidently within the tightest tolerance
(``stop_share``, ``stop_sigmas``), after ``max_steps``, or when no camera can see the
panel any more. Success for each tolerance (a fraction of the panel's size) is judged on
the true final displacement. With no target frame measured (no camera located the
primary target) the task is not attempted and fails every tolerance.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from taskcam.calibration.displacement import largest_sd, prediction_start, stop_reason
from taskcam.calibration.edge_model import Boxes, StereoRig
from taskcam.mapping import (
    LyingPose,
    OccupancyGrid,
    Pinhole,
    move_object,
    support_layer,
)
from taskcam.sim.config.stages import TaskConfig
from taskcam.sim.screen import Advance
from taskcam.sim.stages.absolute_panel import AbsolutePanel
from taskcam.sim.stages.panel_model import panel_model
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.relative import (
    Measurement,
    PanelBelief,
    RelativeMeasurer,
    SlotBelief,
    StandIn,
    slot_model,
)
from taskcam.sim.stages.replacement import Replace
from taskcam.sim.stages.site_view import SiteWatch
from taskcam.sim.stages.task_images import StereoPair, TaskImages
from taskcam.sim.stages.task_result import Camera, TaskResult
from taskcam.sim.world.optics import Lens
from taskcam.sim.world.render import Renderer
from taskcam.sim.world.scene import Scene

STEP_S = 1.0  # simulated time per steering step, for the recording
OVER_SLOT_M = 0.005  # the panel descends once measured this close above the slot (m)
# A camera's misses while the panel stands still (no step measured it in between): the
# first fit starts from the prediction, the second from the absolute measurement; a third
# would see the same images from the same start, so the camera is re-placed after two.
# (``lost_limit`` rides out a panel passing behind something: that needs the panel to move.)
STILL_MISSES = 2


def execution_sd(cfg: TaskConfig, length_m: float) -> float:
    """How far (m, per axis) a commanded step of ``length_m`` errs: ``step_noise_m`` and
    ``step_scale`` of its length."""
    return math.hypot(cfg.step_noise_m, cfg.step_scale * length_m)


# The absolute measurement's panel pose is this good (m, rad per axis): its CAD fit to
# stereo points errs 6-16 mm laterally (median-95th percentile) with the slot's error in
# at 0.8-1.2 m (docs/measurement.md), and is turned 1.3-1.5 deg (median; 6.6 deg at the
# 95th percentile, a tail no Gaussian holds) at 0.5-1.2 m, whatever its start's turn
# (bench/studies/absolute_pose.py); it only starts the relative fits
ABSOLUTE_SD = (0.01, math.radians(2.0))


def _unseen(done: float) -> None:
    """A step nobody is shown."""


class InsertionTask(TaskImages):
    """Runs the task in the world ``data`` with the placed cameras (seeing through
    :class:`TaskImages`)."""

    def __init__(self, scene: Scene, world: mujoco.MjModel, data: mujoco.MjData,
                 renderer: Renderer,
                 pinhole: Pinhole, baseline_m: float, lens: Lens, grid: OccupancyGrid,
                 cfg: TaskConfig, rng: np.random.Generator, recorder: Recorder) -> None:
        m = scene.model
        super().__init__(data, renderer, pinhole, lens, m.geom("panel/panel").id,
                         StereoRig(pinhole.width, pinhole.height, pinhole.fx, pinhole.fy,
                                   pinhole.cx, pinhole.cy, baseline_m, lens.blur_sd_px))
        self.world, self.baseline_m, self.grid, self.cfg = world, baseline_m, grid, cfg
        self.rng, self.recorder = rng, recorder
        self.on_step: Advance = _unseen  # told each step as it starts (a live meter)
        self.model = panel_model(m)  # the CAD model: the nominal one
        self.mocap = int(m.body_mocapid[m.body("panel/panel").id])
        self.slot_site = m.site("workpiece/slot").id
        self.panel_boxes = Boxes(self.model.centres, self.model.halves)
        self.absolute = AbsolutePanel(self, self.model, baseline_m, cfg.stereo_margin_px, rng)
        self.slot_boxes = slot_model(m)
        self._last_pairs: dict[str, StereoPair | str] = {}  # this step's, for the recording

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
        """The absolute measurement (:class:`AbsolutePanel`): the panel's pose fitted to
        what the cameras see (None if they cannot), and why each camera that contributed
        nothing failed."""
        return self.absolute.measure(cameras, guess)

    def _relocate(self, cameras: list[Camera], belief: PanelBelief) -> str | None:
        """Where the relative measurement's fits start when the belief is coarse (after
        the open-loop carry, or a step that measured nothing): the absolute measurement's
        panel pose, if it finds one the belief holds possible, uncertain by ABSOLUTE_SD;
        why the belief was kept, if it found another."""
        pose, _ = self.measure(cameras, belief.pose)
        if pose is None:
            return None
        why = belief.implausible(pose, ABSOLUTE_SD)
        if why is None:
            belief.pose = pose.copy()
            belief.position_sd_m = ABSOLUTE_SD[0]
            belief.rotation_information = np.eye(3) / ABSOLUTE_SD[1] ** 2
        return why

    def measure_relative(self, cameras: list[Camera], measurer: RelativeMeasurer,
                         panel: PanelBelief,
                         prediction: tuple[np.ndarray, np.ndarray] | None = None
                         ) -> Measurement:
        """Every camera's relative measurement of the panel against its slot, fused
        (``prediction``: the displacement the last step leads to expect, and its
        covariance)."""
        pairs: dict[str, Any] = {}
        for cam in cameras:
            pair = self.stereo_pair(cam.robot.camera, cam.robot.right_camera,
                                    self._slot_window(cam, measurer))
            pairs[cam.robot.name] = (pair, None, None) if isinstance(pair, str) else (
                (pair.left, pair.right), (pair.mask, pair.right_mask), self.seen(pair))
            self._last_pairs[cam.robot.name] = pair
        return measurer.step(cameras, pairs, panel, prediction)

    # ------------------------------------------------------------ the loop

    def not_attempted(self, cameras: list[Camera], why: str) -> TaskResult:
        """The outcome of a task that could not start: the panel stays where it lies."""
        return TaskResult(self.model.size, self.cfg.tolerances, attempted=False,
                          cameras=self._camera_rows(cameras), stopped_by=why)

    @staticmethod
    def _camera_rows(cameras: list[Camera]) -> list[dict[str, Any]]:
        return [{"robot": c.robot.name, "pose": c.pose_status,
                 "pose_sd_m": round(c.pose_sd_m, 6)} for c in cameras]

    def run(self, cameras: list[Camera], slot: SlotBelief, lying: LyingPose,
            replace: Replace | None = None, frame_robots: list[str] | None = None,
            watch: SiteWatch | None = None,
            stand_ins: dict[str, list[StandIn]] | None = None) -> TaskResult:
        """Carry, then steer the panel into the slot believed at ``slot``, which the
        sightings of ``frame_robots`` placed; ``lying`` is where the panel was perceived
        lying, with that pose's covariance;
        ``replace`` places a camera again: one that keeps losing the panel, or whose view
        of the insertion site (rated every step by ``watch``) fell well below what it
        had; ``stand_ins``: per camera, where the secondary targets it sighted put the
        slot (one placed for such a target measures the panel against it; another, where
        it cannot fit the slot)."""
        cfg = self.cfg
        rows = self._camera_rows(cameras)
        cameras = list(cameras)  # a re-placed camera takes its predecessor's place
        lost = {c.robot.name: 0 for c in cameras}  # steps running without the panel
        still = dict(lost)  # of those, since the panel last moved
        steps = measurements = lost_views = freed = occupied = 0
        failed: list[dict[str, Any]] = []
        log: list[dict[str, Any]] = []
        replacements: list[dict[str, Any]] = []
        measured: np.ndarray | None = None
        # the displacement the last step leads to expect, and its covariance (world, m)
        predicted: tuple[np.ndarray, np.ndarray] | None = None
        stopped_by = "max_steps"
        above = np.array([0.0, 0.0, cfg.approach_m])
        tolerance = min(cfg.tolerances) * self.model.size
        start = self.panel[:3, 3].copy()  # the carrier picks it up where it truly lies
        arrival = slot.position + above + self.rng.normal(0.0, cfg.carry_error_m, 3)
        t0 = float(self.data.time)
        for k, s in enumerate(np.linspace(0.0, 1.0, 11)):  # the open-loop carry
            lift = np.array([0.0, 0.0, 4 * s * (1 - s) * cfg.approach_m])
            self._move_panel((1 - s) * start + s * arrival + lift)
            self.recorder.panel(t0 + 0.2 * k, self.data, self.panel[:3, 3], None)
        guess = lying.pose.copy()  # the carry keeps the orientation it was picked up with
        guess[:3, 3] = slot.position + above  # where the carrier believes it put the panel
        belief = PanelBelief(guess, cfg.carry_error_m, np.linalg.inv(lying.covariance[:3, :3]))
        measurer = RelativeMeasurer(self.rig, self.panel_boxes, self.slot_boxes, slot, stand_ins)
        moved_from: np.ndarray | None = lying.pose
        moved_from_covariance: np.ndarray | None = lying.covariance
        keep: np.ndarray | None = support_layer(self.grid, lying.support_z)  # its floor
        descending = False
        relocate = True
        if watch is not None:
            for cam in cameras:
                watch.start(cam.robot.name, cam.believed[:3, 3], lying.pose)
        for step in range(cfg.max_steps):
            steps = step + 1
            self.on_step(steps)
            self.recorder.tick()  # each task step is a step of the recording's timeline
            t = t0 + 2.0 + STEP_S * step
            covariance: np.ndarray | None = None
            expect: tuple[np.ndarray, np.ndarray] | None = None  # the prediction's start
            agreed = True  # the cameras fused agree within chance
            if cfg.measurement == "relative":
                kept = None
                if relocate:  # the first step, or after one that measured nothing
                    kept = self._relocate(cameras, belief)
                found = self.measure_relative(cameras, measurer, belief, predicted)
                relocate = found.fused is None
                why = found.why
                pose = found.panel
                truth = self.panel[:3, 3] - self.data.site_xpos[self.slot_site]
                record: dict[str, Any] = {"step": step, "cameras": found.cameras,
                                          "true_displacement": truth.round(6).tolist()}
                if kept is not None:  # the absolute measurement's pose, refused
                    record["absolute_refused"] = kept
                if found.fused is not None:
                    displacement, covariance = found.fused.displacement, found.fused.covariance
                    expect = prediction_start(found.fused)
                    agreed = found.fused.agreed
                    record["fused"] = found.fused.summary()
                log.append(record)
                self.recorder.task_view(t, cameras, self._last_pairs, found.fits)
            else:
                pose, why = self.measure(cameras, belief.pose)
                if pose is not None:
                    displacement = pose[:3, 3] - slot.position
                log.append({"step": step, "cameras": {n: {"why": w} for n, w in why.items()}})
            for cam in cameras:
                missed = cam.robot.name in why
                lost[cam.robot.name] = lost[cam.robot.name] + 1 if missed else 0
                still[cam.robot.name] = 0 if pose is not None else lost[cam.robot.name]
                lost_views += missed
            seeing = self._recover(cameras, lost, still, step, replacements, replace,
                                   measurer, belief.pose, watch)
            if pose is None:
                failed.append({"step": step, "why": why})
                if not seeing:
                    stopped_by = "no camera sees the panel"
                    break
                continue
            measurements += 1
            emptied, filled = move_object(self.grid, self.model, moved_from, pose,
                                          moved_from_covariance, None, keep=keep)
            freed, occupied = freed + emptied, occupied + filled
            moved_from, moved_from_covariance, keep = pose, None, None
            measured = displacement
            if watch is not None:
                self._watch(cameras, watch, step, log[-1], replacements, replace, measurer,
                            pose)
            self.recorder.panel(t, self.data, self.panel[:3, 3], pose[:3, 3],
                                float(np.linalg.norm(displacement)))
            spread = np.zeros((3, 3)) if covariance is None else covariance
            next_error = execution_sd(cfg, cfg.gain * float(np.linalg.norm(displacement)))
            stop = stop_reason(displacement, spread, tolerance, cfg.stop_share, cfg.stop_sigmas,
                               agreed, cfg.gain, next_error)
            if stop is not None:
                stopped_by = stop
                break
            goal = np.zeros(3)
            if not descending and np.linalg.norm(displacement[:2]) > OVER_SLOT_M:
                goal[2] += cfg.approach_m  # not over the slot yet: stay above it
            else:
                descending = True  # once on its way down it is not lifted again
            step_vec = cfg.gain * (goal - displacement)
            length = float(np.linalg.norm(step_vec))
            if length > cfg.max_step_m:
                step_vec *= cfg.max_step_m / length
            executed = (step_vec * (1 + self.rng.normal(0.0, cfg.step_scale))
                        + self.rng.normal(0.0, cfg.step_noise_m, 3))
            moved = self.panel[:3, 3] + executed
            # the slot's floor stops the panel's bottom edge: a real panel rests on it,
            # the carried (kinematic) one would pass into the plate
            moved[2] = max(moved[2], float(self.data.site_xpos[self.slot_site][2]))
            self._move_panel(moved)
            belief.pose[:3, 3] = pose[:3, 3] + step_vec
            measured_sd = largest_sd(spread)
            erred = execution_sd(cfg, float(np.linalg.norm(step_vec)))
            belief.position_sd_m = math.hypot(measured_sd, erred)
            predicted = (None if expect is None else
                         (expect[0] + step_vec, expect[1] + erred ** 2 * np.eye(3)))
        truth_slot = self.data.site_xpos[self.slot_site]
        return TaskResult(
            self.model.size, cfg.tolerances, frame_robots=frame_robots or [], cameras=rows,
            final_displacement=self.panel[:3, 3] - truth_slot, measured_displacement=measured,
            steps=steps, measurements=measurements, failed=failed, lost_views=lost_views,
            replacements=replacements, stopped_by=stopped_by, voxels_freed=freed,
            voxels_occupied=occupied, measurement=cfg.measurement, log=log,
            lying=lying.summary())

    def _watch(self, cameras: list[Camera], watch: SiteWatch, step: int,
               record: dict[str, Any], replacements: list[dict[str, Any]],
               replace: Replace | None, measurer: RelativeMeasurer, panel: np.ndarray) -> None:
        """Rate every camera on the insertion site with the panel where it was measured;
        place again one whose rating fell (once the trigger says so), if a better view is
        worth the move."""
        for i, cam in enumerate(cameras):
            name = cam.robot.name
            rating = watch.rate(cam.believed[:3, 3], panel)
            entry = record["cameras"].setdefault(name, {})
            entry["site"] = {"rating": round(rating.total, 6),
                             "open": round(rating.open_fraction, 4)}
            why = watch.check(name, rating)
            if why is None or replace is None:
                continue
            again = replace(cam, step, why, rating.total, panel)
            if again is None:
                continue
            replacements.append(again.record)
            if again.camera is not None:
                cameras[i] = again.camera
                measurer.forget(name)
                watch.start(name, again.camera.believed[:3, 3], panel)

    def _recover(self, cameras: list[Camera], lost: dict[str, int], still: dict[str, int],
                 step: int, replacements: list[dict[str, Any]], replace: Replace | None,
                 measurer: RelativeMeasurer, panel: np.ndarray,
                 watch: SiteWatch | None) -> bool:
        """Re-place the cameras that lost the panel ``lost_limit`` steps running, or
        STILL_MISSES times while it stood still (``still``), once each; whether any camera
        may still see it."""
        limit = self.cfg.lost_limit
        for i, cam in enumerate(cameras):
            name = cam.robot.name
            stuck = still[name] >= min(STILL_MISSES, limit)
            if (lost[name] >= limit or stuck) and replace is not None \
                    and not any(r["robot"] == name for r in replacements):
                why = (f"lost the panel {lost[name]} steps running"
                       + (" while it stood still" if lost[name] < limit else ""))
                again = replace(cam, step, why, None, panel)
                if again is not None:
                    replacements.append(again.record)
                    lost[name] = still[name] = 0
                    if again.camera is not None:
                        cameras[i] = again.camera
                        measurer.forget(name)
                        if watch is not None:
                            watch.start(name, again.camera.believed[:3, 3], panel)
        return any(lost[c.robot.name] < limit and still[c.robot.name] < STILL_MISSES
                   for c in cameras)
