"""Correcting a camera's pose from natural fiducials after its robot moved (sec. 2.4).

Along the move, whenever the camera has turned ``frame_every_deg`` or moved
``frame_every_m`` since the last frame (by the joints as the robot measures them), the
head takes a stereo frame; the fiducials are tracked through the frames
(calibration/tracking.py), starting from the pose before the move, which is known. Each
frame's pose is predicted from the last located one moved as the measured joints say;
what the encoders and odometry cannot see (their offsets, wheel slip, the mount's tilt)
changes little between frames. At the goal, once the arm has settled, a last frame is taken and
the frames are bundle-adjusted. The fiducials the last frame sees are then estimated as
the paper does: an EKF each over its measurements in the earlier frames, the frames'
pose uncertainty folded into the measurement noise (eq. 10-12); rated by eq. 8 and
picked apart from each other; and the camera's pose estimated from them by the
scenario's estimator (eq. 5-6, Kabsch or SQPnP), with its fallbacks.

When the final frame cannot be located, the corrector recovers as a real system would:
it searches that frame again ``WIDER`` times as far from the prediction, and failing
that the robot goes back along its path to where it last located a frame and forth
again, with frames twice as dense (the episode drives it: :meth:`PoseCorrector.retrace`).
A move starts from where the robot believes its camera is: exactly known before its
first move, afterwards the last correction's pose (the frames are tied to it, so its
uncertainty is carried into this correction's). A correction is trusted (``corrected``)
when it holds the correction's accuracy (``ACCURACY_M``, ``ACCURACY_DEG``): its estimate
and the bundle adjustment's own pose agree to within it, and the bundle's error bound
at 95 % (from its standard deviation, scaled to the errors measured, with the start's)
plus the two estimates' distance is inside it too. Otherwise it is
``uncertain``; one that fails says why, and the camera keeps its commanded pose with
that pose's prior uncertainty (:func:`prior_pose_sd`) for whatever uses it.

Only images, the measured joints and the map are used: never the simulator's truth.
The robots' own bodies are masked out of the images (they know their joint states).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from calibration.ekf import FiducialFilter, StereoCamera
from calibration.fiducials import Candidate, certainty, depth_contrast, pick, rate, visual_contrast
from calibration.pose import (
    METHODS,
    DegenerateGeometryError,
    PoseEstimate,
    estimate_pose,
    invert,
    rotation_deg,
)
from calibration.targets import to_gray
from calibration.tracking import (
    FeatureFinder,
    FiducialTracker,
    Frame,
    StereoFeatures,
    TrackerSettings,
)
from mapping import OccupancyGrid, Pinhole, mujoco_pose, opencv_pose
from sim.config.scenario import CorrectionConfig, MotionConfig
from sim.world.render import Renderer, camera_pose
from sim.world.scene import Robot, Scene

WIDER = 3.0  # the final frame's second search: this many times search_px and max_jump
# The accuracy a trusted correction holds: the pose-correction benchmark's moves are all
# within it (bench/pose_correction.py: at most 2.4 mm and 0.17 deg off the truth). Two
# estimates from the same fiducials further apart than that cannot both be that close.
ACCURACY_M = 0.003
ACCURACY_DEG = 0.2
# A pose standard deviation given as the root of a 3x3 covariance's trace (the root mean
# square of the 3-D error) bounds 95 % of errors at this multiple: sqrt(chi2_3(0.95) / 3).
RMS_TO_95 = math.sqrt(7.8147 / 3)
# The bundle adjustment's covariance counts only independent pixel noise (pixel_sigma);
# the errors it leaves are larger (the first frame's pose held exact, errors shared by a
# fiducial's measurements). Over 90 corrections of the soak's 50 scenes with correction
# on (bench/soak.py's scenes i % 10 == 9, master seed 1), the 95th percentile of error
# over standard deviation was 3.13 in position and 1.80 in rotation, where a covariance
# that held gives RMS_TO_95 (1.61): its standard deviations are scaled by the ratio.
BUNDLE_SD_SCALE = (3.13 / RMS_TO_95, 1.80 / RMS_TO_95)
ARM_REACH_M = 1.0  # base pivot to camera, for the prior of an uncorrected pose (m)


def prior_pose_sd(cfg: MotionConfig, reach_m: float = ARM_REACH_M) -> tuple[float, float]:
    """Standard deviation of an uncorrected camera pose, position (m) and rotation (deg),
    from the positioning errors' standard deviations, to first order: the base's x and y,
    and every rotation (base yaw, mount roll and pitch, six joints' offset and noise)
    swinging the camera at ``reach_m``."""
    rot = math.radians(math.sqrt(cfg.base_yaw_deg ** 2 + 2 * cfg.suspension_deg ** 2
                                 + 6 * (cfg.joint_offset_deg ** 2 + cfg.joint_noise_deg ** 2)))
    return math.sqrt(2 * cfg.base_offset_m ** 2 + (reach_m * rot) ** 2), math.degrees(rot)


@dataclass(frozen=True)
class UsedFiducial:
    """A fiducial the final pose was estimated from."""

    position: np.ndarray  # world (m), the EKF's estimate
    covariance: np.ndarray  # 3x3 (m^2)
    pixel: np.ndarray  # (u, v) in the final left image
    disparity: float  # pixels
    rating: float  # eq. 8
    track: list[tuple[float, float]]  # its left pixels through the move


@dataclass
class Correction:
    """The outcome for one robot's move. ``pose`` is the corrected camera pose (4x4,
    MuJoCo camera convention), None if it could not be estimated (``reason`` says why)."""

    pose: np.ndarray | None = None
    estimate: PoseEstimate | None = None
    others: dict[str, np.ndarray] = field(default_factory=dict)  # the other estimators' poses
    bundle_pose: np.ndarray | None = None  # the bundle adjustment's last pose (MuJoCo)
    pose_sd: tuple[float, float] | None = None  # bundle: position (m), rotation (deg)
    start_sd: tuple[float, float] = (0.0, 0.0)  # of the pose the move started from
    frames: int = 0
    located: int = 0
    fiducials_tracked: int = 0
    bundle_rms_px: float | None = None
    used: list[UsedFiducial] = field(default_factory=list)
    reason: str = ""  # why it failed; empty when ``pose`` is trusted
    recovered_by: str = ""  # "wider search" or "retrace" when the first try failed
    tried: list[str] = field(default_factory=list)  # the recoveries tried, in order
    retrace_from: np.ndarray | None = None  # joints of the last located frame, to go back to

    @property
    def status(self) -> str:
        """``corrected`` (trusted), ``uncertain`` (an estimate the bundle adjustment
        disagrees with) or ``failed`` (no estimate: the commanded pose stands)."""
        if self.pose is None:
            return "failed"
        return "uncertain" if self.reason else "corrected"

    def believed_sd(self, prior: tuple[float, float]) -> tuple[float, float]:
        """Standard deviation of the pose this correction leaves the robot believing, in
        position (m) and rotation (deg): the bundle's when corrected, the estimators'
        disagreement when uncertain, ``prior`` (the commanded pose's) when failed."""
        if self.status == "failed":
            return prior
        sd = self.sd
        if self.status == "uncertain" and self.pose is not None and self.bundle_pose is not None:
            return (max(sd[0], float(np.linalg.norm(self.pose[:3, 3] - self.bundle_pose[:3, 3]))),
                    max(sd[1], rotation_deg(self.pose, self.bundle_pose)))
        return sd

    @property
    def sd(self) -> tuple[float, float]:
        """Standard deviation of the bundle adjustment's pose, position (m) and rotation
        (deg): its covariance's, scaled to the errors measured (BUNDLE_SD_SCALE), and the
        start pose's together."""
        bundle = self.pose_sd or (0.0, 0.0)
        return (math.hypot(BUNDLE_SD_SCALE[0] * bundle[0], self.start_sd[0]),
                math.hypot(BUNDLE_SD_SCALE[1] * bundle[1], self.start_sd[1]))

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"status": self.status,
                               "frames": self.frames, "frames_located": self.located,
                               "fiducials_tracked": self.fiducials_tracked}
        if self.reason:
            out["failed"] = self.reason
        if self.tried:
            out["recoveries_tried"] = self.tried
        if self.recovered_by:
            out["recovered_by"] = self.recovered_by
        if self.estimate is not None:
            out.update({"estimator": self.estimate.method, "fiducials": self.estimate.count,
                        "reprojection_rms_px": round(self.estimate.rms_px, 4)})
            if self.estimate.note:
                out["note"] = self.estimate.note
        if self.bundle_rms_px is not None:
            out["bundle_rms_px"] = round(self.bundle_rms_px, 4)
        if self.pose_sd is not None:
            out["bundle_sd"] = {"position_m": round(self.pose_sd[0], 6),
                                "orientation_deg": round(self.pose_sd[1], 5)}
        out["start_sd"] = {"position_m": round(self.start_sd[0], 6),
                           "orientation_deg": round(self.start_sd[1], 5)}
        if self.pose_sd is not None:
            out["sd"] = {"position_m": round(self.sd[0], 6),
                         "orientation_deg": round(self.sd[1], 5)}
        out["used"] = [{"position": f.position.round(5).tolist(),
                        "sd_m": round(float(np.sqrt(np.trace(f.covariance))), 6),
                        "pixel": f.pixel.round(2).tolist(),
                        "disparity_px": round(f.disparity, 3),
                        "rating": round(f.rating, 4), "track_length": len(f.track)}
                       for f in self.used]
        return out


