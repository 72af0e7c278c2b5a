"""What the insertion task sees: each placed camera's stereo pair through its lens, rendered
only around the panel (and the slot's walls, when the relative measurement needs them),
and the panel's pixels in it (the hull of its yellow)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import cv2
import mujoco
import numpy as np

from taskcam.calibration.edge_model import Seen, StereoRig
from taskcam.calibration.edge_search import CORNERS
from taskcam.calibration.panel import measuring_window, panel_mask
from taskcam.mapping import Pinhole, opencv_pose
from taskcam.mapping.stereo import StereoSettings, stereo_depth
from taskcam.sim.stages.relative import RelativeMeasurer
from taskcam.sim.stages.task_result import Camera
from taskcam.sim.world.optics import Lens, defocus

MIN_POINTS = 150  # panel pixels (and points) a measurement needs, over all cameras
BLUR_MARGIN_PX = 48  # blurred around the panel: 3 sigma of the widest blur level and more
SETTINGS = StereoSettings()
# What hides the models the task fits (``TaskImages.seen``) is matched at half the
# resolution: a quarter of the pixels and half the disparities cost an eighth, and a
# surface is still placed to a fraction of a pixel, far within edge_model.NEARER_PX.
SEEN_SCALE = 2
SEEN_SETTINGS = StereoSettings(num_disparities=SETTINGS.num_disparities // SEEN_SCALE)
# Where the panel is in a view comes from a segmentation at 1/COARSE of the resolution;
# only the pixels measuring uses around it are then rendered in full.
COARSE = 2
# Around the slot's walls the images are rendered this far (px) beyond their projection
# at the fit's start: the widest alignment (edge_search.MAX_REACH_PX) and the blur around it
SLOT_MARGIN_PX = 48


class TaskRenderer(Protocol):
    """What the task renders with: a :class:`taskcam.sim.world.render.Renderer`, or a stand-in
    that serves images rendered beforehand (as :meth:`Renderer.rgb_and_depth` and
    :meth:`Renderer.segmentation` give them)."""

    def segmentation(self, data: mujoco.MjData, camera: str, downscale: int = 1
                     ) -> np.ndarray: ...

    def rgb_and_depth(self, data: mujoco.MjData, camera: str,
                      window: tuple[slice, slice] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class StereoPair:
    """A camera's two images through its lens (uint8, full size, black outside
    ``window``), the panel's pixels in the left one, and its sharp pixels (``near``)."""

    left: np.ndarray
    right: np.ndarray
    mask: np.ndarray
    near: np.ndarray
    window: tuple[slice, slice]
    right_mask: np.ndarray  # the panel's pixels in the right image


def _union(a: tuple[slice, slice], b: tuple[slice, slice] | None) -> tuple[slice, slice]:
    """The smallest window (rows, columns) holding both."""
    if b is None:
        return a
    return (slice(min(a[0].start, b[0].start), max(a[0].stop, b[0].stop)),
            slice(min(a[1].start, b[1].start), max(a[1].stop, b[1].stop)))


def stereo_window(mask: np.ndarray, margin: int) -> tuple[slice, slice]:
    """The window around ``mask`` measuring uses, with the stereo's disparity range."""
    return measuring_window(mask, margin, SETTINGS.num_disparities)


