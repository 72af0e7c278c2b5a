"""The pose corrector: takes a stereo frame whenever the camera has moved enough along
a move, tracks the fiducials through them, and at the goal estimates the camera's pose
from them (sec. 2.4; the method is told in sim/stages/correction.py)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import cv2
import mujoco
import numpy as np

from taskcam.calibration.ekf import FiducialFilter, StereoCamera
from taskcam.calibration.fiducials import (
    Candidate,
    certainty,
    depth_contrast,
    pick,
    rate,
    visual_contrast,
)
from taskcam.calibration.pose import (
    METHODS,
    DegenerateGeometryError,
    estimate_pose,
    invert,
    rotation_deg,
)
from taskcam.calibration.stereo_features import FeatureFinder, StereoFeatures
from taskcam.calibration.targets import to_gray
from taskcam.calibration.tracker_settings import TrackerSettings
from taskcam.calibration.tracking import FiducialTracker, Frame
from taskcam.mapping import OccupancyGrid, Pinhole, mujoco_pose, opencv_pose
from taskcam.sim.config.stages import CorrectionConfig
from taskcam.sim.stages.correction import Correction, UsedFiducial, distrust
from taskcam.sim.stages.timer import Timer
from taskcam.sim.world.render import Renderer, camera_pose
from taskcam.sim.world.scene import Robot, Scene

WIDER = 3.0  # the final frame's second search: this many times search_px and max_jump
OWN_DOWNSCALE = 4  # the robots' bodies are masked from a segmentation at 1/4 resolution


class PoseCorrector:
    """Takes the frames of each move and corrects the camera's pose at its end."""

    def __init__(self, scene: Scene, belief: mujoco.MjData, world: mujoco.MjData,
                 renderer: Renderer, pinhole: Pinhole, baseline_m: float,
                 grid: OccupancyGrid, config: CorrectionConfig) -> None:
        self.scene, self.belief, self.world = scene, belief, world
        self.renderer, self.pinhole, self.grid, self.cfg = renderer, pinhole, grid, config
        self.camera = StereoCamera(pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy, baseline_m)
        self.settings = TrackerSettings(detector=config.detector, stereo=config.stereo,
                                        features=config.features,
                                        search_px=config.search_px,
                                        pixel_sigma=config.pixel_sigma)
        self.finder = FeatureFinder(self.settings)
        self.robot_geoms = scene.robot_geoms()
        self._scratch = scene.make_data()
        self._tracker: FiducialTracker | None = None
        self._last_left = np.zeros((pinhole.height, pinhole.width, 3), np.uint8)
        self._last_measured = np.eye(4)  # the measured camera pose at the last frame
        self._joints = np.zeros(0)  # the latest measured joints
        self._last_located = np.eye(4)  # g01 of the last located frame ...
        self._located_measured = np.eye(4)  # ... and the measured camera pose then
        self._located_joints = np.zeros(0)  # ... and the measured joints then
        self._found: StereoFeatures | None = None  # the last frame's features
        self._retraced = False  # the move is being gone over again (frames twice as dense)
        self._start_sd = (0.0, 0.0)  # of the pose the move started from
        self._goal_measured = np.eye(4)  # the camera pose the joints' goal puts it at
        self._timer = Timer()  # wall seconds of this move's correction, by part
        self._kinds = Timer()  # ... and its frames' (and how many), by why each was taken

    @property
    def last_left(self) -> np.ndarray:
        """The left image (h x w x 3 uint8) of the last frame taken."""
        return self._last_left

    # ------------------------------------------------------------ along the move

    def nominal_pose(self, robot: Robot, joints: np.ndarray) -> np.ndarray:
        """The camera pose (OpenCV convention) of the nominal model at ``joints``."""
        d = self._scratch
        d.qpos[:] = self.belief.qpos
        d.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(self.scene.model, d)
        mujoco.mj_camlight(self.scene.model, d)
        return opencv_pose(camera_pose(d, robot.camera))

    def begin(self, robot: Robot, path: np.ndarray,
              start: tuple[np.ndarray, tuple[float, float]] | None = None) -> None:
        """The first frame of a move along ``path`` (k, 9 joints), at the pose before it:
        ``start`` (the camera pose the robot believes, MuJoCo convention, and its standard
        deviation in m and deg), or where the joints put it when no move has made an
        error yet."""
        self._tracker = FiducialTracker(self.camera, self.settings)
        self._timer, self._kinds = Timer(), Timer()
        start_joints = path[0]
        self._goal_measured = self.nominal_pose(robot, path[-1])
        measured = self.nominal_pose(robot, start_joints)  # frames are predicted from it
        T = measured if start is None else opencv_pose(start[0])
        self._start_sd = (0.0, 0.0) if start is None else start[1]
        with self._kinds("first"):
            found = self._look(robot)
            with self._timer("track"):  # its fiducials seeded
                frame = self._tracker.start(found, invert(T))
        self._last_measured = self._located_measured = measured
        self._last_located = frame.g01
        self._joints = np.array(start_joints, copy=True)
        self._located_joints = self._joints.copy()
        self._retraced = False

    def on_sample(self, robot: Robot) -> Callable[[float, np.ndarray], None]:
        """A callback for the mover, given the measured joints: a frame whenever the
        view is predicted to need one (:meth:`_due`)."""

        def sample(t: float, measured: np.ndarray) -> None:
            self._joints = np.array(measured, copy=True)
            T = self.nominal_pose(robot, measured)
            kind = self._due(T)
            if kind:
                self._frame(robot, T, kind)
        return sample

    def _due(self, T_measured: np.ndarray) -> str:
        """Which frame the camera, where the joints put it, needs; "" if none. With
        ``frames = "overlap"``: a ``"track"`` frame when fewer than ``frame_overlap`` of
        the last located frame's fiducials are predicted findable from the predicted pose
        (after a frame that was not located, only once the camera has also moved the fixed
        rule's step and is expected to see enough of them to be located:
        :meth:`_relocatable`), and a ``"goal view"`` at the fixed rule's step while the
        view shares that much with the goal's: the fiducials the final pose is estimated
        from are then measured from many views, which their positions average (each
        frame's pixel noise is its own). With ``"track"``: as ``"overlap"``, without the
        goal views. With ``"fixed"``: a ``"step"`` when it has turned ``frame_every_deg``
        or moved ``frame_every_m`` since the last frame. On a retrace frames are twice as
        dense."""
        assert self._tracker is not None, "begin() first"
        cfg, last = self.cfg, self._last_measured
        denser = 2.0 if self._retraced else 1.0
        stepped = (rotation_deg(last, T_measured) >= cfg.frame_every_deg / denser
                   or np.linalg.norm(T_measured[:3, 3] - last[:3, 3]) >= cfg.frame_every_m / denser)
        if cfg.frames == "fixed":
            return "step" if stepped else ""
        size = (self.pinhole.width, self.pinhole.height)
        if not self._tracker.frames[-1].located:
            return "track" if stepped and self._relocatable(
                self._tracker.overlap(self._predict(T_measured), size)) else ""
        wanted = 1 - (1 - cfg.frame_overlap) / denser
        if self._tracker.overlap(self._predict(T_measured), size) < wanted:
            return "track"
        near_goal = cfg.frames == "overlap" and stepped and self._tracker.overlap(
            self._predict(self._goal_measured), size) >= cfg.frame_overlap
        return "goal view" if near_goal else ""

    def _relocatable(self, overlap: float) -> bool:
        """Whether a frame with this predicted overlap (with the last located frame) is
        expected to find enough of its fiducials to be located: a frame is located from
        ``min_inliers`` of them. Once a track is lost, a frame is taken only then (and
        at the goal): out there the camera sees none it knows, and a lost track used to
        take a frame at every step of the move's rest (hundreds on a base's drive)."""
        assert self._tracker is not None, "begin() first"
        last = self._tracker.last_located
        return overlap * len(last.observations) >= self.settings.min_inliers

    def _predict(self, T_measured: np.ndarray) -> np.ndarray:
        """The camera's g01 predicted for the joints' camera pose ``T_measured``: the last
        located frame's, moved as the joints say since."""
        motion = invert(self._located_measured) @ T_measured
        return invert(invert(self._last_located) @ motion)

    def _frame(self, robot: Robot, T_measured: np.ndarray, kind: str,
               wider: float | None = None) -> bool:
        """Takes a frame of a ``kind`` (why it is taken: :meth:`_due`, or "final") or,
        ``wider``, tracks the last again that much further afield; whether it was
        located."""
        with self._kinds(kind):
            return self._take(robot, T_measured, wider)

    def _take(self, robot: Robot, T_measured: np.ndarray, wider: float | None) -> bool:
        assert self._tracker is not None, "begin() first"
        predicted = self._predict(T_measured)
        if wider is None:
            size = (self.pinhole.width, self.pinhole.height)
            self._found = self._look(robot, self._tracker.expected(predicted, size))
        assert self._found is not None, "a frame first"
        with self._timer("track"):
            frame = (self._tracker.add(self._found, predicted) if wider is None
                     else self._tracker.retry(self._found, predicted, wider))
        self._last_measured = T_measured
        if frame.located:
            self._last_located, self._located_measured = frame.g01, T_measured
            self._located_joints = self._joints.copy()
        return frame.located

    def _search_wider(self, robot: Robot) -> bool:
        """The last frame tracked again, its fiducials looked for ``WIDER`` times as far
        from their predicted pixels and its pose allowed as much further from the
        prediction; whether it was located."""
        return self._frame(robot, self._last_measured, "wider search", WIDER)

    @property
    def frames_taken(self) -> int:
        """How many frames this move's correction has taken so far."""
        return 0 if self._tracker is None else len(self._tracker.frames)

    def retrace(self, path: np.ndarray, back_to: np.ndarray) -> np.ndarray:
        """The way (k, 9) back along ``path`` to its waypoint nearest the joints
        ``back_to`` (where a frame was last located) and forth again to the goal; frames
        are taken twice as densely on it."""
        k = min(int(np.argmin(np.linalg.norm(path - back_to, axis=1))), len(path) - 2)
        self._retraced = True
        return np.vstack([path[k:][::-1], path[k + 1:]])

    def _look(self, robot: Robot, expected: np.ndarray | None = None) -> StereoFeatures:
        """The stereo pair's features; more of them where the known fiducials are
        ``expected`` ((u, v, disparity), m x 3)."""
        r, d = self.renderer, self.world
        with self._timer("render"):
            left, right = r.rgb(d, robot.camera), r.rgb(d, robot.right_camera)
            own = self._own(robot.camera)
        self._last_left = left
        with self._timer("features"):
            # a right keypoint on a robot can only pair with a left one there, already out
            return self.finder.stereo(left, right, own, expected)

    def _own(self, camera: str) -> np.ndarray:
        """The robots' bodies in ``camera``'s image (h, w bool), from a segmentation at
        1/OWN_DOWNSCALE of the resolution grown by a block (a body's edge may lie anywhere
        in a block): keypoints are kept farther than that from them anyway."""
        k = OWN_DOWNSCALE
        seen = self.renderer.segmentation(self.world, camera, downscale=k)
        coarse = ((seen >= 0) & self.robot_geoms[np.maximum(seen, 0)]).astype(np.uint8)
        grown = cv2.dilate(coarse, np.ones((3, 3), np.uint8))
        full = np.zeros((self.pinhole.height, self.pinhole.width), bool)
        fine = np.repeat(np.repeat(grown, k, axis=0), k, axis=1).astype(bool)
        full[:fine.shape[0], :fine.shape[1]] = fine
        return full

    # ------------------------------------------------------------ at the goal

    def finish(self, robot: Robot, last_try: bool = True) -> Correction:
        """The last frame, at the goal after settling; the corrected pose from it. If the
        frame cannot be located even by a wider search, the result has ``retrace_from``
        (the joints to go back to) unless ``last_try``; :meth:`retrace` then prepares the
        way back and forth, and ``finish`` is called again. ``seconds`` holds the wall
        time of the move's correction so far, by part (render, features, track, bundle,
        estimate)."""
        out = self._finish(robot, last_try)
        return replace(out, seconds=self._timer.rounded(4), frames_by_kind=self._kinds.counted(4))

    def _finish(self, robot: Robot, last_try: bool) -> Correction:
        tracker = self._tracker
        assert tracker is not None, "begin() first"
        tried = ["wider search", "retrace"] if self._retraced else []
        located = self._frame(robot, self.nominal_pose(robot, self._joints), "final")
        if not located:
            if not self._retraced:
                tried.append("wider search")
            located = self._search_wider(robot)
        out = Correction(tried=tried, start_sd=self._start_sd,
                         recovered_by=tried[-1] if located and tried else "",
                         frames=len(tracker.frames),
                         located=sum(f.located for f in tracker.frames),
                         fiducials_tracked=len(tracker.fiducials))
        if not located:
            out = replace(out, reason="too few fiducials found again in the final frame")
            if not last_try and not self._retraced:
                return replace(out, retrace_from=self._located_joints.copy())
        self._tracker = None
        if not located:
            return out
        with self._timer("bundle"):
            bundle, frames, kept = tracker.solve()
        cov = bundle.pose_cov[-1]
        out = replace(out, bundle_rms_px=bundle.rms_px,
                      bundle_pose=mujoco_pose(invert(bundle.poses[-1])),
                      pose_sd=(float(np.sqrt(np.trace(cov[3:, 3:]))),
                               math.degrees(float(np.sqrt(np.trace(cov[:3, :3]))))))
        with self._timer("estimate"):
            return self._estimate(out, tracker, bundle.poses, bundle.pose_cov, frames, kept)

    def _estimate(self, out: Correction, tracker: FiducialTracker, poses: list[np.ndarray],
                  pose_cov: list[np.ndarray], frames: list[Frame], kept: np.ndarray
                  ) -> Correction:
        """The final pose from the final frame's best-rated fiducials (eq. 8, 10-12), by
        the scenario's estimator and, for comparison, the others."""
        candidates, filters, ids = self._rated(frames, poses, pose_cov, kept)
        chosen = pick(candidates, self.cfg.fiducials)
        if not chosen:
            return replace(out, reason="no fiducial of the final frame was seen before")
        position = {id(c): k for k, c in enumerate(candidates)}
        index = [position[id(c)] for c in chosen]
        fids = [filters[k] for k in index]
        zs = np.array([frames[-1].observations[ids[k]] for k in index])
        world = np.array([f.x for f in fids])
        cameras = np.array([self.camera.point(z) for z in zs])
        try:
            estimate = estimate_pose(world, cameras, zs[:, :2], tracker.K, self.cfg.estimator)
        except DegenerateGeometryError as exc:
            return replace(out, reason=str(exc))
        out = replace(out, estimate=estimate, pose=mujoco_pose(estimate.pose))
        others: dict[str, np.ndarray] = {}
        for method in METHODS:  # the same fiducials by every estimator, for comparison
            if method != estimate.method:
                try:
                    other = estimate_pose(world, cameras, zs[:, :2], tracker.K, method)
                except DegenerateGeometryError:
                    continue
                if other.method == method:
                    others[method] = mujoco_pose(other.pose)
        used = [UsedFiducial(f.x, f.covariance, z[:2], float(z[2]), c.rating,
                             tracker.fiducials.tracks[ids[k]])
                for f, z, c, k in zip(fids, zs, chosen, index, strict=True)]
        return replace(out, reason=distrust(out), others=others, used=used)

    def _rated(self, frames: list[Frame], poses: list[np.ndarray], pose_cov: list[np.ndarray],
               kept: np.ndarray) -> tuple[list[Candidate], list[FiducialFilter], list[int]]:
        """The final frame's fiducials seen before: each an EKF over its earlier
        measurements (eq. 10-12), rated by eq. 8 at its place in the final image."""
        cfg = self.cfg
        final = frames[-1]
        known = set(int(i) for i in kept)
        p = self.grid.probability()
        gray = to_gray(self._last_left)
        candidates, filters, ids = [], [], []
        in_voxel: dict[tuple[int, ...], tuple[float, float]] = {}  # certainty, depth contrast
        for i, z in final.observations.items():
            if i not in known:
                continue
            earlier = [(k, f.observations[i]) for k, f in enumerate(frames[:-1])
                       if i in f.observations]
            if not earlier:
                continue
            k0, z0 = earlier[0]
            ekf = FiducialFilter(self.camera, z0, poses[k0], cfg.pixel_sigma,
                                 math.sqrt(2) * cfg.pixel_sigma, pose_cov[k0])
            for k, zk in earlier[1:]:
                ekf.update(zk, poses[k], pose_cov[k])
            x = ekf.x
            voxel = tuple(int(k) for k in self.grid.index(x[None])[0])
            if voxel not in in_voxel:  # the map's terms depend on the voxel alone
                in_voxel[voxel] = (certainty(self.grid, p, x), depth_contrast(self.grid, p, x))
            sure, depth = in_voxel[voxel]
            candidates.append(Candidate(z[:2], float(z[2]), sure, visual_contrast(gray, z[:2]),
                                        depth))
            filters.append(ekf)
            ids.append(i)
        rate(candidates)
        return candidates, filters, ids
