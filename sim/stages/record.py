"""The rerun recording of an episode: the world and its moving bodies, cameras, images,
depth, grid, ratings, choices, and a layout to open it on (sim/stages/record_layout.py).

Entity paths: ``world/scene`` (every drawn geom under its body: sim/stages/scene_record.py),
``world/grid`` (the occupancy map, beside the true geometry: hide either),
``world/targets`` (labelled above them, under ``world/targets/labels``),
``world/<robot>/camera`` (its pose and a pinhole; beneath it what it saw last: ``depth``
from a mapping view, or ``rgb`` from the last frame its pose was corrected from, the
look or a task step, and under ``rgb/found`` what was found in that image: fiducials
and their tracks, the task's matched edges), ``world/<robot>/views`` (its latest
mapping view, until mapping ends), ``world/<robot>/candidates`` (coloured by rating, with a legend
beneath), ``world/<robot>/chosen`` (labelled at the camera's end); plots under
``mapping`` (the region's entropy, each view's gain) and ``task`` (the measured
displacement). Every 2-D entity in the world lies under a camera's pinhole. Everything
is on the ``step`` timeline; the robots' moves and the task are on the ``sim_time``
timeline too. Quaternions go to rerun as x, y, z, w.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from taskcam.mapping import OccupancyGrid, Pinhole, opencv_pose
from taskcam.sim.stages.record_layout import layout
from taskcam.sim.stages.scene_record import SceneGeometry, log_geometry, log_poses

if TYPE_CHECKING:
    import mujoco

    from taskcam.calibration.displacement import Relative
    from taskcam.sim.stages.correction import Correction
    from taskcam.sim.stages.overview import Film
    from taskcam.sim.stages.task_result import Camera


BODY_RATE_HZ = 30.0  # moving bodies' poses are logged at most this often in simulated time


# a viridis-like scale, low to high: dark violet, blue, teal, green, yellow (RGB)
SCALE = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]])
UNRATED = [110, 110, 110]  # a candidate rated 0 (its target not seen from there)
FRUSTUM_SHARE = 0.1  # frusta are drawn this share of the scene's size (its bounding box's)
# labels stand this share of the scene's size apart in height, so that at the opening
# view (which frames the scene) one does not cover the next
LABEL_SHARE = 0.08


def _colormap(values: np.ndarray) -> np.ndarray:
    """:data:`SCALE`'s colours (uint8 RGB) for values in [0, 1]."""
    v = np.clip(np.nan_to_num(values), 0.0, 1.0)
    stops = np.linspace(0.0, 1.0, len(SCALE))
    return np.column_stack([np.interp(v, stops, SCALE[:, c]) for c in range(3)]).astype(np.uint8)


