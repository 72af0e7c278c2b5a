"""The rerun recording of an episode: the world and its moving bodies, cameras, images,
depth, grid, ratings, choices, and a layout to open it on.

Entity paths: ``world/scene`` (every drawn geom under its body: sim/stages/scene_record.py),
``world/grid`` (the occupancy map, beside the true geometry: hide either),
``world/targets``, ``world/<robot>/camera`` (a pinhole with ``rgb`` and ``depth`` beneath
it), ``world/<robot>/task/left`` (its left image during the task, with the edges its fits
matched), ``world/<robot>/candidates``, ``world/<robot>/chosen``; plots under ``mapping``
(the region's entropy, each view's gain) and ``task`` (the measured displacement).
Everything is on the ``step`` timeline; the robots' moves and the task are on the
``sim_time`` timeline too. Quaternions go to rerun as x, y, z, w.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from mapping import OccupancyGrid, Pinhole, opencv_pose
from sim.stages.scene_record import SceneGeometry, log_geometry, log_poses

if TYPE_CHECKING:
    import mujoco

    from calibration.displacement import Relative
    from sim.stages.correction import Correction
    from sim.stages.overview import Film
    from sim.stages.task_result import Camera


BODY_RATE_HZ = 30.0  # moving bodies' poses are logged at most this often in simulated time


def _colormap(values: np.ndarray) -> np.ndarray:
    """Blue (low) to yellow (high), uint8 RGB, for values in [0, 1]."""
    v = np.clip(np.nan_to_num(values), 0.0, 1.0)[:, None]
    low, high = np.array([40, 60, 200]), np.array([250, 220, 30])
    return (low + v * (high - low)).astype(np.uint8)


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
              task: bool, eye: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The world's geometry and its bodies where they are now, and the layout the
        recording opens on (see :func:`layout`; ``eye``, the 3-D view's position and the
        point it looks at); later poses come with :meth:`bodies`."""
        if self.film is not None:
            self.film.frame(data, None)
        if self.rec is None:
            return
        self.model = model
        self.geometry = log_geometry(self.rec, model, data)
        self.rec.send_blueprint(layout(robots, task, eye))

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
        if self.rec is not None:
            self.rec.log("world/targets", rr.Points3D(positions, radii=radii, labels=names,
                                                      colors=[255, 60, 60]), static=True)

    def camera(self, robot: str, T_world_mjcam: np.ndarray, pinhole: Pinhole,
               rgb: np.ndarray | None = None, depth: np.ndarray | None = None) -> None:
        """A camera's pose and intrinsics, with what it saw."""
        if self.rec is None:
            return
        T = opencv_pose(T_world_mjcam)
        path = f"world/{robot}/camera"
        self.rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log(path, rr.Pinhole(image_from_camera=pinhole.matrix,
                                      resolution=[pinhole.width, pinhole.height],
                                      camera_xyz=rr.ViewCoordinates.RDF))
        if rgb is not None:
            self.rec.log(f"{path}/rgb", rr.Image(rgb))
        if depth is not None:
            self.rec.log(f"{path}/depth", rr.DepthImage(np.where(np.isfinite(depth), depth, 0.0),
                                                        meter=1.0))

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
        """A mapping view: its frustum (OpenCV pose) out to ``depth`` m, and its gain."""
        if self.rec is None:
            return
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
        if self.rec is None:
            return
        scale = totals / totals.max() if len(totals) and totals.max() > 0 else totals
        self.rec.log(f"world/{robot}/candidates",
                     rr.Points3D(positions, colors=_colormap(scale), radii=0.01))

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

    def fiducials(self, robot: str, correction: Correction) -> None:
        """The fiducials a camera's pose was corrected from: 3-sigma covariance ellipsoids
        in the world, their tracks through the move over the camera's last image, and
        the corrected camera pose."""
        if self.rec is None or not correction.used:
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
        self.rec.log(f"world/{robot}/camera/rgb/fiducials",
                     rr.Points2D([f.pixel for f in correction.used], radii=1.5,
                                 colors=[240, 80, 200]))
        self.rec.log(f"world/{robot}/camera/rgb/fiducial_tracks",
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
        """Each camera's left image during the task (``world/<robot>/task/left``, on the
        ``sim_time`` timeline) with the edge points its fits matched: the panel's in
        yellow, the slot's walls' in cyan (they lie on the fitted models' edges)."""
        if self.rec is None:
            return
        self.rec.set_time("sim_time", duration=time_s)
        for cam in cameras:
            name = cam.robot.name
            pair = pairs.get(name)
            path = f"world/{name}/task/left"
            if pair is None or isinstance(pair, str):
                continue
            self.rec.log(path, rr.Image(pair.left))
            found = fits.get(name)
            for part, fit, colour in (("panel", None if found is None else found.object_fit,
                                       [250, 220, 40]),
                                      ("slot", None if found is None else found.goal_fit,
                                       [40, 220, 250])):
                if fit is None or not fit.matched:
                    self.rec.log(f"{path}/{part}", rr.Clear(recursive=True))
                    continue
                self.rec.log(f"{path}/{part}/matched",
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
        if self.rec is not None:
            self.rec.log(f"world/{robot}/chosen",
                         rr.Arrows3D(origins=[position], vectors=[target - position],
                                     labels=[label], colors=[60, 220, 90]))

    def close(self) -> None:
        if self.film is not None:
            self.film.close()
            self.film = None
        if self.rec is not None:
            self.rec.flush()
            self.rec.disconnect()
            self.rec = None


def layout(robots: list[str], task: bool, eye: tuple[np.ndarray, np.ndarray] | None = None
           ) -> rrb.Blueprint:
    """The layout a recording opens on: the 3-D world large (seen from ``eye``: its
    position and the point it looks at, m; the depth images, drawn there as point clouds,
    left out); beside it each robot's left image with what was found in it (during the
    task, its fitted edges; else the fiducials of its pose correction); below, the
    mapped region's entropy and the task's displacement. It opens on the ``step``
    timeline, where both plots have their data (each mapping view and each task step is
    a step; the moves play on ``sim_time``); the occupancy grid, the rated candidates and
    the occluder hulls start hidden."""
    image = "task/left" if task else "camera/rgb"
    cameras = [rrb.Spatial2DView(origin=f"world/{r}/{image}", name=f"{r}: left image")
               for r in robots]
    controls = None if eye is None else rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital, position=eye[0], look_target=eye[1], eye_up=[0.0, 0.0, 1.0])
    world = rrb.Spatial3DView(origin="world", name="world", eye_controls=controls,
                              contents=["+ $origin/**",
                                        *(f"- world/{r}/camera/depth" for r in robots)],
                              # the map and the ratings hide the scene: shown on request
                              overrides={path: rrb.EntityBehavior(visible=False) for path in
                                         ["world/grid", *(f"world/{r}/{part}" for r in robots
                                                          for part in ("candidates", "hulls"))]})
    plots = rrb.Horizontal(
        rrb.TimeSeriesView(origin="mapping/region_entropy_bits",
                           name="mapping: the region's entropy (bits a voxel)"),
        rrb.TimeSeriesView(origin="task", name="task: displacement, measurement error (m)"))
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(world, rrb.Vertical(*cameras), column_shares=[3, 1]),
                     plots, row_shares=[3, 1]),
        rrb.TimePanel(timeline="step"),
        collapse_panels=True)