class PoseCorrector:
    """Takes the frames of each move and corrects the camera's pose at its end."""

    def __init__(self, scene: Scene, belief: mujoco.MjData, world: mujoco.MjData,
                 renderer: Renderer, pinhole: Pinhole, baseline_m: float,
                 grid: OccupancyGrid, config: CorrectionConfig) -> None:
        self.scene, self.belief, self.world = scene, belief, world
        self.renderer, self.pinhole, self.grid, self.cfg = renderer, pinhole, grid, config
        self.camera = StereoCamera(pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy, baseline_m)
        self.settings = TrackerSettings(features=config.features, search_px=config.search_px,
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

    # ------------------------------------------------------------ along the move

    def nominal_pose(self, robot: Robot, joints: np.ndarray) -> np.ndarray:
        """The camera pose (OpenCV convention) of the nominal model at ``joints``."""
        d = self._scratch
        d.qpos[:] = self.belief.qpos
        d.qpos[robot.qpos_adr] = joints
        mujoco.mj_kinematics(self.scene.model, d)
        mujoco.mj_camlight(self.scene.model, d)
        return opencv_pose(camera_pose(d, robot.camera))

    def begin(self, robot: Robot, start_joints: np.ndarray,
              start: tuple[np.ndarray, tuple[float, float]] | None = None) -> None:
        """The first frame, at the pose before the move: ``start`` (the camera pose the
        robot believes, MuJoCo convention, and its standard deviation in m and deg), or
        where the joints put it when no move has made an error yet."""
        self._tracker = FiducialTracker(self.camera, self.settings)
        measured = self.nominal_pose(robot, start_joints)  # frames are predicted from it
        T = measured if start is None else opencv_pose(start[0])
        self._start_sd = (0.0, 0.0) if start is None else start[1]
        frame = self._tracker.start(self._look(robot), invert(T))
        self._last_measured = self._located_measured = measured
        self._last_located = frame.g01
        self._joints = np.array(start_joints, copy=True)
        self._located_joints = self._joints.copy()
        self._retraced = False

    def on_sample(self, robot: Robot) -> Callable[[float, np.ndarray], None]:
        """A callback for the mover, given the measured joints: a frame whenever the
        camera has moved enough since the last one."""
        cfg = self.cfg

        def sample(t: float, measured: np.ndarray) -> None:
            self._joints = np.array(measured, copy=True)
            T = self.nominal_pose(robot, measured)
            last = self._last_measured
            denser = 2.0 if self._retraced else 1.0
            if (rotation_deg(last, T) >= cfg.frame_every_deg / denser
                    or np.linalg.norm(T[:3, 3] - last[:3, 3]) >= cfg.frame_every_m / denser):
                self._frame(robot, T)
        return sample

    def _frame(self, robot: Robot, T_measured: np.ndarray,
               found: StereoFeatures | None = None) -> bool:
        """Takes (or, given ``found``, tracks again) a frame; whether it was located."""
        assert self._tracker is not None, "begin() first"
        # the last located pose, moved as the joints say since
        motion = invert(self._located_measured) @ T_measured
        predicted = invert(invert(self._last_located) @ motion)
        self._found = self._look(robot) if found is None else found
        frame = self._tracker.add(self._found, predicted)
        self._last_measured = T_measured
        if frame.located:
            self._last_located, self._located_measured = frame.g01, T_measured
            self._located_joints = self._joints.copy()
        return frame.located

    def _search_wider(self, robot: Robot) -> bool:
        """The last frame tracked again, its fiducials looked for ``WIDER`` times as far
        from their predicted pixels and its pose allowed as much further from the
        prediction; whether it was located."""
        tracker = self._tracker
        assert tracker is not None and self._found is not None, "a frame first"
        tracker.frames.pop()
        narrow = tracker.settings
        tracker.settings = dataclasses.replace(
            narrow, search_px=WIDER * narrow.search_px, max_jump_m=WIDER * narrow.max_jump_m,
            max_jump_deg=WIDER * narrow.max_jump_deg)
        try:
            return self._frame(robot, self._last_measured, self._found)
        finally:
            tracker.settings = narrow

    def retrace(self, path: np.ndarray, back_to: np.ndarray) -> np.ndarray:
        """The way (k, 9) back along ``path`` to its waypoint nearest the joints
        ``back_to`` (where a frame was last located) and forth again to the goal; frames
        are taken twice as densely on it."""
        k = min(int(np.argmin(np.linalg.norm(path - back_to, axis=1))), len(path) - 2)
        self._retraced = True
        return np.vstack([path[k:][::-1], path[k + 1:]])

    def _look(self, robot: Robot) -> StereoFeatures:
        r, d = self.renderer, self.world
        left, right = r.rgb(d, robot.camera), r.rgb(d, robot.right_camera)
        self._last_left = left
        # a right keypoint on a robot can only pair with a left one there, already out
        return self.finder.stereo(left, right, self._own(robot.camera))

    def _own(self, camera: str) -> np.ndarray:
        seen = self.renderer.segmentation(self.world, camera)
        return (seen >= 0) & self.robot_geoms[np.maximum(seen, 0)]

    # ------------------------------------------------------------ at the goal

    def finish(self, robot: Robot, last_try: bool = True) -> Correction:
        """The last frame, at the goal after settling; the corrected pose from it. If the
        frame cannot be located even by a wider search, the result has ``retrace_from``
        (the joints to go back to) unless ``last_try``; :meth:`retrace` then prepares the
        way back and forth, and ``finish`` is called again."""
        tracker = self._tracker
        assert tracker is not None, "begin() first"
        out = Correction(tried=["wider search", "retrace"] if self._retraced else [],
                         start_sd=self._start_sd)
        located = self._frame(robot, self.nominal_pose(robot, self._joints))
        if not located:
            if not self._retraced:
                out.tried.append("wider search")
            located = self._search_wider(robot)
        if located and out.tried:
            out.recovered_by = out.tried[-1]
        out.frames = len(tracker.frames)
        out.located = sum(f.located for f in tracker.frames)
        out.fiducials_tracked = len(tracker.fiducials)
        if not located:
            out.reason = "too few fiducials found again in the final frame"
            if not last_try and not self._retraced:
                out.retrace_from = self._located_joints.copy()
                return out
        self._tracker = None
        if not located:
            return out
        bundle, frames, kept = tracker.solve()
        out.bundle_rms_px = bundle.rms_px
        out.bundle_pose = mujoco_pose(invert(bundle.poses[-1]))
        cov = bundle.pose_cov[-1]
        out.pose_sd = (float(np.sqrt(np.trace(cov[3:, 3:]))),
                       math.degrees(float(np.sqrt(np.trace(cov[:3, :3])))))
        candidates, filters, ids = self._rated(frames, bundle.poses, bundle.pose_cov, kept)
        chosen = pick(candidates, self.cfg.fiducials)
        if not chosen:
            out.reason = "no fiducial of the final frame was seen before"
            return out
        position = {id(c): k for k, c in enumerate(candidates)}
        index = [position[id(c)] for c in chosen]
        fids = [filters[k] for k in index]
        zs = np.array([frames[-1].observations[ids[k]] for k in index])
        world = np.array([f.x for f in fids])
        cameras = np.array([self.camera.point(z) for z in zs])
        try:
            out.estimate = estimate_pose(world, cameras, zs[:, :2], tracker.K, self.cfg.estimator)
        except DegenerateGeometryError as exc:
            out.reason = str(exc)
            return out
        out.pose = mujoco_pose(out.estimate.pose)
        out.reason = self._distrust(out)
        for method in METHODS:  # the same fiducials by every estimator, for comparison
            if method != out.estimate.method:
                try:
                    other = estimate_pose(world, cameras, zs[:, :2], tracker.K, method)
                except DegenerateGeometryError:
                    continue
                if other.method == method:
                    out.others[method] = mujoco_pose(other.pose)
        out.used = [UsedFiducial(f.x, f.covariance, z[:2], float(z[2]), c.rating,
                                 tracker.fiducials.tracks[ids[k]])
                    for f, z, c, k in zip(fids, zs, chosen, index, strict=True)]
        return out

    @staticmethod
    def _distrust(c: Correction) -> str:
        """Why the estimate ``c`` cannot be trusted to the correction's accuracy; empty
        if it can."""
        assert c.pose is not None and c.bundle_pose is not None and c.estimate is not None
        why = []
        apart_m = float(np.linalg.norm(c.pose[:3, 3] - c.bundle_pose[:3, 3]))
        apart_deg = rotation_deg(c.pose, c.bundle_pose)
        if apart_m > ACCURACY_M or apart_deg > ACCURACY_DEG:
            why.append(f"the {c.estimate.method} estimate and the bundle adjustment "
                       f"disagree by {apart_m * 1e3:.1f} mm, {apart_deg:.2f} deg")
        sd_m, sd_deg = c.sd
        bound_m, bound_deg = RMS_TO_95 * sd_m + apart_m, RMS_TO_95 * sd_deg + apart_deg
        if not why and (bound_m > ACCURACY_M or bound_deg > ACCURACY_DEG):
            start = " (with the start pose's)" if any(c.start_sd) else ""
            why.append(f"its standard deviation{start}, {sd_m * 1e3:.1f} mm and "
                       f"{sd_deg:.2f} deg, with the estimators {apart_m * 1e3:.1f} mm and "
                       f"{apart_deg:.2f} deg apart, allows errors of {bound_m * 1e3:.1f} mm "
                       f"and {bound_deg:.2f} deg (95 %), beyond {ACCURACY_M * 1e3:g} mm / "
                       f"{ACCURACY_DEG:g} deg")
        return "; ".join(why)

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
            candidates.append(Candidate(z[:2], float(z[2]), certainty(self.grid, p, x),
                                        visual_contrast(gray, z[:2]),
                                        depth_contrast(self.grid, p, x)))
            filters.append(ekf)
            ids.append(i)
        rate(candidates)
        return candidates, filters, ids
