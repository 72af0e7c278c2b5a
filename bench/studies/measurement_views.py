"""Rendered stereo views of the insertion site for bench/studies/measurement.py, and the
measurements run on them. A helper of that script, not a script itself.

A view: the panel hangs a random displacement above its slot; a free stereo pair (the
scenario's baseline) looks at the site from a distance and an angle off the slot's normal;
a thin plate between camera and site hides a chosen share of the panel's and the rails'
edges; the work-piece stands off where the robots believe it (Table 1's errors) and the
camera's believed pose is off its true one by the pose correction's residual. Both images
are rendered once, sharp, with their depth; every measurement gets the same ``View`` (and
applies the lens itself, as the task does).

A measurement is a function ``(Site, View) -> Measured`` listed in ``MEASUREMENTS``;
``absolute`` is today's: the panel from the task's own ``InsertionTask.measure`` (SGBM
points fitted with the CAD model, through the believed pose), the slot from the holes
sighted in stereo (``sight``), their common frame and the slot's CAD offset
(``in_measured_frame``), as the episode does. A second one (the relative measurement)
is added to ``MEASUREMENTS`` and runs on the same views.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from bench.common import SCENARIOS
from bench.studies.detector_views import look_rotation, put_camera
from taskcam.calibration.target_frame import common_frame, in_measured_frame, sight
from taskcam.mapping import opencv_pose
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.config.scene import ObstacleConfig
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.stages.look import target_sd
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.relative import SLOT_FRAME_SD, PanelBelief, RelativeMeasurer, SlotBelief
from taskcam.sim.stages.task import InsertionTask
from taskcam.sim.stages.task_result import Camera
from taskcam.sim.stages.world import misplace_workpiece, new_grid
from taskcam.sim.world.optics import Lens, defocus
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene

TABLE1 = SCENARIOS / "table1.toml"
POSE_SD_M = 0.001  # the pose correction's residual (RMS of the 3-D error)
POSE_SD_DEG = 0.1
GUESS_SD_M = 0.01  # the fit starts this far off (per axis): a previous measurement's error
# The guess's orientation is off by this per axis, and the relative fit is told so: what the
# task's belief holds at a step of the approach. The carrier does not turn the panel, so
# the task fuses every fit's orientation (sim/stages/relative.py's PanelBelief): in the
# default scenario (seed 0) its largest sd is 0.082 deg after the first fit, 0.024 deg
# after the last. The first's is taken. (It matters from straight above: the panel's
# bottom edge, which the displacement is of, hides under its top, and its place across
# the panel comes from the top's through the panel's tilt, 0.15 m below.)
GUESS_SD_RAD = math.radians(0.082)
DISPLACEMENT_XY_M = 0.02  # the panel's true displacement: uniform within +-this across ...
DISPLACEMENT_Z_M = (0.035, 0.06)  # ... and this high above the slot (rails' top: 0.03)
AZIMUTH_SPREAD_DEG = 45.0  # views within this of the panel's face normal (either side)
ROLL_DEG = 15.0  # camera roll, uniform within +-this
EDGE_SAMPLES = 16  # points per box edge for the occlusion measure
OCCLUDER_HALF_M = (0.6, 0.6, 0.003)  # the occluding plate's half extents
HIDDEN = np.array([0.0, 0.0, -5.0])  # where the occluder waits when there is none


def bench_scenario(samples: int | None = None) -> Scenario:
    """Table 1's scenario (the default with the sweep's overrides: no MSAA, the work-piece
    off by 1 cm / 2 deg, 16 px stereo margin) with one robot and one box obstacle, the
    occluder, whose pose and size the views set; ``samples``: MSAA other than Table 1's."""
    s = load_sweep(TABLE1).scenario
    camera = s.camera if samples is None else dataclasses.replace(s.camera, samples=samples)
    return dataclasses.replace(
        s, seed=0, robots=dataclasses.replace(s.robots, count=1, bases=s.robots.bases[:1]),
        camera=camera,
        obstacles=(ObstacleConfig(shape="box", position=(1.2, 1.2, 0.1), size=(0.05,) * 3),))


