"""The absolute measurement of the panel (docs/task.md): stereo points of the panel in
each camera's view, carried into the world through the camera's believed pose, fitted
with the panel's CAD model, all trusted cameras together, else each alone.
"""

from __future__ import annotations

import numpy as np

from taskcam.calibration.panel import window
from taskcam.mapping import BoxModel, fit_model, opencv_pose
from taskcam.mapping.cad import to_object
from taskcam.mapping.stereo import stereo_depth
from taskcam.sim.stages.task_images import MIN_POINTS, SETTINGS, TaskImages
from taskcam.sim.stages.task_result import Camera

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


class AbsolutePanel:
    """Measures the panel's pose from the stereo pairs ``images`` renders (m, world)."""

    def __init__(self, images: TaskImages, model: BoxModel, baseline_m: float,
                 margin_px: int, rng: np.random.Generator) -> None:
        self.images, self.model, self.baseline_m = images, model, baseline_m
        self.margin_px, self.rng = margin_px, rng
        self.noise_scale = max(1.0, REFERENCE_FX_PX / images.pinhole.fx)

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
            found = self.panel_points(cam)
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

    def panel_points(self, cam: Camera) -> np.ndarray | str:
        """World points of the panel in one camera's view, or why there are none."""
        pair = self.images.stereo_pair(cam.robot.camera, cam.robot.right_camera)
        if isinstance(pair, str):
            return pair
        depth = stereo_depth(pair.left, pair.right, self.images.pinhole, self.baseline_m, SETTINGS,
                             window(pair.near, self.margin_px))
        v, u = np.nonzero(pair.mask & np.isfinite(depth))
        if len(v) < MIN_POINTS // 2:
            return "no stereo depth on the panel"
        if len(v) > MAX_POINTS_PER_CAMERA:
            keep = self.rng.choice(len(v), MAX_POINTS_PER_CAMERA, replace=False)
            v, u = v[keep], u[keep]
        z = depth[v, u].astype(float)
        p = self.images.pinhole
        in_cam = np.column_stack([(u - p.cx) * z / p.fx, (v - p.cy) * z / p.fy, z])
        T = opencv_pose(cam.believed)
        return in_cam @ T[:3, :3].T + T[:3, 3]