class TaskImages:
    """Renders what the task's cameras see of the panel in ``data`` (``renderer``, the
    cameras' ``pinhole`` and ``lens``; the panel's geom, ``panel_geom``)."""

    def __init__(self, data: mujoco.MjData, renderer: TaskRenderer, pinhole: Pinhole,
                 lens: Lens, panel_geom: int, rig: StereoRig) -> None:
        self.data, self.renderer, self.pinhole, self.lens = data, renderer, pinhole, lens
        self.panel_geom, self.rig = panel_geom, rig

    def _sharp_left(self, camera: str, include: tuple[slice, slice] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[slice, slice]] | None:
        """A left camera's sharp colour and depth (m), where the panel is (its yellow
        pixels), and the window around them that measuring uses (rows, columns, with the
        stereo's disparity range in front, and ``include`` if given); None if fewer than
        MIN_POINTS panel pixels are in view. Only a window around the panel's silhouette in
        a coarse segmentation is rendered (black, depth inf elsewhere); the whole image if
        the panel reaches that window's edge."""
        r, d = self.renderer, self.data
        h, w = self.pinhole.height, self.pinhole.width
        ys, xs = np.nonzero(r.segmentation(d, camera, COARSE) == self.panel_geom)
        if len(ys) == 0:
            return None
        sy, sx = h / (h // COARSE), w / (w // COARSE)
        silhouette = np.zeros((h, w), bool)  # its bounding box, in the image's pixels
        silhouette[int(ys.min() * sy):int(np.ceil((ys.max() + 1) * sy)),
                   int(xs.min() * sx):int(np.ceil((xs.max() + 1) * sx))] = True
        around = _union(stereo_window(silhouette, BLUR_MARGIN_PX + COARSE), include)
        for rendered in (around, (slice(0, h), slice(0, w))):
            sharp = np.zeros((h, w, 3), np.uint8)
            depth = np.full((h, w), np.inf, np.float32)
            sharp[rendered], depth[rendered] = r.rgb_and_depth(d, camera, rendered)
            near = panel_mask(sharp)  # where to look: the lens blurs only a few pixels
            if near.sum() < MIN_POINTS:
                return None
            rows, cols = _union(stereo_window(near, BLUR_MARGIN_PX), include)
            if all(outer.start <= inner.start and inner.stop <= outer.stop
                   for outer, inner in zip(rendered, (rows, cols), strict=True)):
                break
        return sharp, depth, near, (rows, cols)

    def stereo_pair(self, camera: str, right_camera: str,
                    include: tuple[slice, slice] | None = None) -> StereoPair | str:
        """Both images through the lens around the panel (and ``include``), the panel's
        pixels in the left one, or why the panel is not in view."""
        found = self._sharp_left(camera, include)
        if found is None:
            return "panel not in view (occluded or outside the image)"
        sharp, sharp_depth, near, (rows, cols) = found
        left = np.zeros_like(sharp)
        left[rows, cols] = defocus(sharp[rows, cols], sharp_depth[rows, cols], self.lens)
        right = np.zeros_like(sharp)
        right[rows, cols] = defocus(*self.renderer.rgb_and_depth(self.data, right_camera,
                                                                 (rows, cols)), self.lens)
        mask = np.zeros_like(near)
        mask[rows, cols] = panel_mask(left[rows, cols])
        if mask.sum() < MIN_POINTS:
            return "panel not in view (occluded or outside the image)"
        right_mask = np.zeros_like(near)
        right_mask[rows, cols] = panel_mask(right[rows, cols])
        return StereoPair(left, right, mask, near, (rows, cols), right_mask)

    def seen(self, pair: StereoPair) -> Seen:
        """What the pair saw over its window (:func:`pair_seen`)."""
        return pair_seen(pair.left, pair.right, self.pinhole, self.rig.baseline_m, pair.window)

    def _slot_window(self, cam: Camera, measurer: RelativeMeasurer
                     ) -> tuple[slice, slice] | None:
        """The pixels the slot's fit may search in this camera's left image: its walls'
        projected box where the fit starts, with the searches' reach around it."""
        T_cam_world = np.linalg.inv(opencv_pose(cam.believed))
        start = measurer.slot_fits.get(cam.robot.name, T_cam_world @ measurer.belief.pose)
        slot = measurer.slot
        corners = np.concatenate([c + CORNERS * h for c, h in zip(slot.centres, slot.halves,
                                                                 strict=True)])
        X = corners @ start[:3, :3].T + start[:3, 3]
        if (X[:, 2] <= 0.05).any():
            return None
        uv = self.rig.project(X, 0)
        margin = SLOT_MARGIN_PX
        h, w = self.pinhole.height, self.pinhole.width
        rows = slice(int(np.clip(uv[:, 1].min() - margin, 0, h)),
                     int(np.clip(uv[:, 1].max() + margin + 1, 0, h)))
        cols = slice(int(np.clip(uv[:, 0].min() - margin - SETTINGS.num_disparities, 0, w)),
                     int(np.clip(uv[:, 0].max() + margin + 1, 0, w)))
        return None if rows.start >= rows.stop or cols.start >= cols.stop else (rows, cols)


def pair_seen(left: np.ndarray, right: np.ndarray, pinhole: Pinhole, baseline_m: float,
              window: tuple[slice, slice] | None = None) -> Seen:
    """What a stereo pair of ``pinhole`` images, ``baseline_m`` apart, saw: its left
    image's disparity (px, full size) over ``window`` (rows, columns; the whole image if
    None), matched at 1/SEEN_SCALE of the resolution (``Seen``: what hides the models
    the pair's edges are fitted to)."""
    s, p = SEEN_SCALE, pinhole
    small = dataclasses.replace(p, width=p.width // s, height=p.height // s, fx=p.fx / s,
                                fy=p.fy / s, cx=(p.cx + 0.5) / s - 0.5,
                                cy=(p.cy + 0.5) / s - 0.5)
    left, right = (cv2.resize(im, (small.width, small.height), interpolation=cv2.INTER_AREA)
                   for im in (left, right))
    rows, cols = window if window is not None else (slice(0, p.height), slice(0, p.width))
    scaled = tuple(slice(w.start // s, -(-w.stop // s)) for w in (rows, cols))
    depth = stereo_depth(left, right, small, baseline_m, SEEN_SETTINGS, (scaled[0], scaled[1]))
    disparity = cv2.resize(s * small.fx * baseline_m / depth, (p.width, p.height),
                           interpolation=cv2.INTER_NEAREST)
    return Seen.of(disparity)