class Recorder:
    """Writes one ``.rrd`` file; a no-op when ``path`` is None."""

    def __init__(self, path: Path | None, recording_id: str, unknown: bool = False,
                 film: Film | None = None) -> None:
        self.path = path
        self.film = film  # the episode filmed too, from the bodies' poses
        self.unknown = unknown  # record never-observed voxels with the grid
        self.rec: rr.RecordingStream | None = None
        self.steps = 0  # the ``step`` timeline's latest value
        self.model: mujoco.MjModel | None = None  # the world's, once :meth:`scene` logged it
        self.geometry: SceneGeometry | None = None
        self.bodies_s = -math.inf  # the simulated time (s) the bodies were last logged at
        self.frustum_m = 0.3  # how far frusta are drawn (m): see :meth:`scene` ...
        self.label_m = 0.25  # ... and how far apart labels stand in height (m)
        self.legends = 0  # the candidates' legends drawn so far
        if path is not None:
            self.rec = rr.RecordingStream("taskcam", recording_id=recording_id)
            self.rec.save(str(path))
            self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def step(self, step: int) -> None:
        if self.rec is not None:
            self.rec.set_time("step", sequence=step)

    def tick(self) -> None:
        """The next step of the ``step`` timeline."""
        self.steps += 1
        self.step(self.steps)

    def scene(self, model: mujoco.MjModel, data: mujoco.MjData, robots: list[str],
              task: bool, eye: tuple[np.ndarray, np.ndarray] | None = None,
              size_m: float | None = None, image: tuple[int, int] = (640, 480)) -> None:
        """The world's geometry and its bodies where they are now, and the layout the
        recording opens on (see :func:`layout`; ``eye``, the 3-D view's position and the
        point it looks at; ``image``, the cameras' width and height, px); later poses
        come with :meth:`bodies`. Frusta are drawn :data:`FRUSTUM_SHARE` of the scene's
        size ``size_m`` (m) long, labels stand :data:`LABEL_SHARE` of it apart."""
        if self.film is not None:
            self.film.frame(data, None)
        if size_m is not None:
            self.frustum_m, self.label_m = FRUSTUM_SHARE * size_m, LABEL_SHARE * size_m
        if self.rec is None:
            return
        self.model = model
        self.geometry = log_geometry(self.rec, model, data)
        self.rec.send_blueprint(layout(robots, task, image, eye))

    def bodies(self, data: mujoco.MjData, time_s: float | None = None) -> None:
        """The moving bodies' poses now, on the timelines set (and a film's frame at
        ``time_s``, simulated; None: a still)."""
        if self.film is not None:
            self.film.frame(data, time_s)
        if self.rec is None or self.model is None or self.geometry is None:
            return
        if time_s is not None:  # a move's samples come every physics step: fewer will do
            if 0.0 <= time_s - self.bodies_s < 1.0 / BODY_RATE_HZ:
                return
            self.bodies_s = time_s
        log_poses(self.rec, self.model, data, self.geometry)

    def entropy(self, bits: float) -> None:
        """The mapped region's mean entropy after a view (bits per voxel)."""
        if self.rec is not None:
            self.rec.log("mapping/region_entropy_bits", rr.Scalars(bits))

    def targets(self, names: list[str], positions: np.ndarray, radii: list[float]) -> None:
        """The targets as red discs, each labelled on a stem above it: the labels stand
        at heights ``label_m`` apart (in order along the world's x), so that targets a
        few centimetres apart keep legible labels."""
        if self.rec is None or not names:
            return
        self.rec.log("world/targets", rr.Points3D(positions, radii=radii, colors=[255, 60, 60]),
                     static=True)
        order = np.argsort(positions[:, 0], kind="stable")
        lifted = positions.copy()
        lifted[order, 2] = positions[:, 2].max() + self.label_m * np.arange(1, len(names) + 1)
        self.rec.log("world/targets/labels",
                     rr.Points3D(lifted, radii=0.004, labels=names, colors=[255, 60, 60]),
                     static=True)
        self.rec.log("world/targets/stems",
                     rr.LineStrips3D(np.stack([positions, lifted], axis=1), radii=0.0015,
                                     colors=[255, 60, 60, 160]), static=True)

    def camera(self, robot: str, T_world_mjcam: np.ndarray, pinhole: Pinhole,
               rgb: np.ndarray | None = None, depth: np.ndarray | None = None) -> None:
        """A camera's pose and intrinsics (its frustum drawn ``frustum_m`` deep), with
        what it saw: its ``rgb`` image (see :meth:`image`) or, without one, its ``depth``
        (m; a mapping view's), which takes the place of the image before."""
        if self.rec is None:
            return
        T = opencv_pose(T_world_mjcam)
        path = f"world/{robot}/camera"
        self.rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log(path, rr.Pinhole(image_from_camera=pinhole.matrix,
                                      resolution=[pinhole.width, pinhole.height],
                                      camera_xyz=rr.ViewCoordinates.RDF,
                                      image_plane_distance=self.frustum_m))
        if rgb is not None:
            self.image(robot, rgb)
        elif depth is not None:
            self.rec.log(f"{path}/rgb", rr.Clear(recursive=True))
            self.rec.log(f"{path}/depth", rr.DepthImage(np.where(np.isfinite(depth), depth, 0.0),
                                                        meter=1.0))

    def image(self, robot: str, rgb: np.ndarray) -> None:
        """The latest image a robot's camera took (its left one, h x w x 3 uint8), in
        place of the one before, of what was found there and of a depth image."""
        if self.rec is None:
            return
        path = f"world/{robot}/camera/rgb"
        self.rec.log(f"world/{robot}/camera/depth", rr.Clear(recursive=False))
        self.rec.log(f"{path}/found", rr.Clear(recursive=True))
        self.rec.log(path, rr.Image(rgb))

    def mapped(self, robots: list[str]) -> None:
        """Mapping is over: its views' frusta go."""
        if self.rec is not None:
            for robot in robots:
                self.rec.log(f"world/{robot}/views", rr.Clear(recursive=False))

    def grid(self, grid: OccupancyGrid) -> None:
        """Occupied voxels (P > 0.5) as boxes coloured by probability; if the recorder was
        made with ``unknown``, never-observed voxels too, as small grey points under
        ``world/grid/unknown``."""
        if self.rec is None:
            return
        p = grid.probability()
        idx = np.argwhere(p > 0.5)
        half = np.full((len(idx), 3), grid.resolution / 2)
        self.rec.log("world/grid", rr.Boxes3D(centers=grid.centers(idx), half_sizes=half,
                                              colors=_colormap(2 * p[tuple(idx.T)] - 1),
                                              fill_mode="solid"))
        if self.unknown:
            self.rec.log("world/grid/unknown",
                         rr.Points3D(grid.centers(np.argwhere(grid.log_odds == 0)),
                                     radii=grid.resolution / 6, colors=[150, 150, 150]))

    def view(self, robot: str, T_world_cam: np.ndarray, pinhole: Pinhole, depth: float,
             gain: float) -> None:
        """A mapping view: its frustum (OpenCV pose) out to ``depth`` m or ``frustum_m``,
        whichever is nearer, and its gain."""
        if self.rec is None:
            return
        depth = min(depth, self.frustum_m)
        corners = np.array([[0, 0], [pinhole.width - 1, 0], [pinhole.width - 1,
                            pinhole.height - 1], [0, pinhole.height - 1]], dtype=float)
        rays = np.column_stack([(corners[:, 0] - pinhole.cx) / pinhole.fx,
                                (corners[:, 1] - pinhole.cy) / pinhole.fy, np.ones(4)])
        far = rays * depth @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
        apex = T_world_cam[:3, 3]
        strips = [[apex, c] for c in far] + [[*far, far[0]]]
        self.rec.log(f"world/{robot}/views", rr.LineStrips3D(strips, colors=[90, 200, 255]))
        if not np.isnan(gain):
            self.rec.log(f"mapping/gain_bits/{robot}", rr.Scalars(gain))

    def candidates(self, robot: str, positions: np.ndarray, totals: np.ndarray) -> None:
        """The rated candidates (n x 3, m; their ratings RF), coloured on :data:`SCALE`
        by their rank among those rated above 0 (a dome of many poor views and a few good
        ones is told apart so), those rated 0 small and grey; under
        ``candidates/legend`` the scale as a bar above them, labelled at its ends with
        the ratings its colours stand for (the lowest rated, the median, the best). Each
        robot's legend stands ``label_m`` above the one before."""
        if self.rec is None or len(totals) == 0:
            return
        rated = totals > 0
        values = np.sort(totals[rated])
        rank = (np.searchsorted(values, totals, side="left") / max(len(values) - 1, 1)
                if len(values) else np.zeros(len(totals)))
        colours = np.where(rated[:, None], _colormap(rank), np.array(UNRATED, np.uint8))
        self.rec.log(f"world/{robot}/candidates",
                     rr.Points3D(positions, colors=colours, radii=np.where(rated, 0.01, 0.004)))
        if not len(values):
            return
        low, high = positions.min(axis=0), positions.max(axis=0)
        ticks = np.linspace(0.0, 1.0, 21)
        self.legends += 1
        bar = np.column_stack([low[0] + ticks * max(high[0] - low[0], 6 * self.label_m),
                               np.full_like(ticks, (low[1] + high[1]) / 2),
                               np.full_like(ticks, high[2] + self.label_m * self.legends)])
        labels = [""] * len(ticks)
        labels[0] = f"{robot}: RF {values[0]:.3g} (grey: 0)"
        labels[-1] = f"best RF {values[-1]:.3g} (median {float(np.median(values)):.3g})"
        self.rec.log(f"world/{robot}/candidates/legend",
                     rr.Points3D(bar, colors=_colormap(ticks), radii=0.012, labels=labels))

    def hulls(self, robot: str, hulls: list) -> None:
        """The expanded occluder hulls the chosen target was rated against."""
        if self.rec is None or not hulls:
            return
        tris = np.concatenate([h.triangles for h in hulls]).reshape(-1, 3)
        self.rec.log(f"world/{robot}/hulls",
                     rr.Mesh3D(vertex_positions=tris,
                               triangle_indices=np.arange(len(tris)).reshape(-1, 3),
                               albedo_factor=[0.9, 0.3, 0.3, 0.35]))

    def motion(self, robot: str, time_s: float, data: mujoco.MjData,
               T_world_mjcam: np.ndarray) -> None:
        """The world during a robot's move, on the ``sim_time`` timeline: the bodies'
        poses and the camera's."""
        if self.rec is not None:
            self.rec.set_time("sim_time", duration=time_s)
        self.bodies(data, time_s)
        if self.rec is None:
            return
        T = opencv_pose(T_world_mjcam)
        self.rec.log(f"world/{robot}/camera", rr.Transform3D(translation=T[:3, 3],
                                                             mat3x3=T[:3, :3]))

    def fiducials(self, robot: str, correction: Correction,
                  image: np.ndarray | None = None) -> None:
        """The fiducials a camera's pose was corrected from: 3-sigma covariance ellipsoids
        in the world, their tracks through the move over the final frame's left
        ``image`` (the camera's latest), and the corrected camera pose."""
        if self.rec is None:
            return
        if image is not None:
            self.image(robot, image)
        if not correction.used:
            return
        centres, halves, quats = [], [], []
        for f in correction.used:
            w, V = np.linalg.eigh(f.covariance)
            if np.linalg.det(V) < 0:
                V[:, 0] = -V[:, 0]
            centres.append(f.position)
            halves.append(3 * np.sqrt(np.maximum(w, 0.0)))
            quats.append(Rotation.from_matrix(V).as_quat())  # x, y, z, w
        self.rec.log(f"world/{robot}/fiducials",
                     rr.Ellipsoids3D(centers=centres, half_sizes=halves, quaternions=quats,
                                     colors=[240, 80, 200]))
        # thin, so that the image stays visible beneath
        self.rec.log(f"world/{robot}/camera/rgb/found/fiducials",
                     rr.Points2D([f.pixel for f in correction.used], radii=1.5,
                                 colors=[240, 80, 200]))
        self.rec.log(f"world/{robot}/camera/rgb/found/fiducial_tracks",
                     rr.LineStrips2D([np.array(f.track) for f in correction.used],
                                     radii=0.5, colors=[240, 80, 200, 160]))
        if correction.pose is not None:
            T = opencv_pose(correction.pose)
            self.rec.log(f"world/{robot}/corrected_camera",
                         rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
            self.rec.log(f"world/{robot}/corrected_camera/axes",
                         rr.Arrows3D(vectors=0.1 * np.eye(3), colors=[[255, 0, 0], [0, 255, 0],
                                                                      [0, 0, 255]]))

    def panel(self, time_s: float, data: mujoco.MjData, true: np.ndarray,
              measured: np.ndarray | None, displacement_m: float | None = None) -> None:
        """The panel during the task, on the ``sim_time`` timeline: the bodies' poses, its
        true bottom-edge centre, where the cameras measured it, and the measured distance
        to its slot."""
        if self.rec is not None:
            self.rec.set_time("sim_time", duration=time_s)
        self.bodies(data, time_s)
        if self.rec is None:
            return
        self.rec.log("world/panel/true", rr.Points3D([true], radii=0.006, colors=[60, 220, 60]))
        if measured is not None:
            self.rec.log("world/panel/measured",
                         rr.Points3D([measured], radii=0.006, colors=[230, 60, 60]))
            self.rec.log("task/measurement_error_m",
                         rr.Scalars(float(np.linalg.norm(measured - true))))
        if displacement_m is not None:
            self.rec.log("task/displacement_m", rr.Scalars(displacement_m))

    def task_view(self, time_s: float, cameras: list[Camera], pairs: dict[str, Any],
                  fits: dict[str, Relative]) -> None:
        """Each camera's left image during the task (its latest, on the ``sim_time``
        timeline too) with the edge points its fits matched, under ``rgb/found``: the
        panel's in yellow, the slot's walls' in cyan (they lie on the fitted models'
        edges)."""
        if self.rec is None:
            return
        self.rec.set_time("sim_time", duration=time_s)
        for cam in cameras:
            name = cam.robot.name
            pair = pairs.get(name)
            if pair is None or isinstance(pair, str):
                continue
            self.image(name, pair.left)
            found = fits.get(name)
            for part, fit, colour in (("panel", None if found is None else found.object_fit,
                                       [250, 220, 40]),
                                      ("slot", None if found is None else found.goal_fit,
                                       [40, 220, 250])):
                if fit is not None and fit.matched:
                    self.rec.log(f"world/{name}/camera/rgb/found/{part}",
                                 rr.Points2D(fit.matched[0], radii=0.8, colors=colour))

    def planned_path(self, robot: str, base: np.ndarray, camera: np.ndarray) -> None:
        """A planned move: its base's way on the floor (k, 2; m) and its camera's (n, 3)."""
        if self.rec is None or len(base) == 0:
            return
        floor = np.column_stack([base, np.full(len(base), 0.01)])
        self.rec.log(f"world/{robot}/planned/base", rr.LineStrips3D([floor], colors=[70, 130, 230]))
        self.rec.log(f"world/{robot}/planned/camera", rr.LineStrips3D([camera],
                                                                      colors=[150, 90, 230]))

    def chosen(self, robot: str, position: np.ndarray, target: np.ndarray, label: str) -> None:
        """The placement chosen: an arrow from the camera's ``position`` to its
        ``target`` (m), labelled ``<robot> -> <label>`` at the camera's end, away from
        the targets' own labels."""
        if self.rec is None:
            return
        self.rec.log(f"world/{robot}/chosen",
                     rr.Arrows3D(origins=[position], vectors=[target - position],
                                 colors=[60, 220, 90]))
        self.rec.log(f"world/{robot}/chosen/label",
                     rr.Points3D([position], radii=0.004, labels=[f"{robot} -> {label}"],
                                 colors=[20, 120, 40]))  # dark: legible on a label's grey

    def close(self) -> None:
        if self.film is not None:
            self.film.close()
            self.film = None
        if self.rec is not None:
            self.rec.flush()
            self.rec.disconnect()
            self.rec = None