@dataclass(frozen=True)
class View:
    """One rendered stereo view and what a measurement may know of it; ``true_*`` are for
    scoring only."""

    sharp: dict[str, tuple[np.ndarray, np.ndarray]]  # camera -> rgb, z-depth (m), unblurred
    left: np.ndarray  # both images through the lens (sim/world/optics.py)
    right: np.ndarray
    believed: np.ndarray  # left camera, MuJoCo convention, as the correction leaves it
    guess: np.ndarray  # the panel's pose the measurement starts from (4x4)
    true_camera: np.ndarray
    true_panel: np.ndarray
    true_slot: np.ndarray
    occluded: float  # share of the visible edges the plate hides (left camera)
    target_occluded: float
    blur_px: float  # blur-circle diameter at the slot (px)


@dataclass(frozen=True)
class Measured:
    """A measurement's displacement (world, panel minus slot, m), or why it failed."""

    displacement: np.ndarray | None
    why: str | None = None
    panel: np.ndarray | None = None  # the measured panel position and slot (world, m)
    slot: np.ndarray | None = None
    covariance: np.ndarray | None = None  # of the displacement (world, m^2), if it has one


class StoredImages:
    """What ``InsertionTask`` renders with, serving the view's images: crops of the
    whole sharp renders (the task blurs them itself); segmentation from the renderer."""

    def __init__(self, renderer: Renderer, view: View) -> None:
        self.renderer, self.view = renderer, view

    def segmentation(self, data: mujoco.MjData, camera: str, downscale: int = 1) -> np.ndarray:
        return self.renderer.segmentation(data, camera, downscale)

    def rgb_and_depth(self, data: mujoco.MjData, camera: str,
                      window: tuple[slice, slice] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        rgb, depth = self.view.sharp[camera]
        return (rgb.copy(), depth.copy()) if window is None else (rgb[window].copy(),
                                                                  depth[window].copy())


def box_edges(data: mujoco.MjData, model: mujoco.MjModel, geom: int, n: int) -> np.ndarray:
    """``n`` points inside each of a box geom's 12 edges (world, m)."""
    size, R, c = model.geom_size[geom], data.geom_xmat[geom].reshape(3, 3), data.geom_xpos[geom]
    t = (np.arange(n) + 0.5) / n * 2 - 1
    points = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        for sa in (-1, 1):
            for sb in (-1, 1):
                local = np.zeros((n, 3))
                local[:, axis] = t * size[axis]
                local[:, a], local[:, b] = sa * size[a], sb * size[b]
                points.append(local)
    return c + np.concatenate(points) @ R.T


def ray_visible(model: mujoco.MjModel, data: mujoco.MjData, eye: np.ndarray,
                points: np.ndarray) -> np.ndarray:
    """Which points the eye sees: nothing hit nearer than 3 mm short of the point."""
    out = np.zeros(len(points), bool)
    geomid = np.zeros(1, np.int32)
    for i, p in enumerate(points):
        v = p - eye
        length = float(np.linalg.norm(v))
        hit = mujoco.mj_ray(model, data, eye, v / length, None, 1, -1, geomid)
        out[i] = hit < 0 or hit >= length - 0.003
    return out


def through_plate(eye: np.ndarray, points: np.ndarray, centre: np.ndarray, n: np.ndarray,
                  u: np.ndarray, w: np.ndarray, edge: float, half: float) -> np.ndarray:
    """Which rays eye -> point cross the plane (normal ``n``) through ``centre`` between
    u >= ``edge`` (up to 2 ``half`` beyond) and |w| <= ``half`` (plate coordinates)."""
    d = points - eye
    s = ((centre - eye) @ n) / (d @ n)
    x = eye + s[:, None] * d - centre
    pu, pw = x @ u, x @ w
    return (s > 0) & (s < 1) & (pu >= edge) & (pu <= edge + 2 * half) & (np.abs(pw) <= half)


class Site:
    """The scene, the task's measuring code and the renderer the views share."""

    def __init__(self, rng: np.random.Generator, samples: int | None = None) -> None:
        s = self.scenario = bench_scenario(samples)
        self.scene = build_scene(s)
        self.rng = rng
        self.model = copy.deepcopy(self.scene.model)  # the true world (the work-piece off)
        m = self.model
        m.body_pos[m.body(f"{self.scene.robots[0].name}/base").id, 2] = -3.0  # out of sight
        self.occluder_body = m.body("obstacle0/box").id
        self.occluder = m.geom("obstacle0/box").id
        m.geom_size[self.occluder] = OCCLUDER_HALF_M
        m.geom_rbound[self.occluder] = float(np.linalg.norm(OCCLUDER_HALF_M))
        m.geom_aabb[self.occluder] = [0, 0, 0, *OCCLUDER_HALF_M]
        self.workpiece = m.body("workpiece/workpiece").id
        self.workpiece_at = (m.body_pos[self.workpiece].copy(), m.body_quat[self.workpiece].copy())
        self.data = self.scene.make_data()
        self.edge_geoms = [m.geom(g).id for g in ("panel/panel", "workpiece/rail_a",
                                                  "workpiece/rail_b")]
        nominal = self.scene.make_data()
        mujoco.mj_forward(self.scene.model, nominal)
        self.nominal_slot = nominal.site("workpiece/slot").xpos.copy()  # in the CAD model
        self.nominal_slot_pose = np.eye(4)
        self.nominal_slot_pose[:3, :3] = nominal.site("workpiece/slot").xmat.reshape(3, 3)
        self.nominal_slot_pose[:3, 3] = self.nominal_slot
        self.panel_quat = nominal.mocap_quat[0].copy()
        self.robot = self.scene.robots[0]
        self.pinhole = camera_pinhole(m, self.robot.camera)
        c = s.camera
        self.lens = Lens(c.near_m, c.far_m, c.coc_px)
        self.renderer = Renderer(m, c.width, c.height)
        self.task = InsertionTask(self.scene, m, self.data, self.renderer, self.pinhole,
                                  c.baseline_m, self.lens, new_grid(s), s.task, rng,
                                  Recorder(None, ""))

    def close(self) -> None:
        self.renderer.close()

    def _set_occluder(self, position: np.ndarray, R: np.ndarray) -> None:
        m = self.model
        m.body_pos[self.occluder_body] = position
        m.body_quat[self.occluder_body] = Rotation.from_matrix(R).as_quat(scalar_first=True)
        mujoco.mj_forward(m, self.data)

    def _occlude(self, eye: np.ndarray, aim: np.ndarray, share: float) -> float:
        """Slide the plate across the line of sight until it hides ``share`` of the
        edges the left camera sees (from the side away from the holes); the share it
        hides, checked by ray casting."""
        self._set_occluder(HIDDEN, np.eye(3))
        points = np.concatenate([box_edges(self.data, self.model, g, EDGE_SAMPLES)
                                 for g in self.edge_geoms])
        seen = points[ray_visible(self.model, self.data, eye, points)]
        if share <= 0 or len(seen) == 0:
            return 0.0
        n = (eye - aim) / np.linalg.norm(eye - aim)
        away = aim - self.scene.primary.position  # the holes are covered last
        u = away - (away @ n) * n
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        centre = aim + min(0.5 * np.linalg.norm(eye - aim), 0.3) * n
        half = OCCLUDER_HALF_M[0]
        lo, hi = -1.0, 1.0  # plate edge (m along u): all hidden .. none hidden
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            hidden = through_plate(eye, seen, centre, n, u, w, mid, half).mean()
            lo, hi = (mid, hi) if hidden > share else (lo, mid)
        edge = hi
        R = np.column_stack([u, w, n])  # plate thin along n
        self._set_occluder(centre + (edge + half) * u, R)
        return float(1.0 - ray_visible(self.model, self.data, eye, seen).mean())

    def view(self, distance: float, angle_deg: float, occlusion: float) -> View:
        """A random view of the site at this distance (m, left camera to the slot), angle
        off the slot's normal (deg) and share of edges occluded."""
        m, d, rng, s = self.model, self.data, self.rng, self.scenario
        m.body_pos[self.workpiece], m.body_quat[self.workpiece] = self.workpiece_at
        misplace_workpiece(s, m, rng)  # Table 1's work-piece error, drawn per view
        mujoco.mj_forward(m, d)
        slot = d.site("workpiece/slot").xpos.copy()
        x_axis = d.body("workpiece/workpiece").xmat.reshape(3, 3)[:, 0]
        shift = np.array([*rng.uniform(-DISPLACEMENT_XY_M, DISPLACEMENT_XY_M, 2),
                          rng.uniform(*DISPLACEMENT_Z_M)])
        R_wp = d.body("workpiece/workpiece").xmat.reshape(3, 3)
        panel_at = slot + R_wp @ shift
        d.mocap_pos[self.task.mocap] = panel_at
        d.mocap_quat[self.task.mocap] = self.panel_quat
        normal = np.array([0.0, 0.0, 1.0])
        azimuth = math.atan2(x_axis[1], x_axis[0]) + rng.choice([0.0, math.pi]) + math.radians(
            rng.uniform(-AZIMUTH_SPREAD_DEG, AZIMUTH_SPREAD_DEG))
        a = math.radians(angle_deg)
        direction = math.cos(a) * normal + math.sin(a) * np.array(
            [math.cos(azimuth), math.sin(azimuth), 0.0])
        eye = slot + distance * direction
        aim = 0.5 * (slot + panel_at + [0.0, 0.0, 0.075])  # between slot and panel centre
        R = look_rotation(eye, aim, math.radians(rng.uniform(-ROLL_DEG, ROLL_DEG)))
        robot = self.robot
        put_camera(m, d, robot.camera, eye, R)
        put_camera(m, d, robot.right_camera, eye + s.camera.baseline_m * R[:, 0], R)
        mujoco.mj_forward(m, d)
        occluded = self._occlude(eye, aim, occlusion)
        sharp = {cam: self.renderer.rgb_and_depth(d, cam)
                 for cam in (robot.camera, robot.right_camera)}
        left = defocus(*sharp[robot.camera], self.lens)
        right = defocus(*sharp[robot.right_camera], self.lens)
        true_camera = camera_pose(d, robot.camera)
        believed = true_camera.copy()
        believed[:3, 3] += rng.normal(0.0, POSE_SD_M / math.sqrt(3), 3)
        tilt = Rotation.from_rotvec(np.radians(rng.normal(0.0, POSE_SD_DEG / math.sqrt(3), 3)))
        believed[:3, :3] = tilt.as_matrix() @ believed[:3, :3]
        true_panel = self.task.panel
        guess = true_panel.copy()
        guess[:3, 3] += rng.normal(0.0, GUESS_SD_M, 3)
        off = Rotation.from_rotvec(rng.normal(0.0, GUESS_SD_RAD, 3)).as_matrix()
        guess[:3, :3] = off @ guess[:3, :3]
        depth = float((opencv_pose(true_camera)[:3, :3].T @ (slot - eye))[2])
        blur = float(self.lens.blur_px(np.array([depth]))[0])
        return View(sharp, left, right, believed, guess, true_camera, true_panel, slot,
                    occluded, occlusion, blur)


def hole_state(site: Site, view: View) -> str:
    """Why the primary hole may not have been sighted: out of the left image, hidden from
    the left camera's centre (ray cast to 1 mm above its true centre), or in view."""
    g = site.model.geom(site.scene.primary.geom).id
    hole = site.data.geom_xpos[g] + [0.0, 0.0, site.model.geom_size[g, 1] + 0.001]
    T = opencv_pose(view.true_camera)
    in_cam = (hole - T[:3, 3]) @ T[:3, :3]
    if in_cam[2] <= 0 or not site.pinhole.contains(site.pinhole.project(in_cam[None]),
                                                    margin=5.0)[0]:
        return "out of the image"
    eye = view.true_camera[:3, 3]
    seen = ray_visible(site.model, site.data, eye, hole[None])[0]
    return "in view" if seen else "hidden"


def holes_frame(site: Site, view: View) -> tuple[dict, int]:
    """The target frame the holes sighted in the view's (blurred) pair put through the
    believed pose (``sight`` and ``common_frame``, the episode's code), and how many of
    the targets were sighted."""
    s, robot = site.scenario, site.robot
    targets = site.scene.targets
    sightings = []
    for t in targets:
        found = sight(robot.name, view.left, view.right, t, view.believed, site.pinhole,
                      s.camera.baseline_m, position_sd_m=math.hypot(POSE_SD_M, target_sd(s, t)),
                      rotation_sd_deg=POSE_SD_DEG, others=tuple(o for o in targets if o is not t))
        if found is not None:
            sightings.append(dataclasses.replace(found, sd_m=POSE_SD_M))
    return common_frame(sightings, targets), len(sightings)


def _slot_note(site: Site, view: View, frame: dict, sighted: int) -> tuple[str | None, str | None]:
    """Why the slot is unknown (no primary sighting), and a note if a target was missed."""
    if frame["frame"] is None:
        return f"slot: primary hole not sighted in stereo ({hole_state(site, view)})", None
    return None, None if sighted == len(site.scene.targets) else "secondary hole not sighted"


def absolute(site: Site, view: View) -> Measured:
    """Today's measurement: the panel as ``InsertionTask.measure`` fits it from this
    camera's SGBM points through its believed pose; the slot where the holes' frame,
    sighted in the same (blurred) images through that pose, puts the slot's CAD place."""
    robot, task = site.robot, site.task
    task.renderer = StoredImages(site.renderer, view)
    camera = Camera(robot, view.believed, POSE_SD_M, "corrected")
    pose, why = task.measure([camera], view.guess)
    frame, sighted = holes_frame(site, view)
    unknown, note = _slot_note(site, view, frame, sighted)
    reasons = []
    if pose is None:
        reasons.append("panel: " + "; ".join(sorted(set(why.values()))))
    if unknown is not None:
        reasons.append(unknown)
    if reasons or pose is None:
        return Measured(None, " | ".join(reasons))
    slot = in_measured_frame(site.nominal_slot, site.scene.targets, frame)
    panel = pose[:3, 3]
    return Measured(panel - slot, note, panel, slot)


def relative(site: Site, view: View) -> Measured:
    """The relative measurement, as the task makes it at a step: the panel's
    CAD model and the slot's walls fitted to the edges of this camera's own pair
    (``InsertionTask.measure_relative``), the panel from the view's starting guess (1 cm
    off, as a previous measurement leaves it, and turned as the task's belief holds it),
    the slot from where the look stage's holes' frame leaves it (the true slot off by
    ``SLOT_FRAME_SD``, the frame's error, whether or not this view sights the holes: the
    task knows the slot from before)."""
    robot, task, rng = site.robot, site.task, site.rng
    true_slot = np.eye(4)
    true_slot[:3, :3] = site.data.site("workpiece/slot").xmat.reshape(3, 3)
    true_slot[:3, 3] = view.true_slot
    believed = true_slot.copy()
    believed[:3, 3] += rng.normal(0.0, SLOT_FRAME_SD[0], 3)
    turn = Rotation.from_rotvec(rng.normal(0.0, SLOT_FRAME_SD[1], 3)).as_matrix()
    believed[:3, :3] = turn @ believed[:3, :3]
    task.renderer = StoredImages(site.renderer, view)
    camera = Camera(robot, view.believed, POSE_SD_M, "corrected", math.radians(POSE_SD_DEG))
    measurer = RelativeMeasurer(task.rig, task.panel_boxes, task.slot_boxes,
                                SlotBelief(believed, SLOT_FRAME_SD))
    belief = PanelBelief(view.guess.copy(), GUESS_SD_M, np.eye(3) / GUESS_SD_RAD ** 2)
    found = task.measure_relative([camera], measurer, belief)
    if found.fused is None or found.panel is None:
        return Measured(None, "; ".join(f"{n}: {w}" for n, w in found.why.items()))
    d = found.fused.displacement
    panel = found.panel[:3, 3]
    return Measured(d, None, panel, panel - d, found.fused.covariance)


# name -> measurement; each runs on every view
MEASUREMENTS: dict[str, Callable[[Site, View], Measured]] = {"absolute": absolute,
                                                              "relative": relative}
