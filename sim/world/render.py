"""Offscreen rendering of the scene's cameras: RGB, metric depth, segmentation."""

from __future__ import annotations

import math
import time
from types import TracebackType

import mujoco
import numpy as np

from taskcam.mapping import Pinhole
from taskcam.sim.world.gl import require_gl_backend


def camera_pinhole(model: mujoco.MjModel, camera: str) -> Pinhole:
    """Intrinsics of a named camera at its own resolution."""
    cam = model.camera(camera)
    width, height = (int(v) for v in model.cam_resolution[cam.id])
    return Pinhole.from_fovy(math.radians(float(model.cam_fovy[cam.id])), width, height)


def camera_pose(data: mujoco.MjData, camera: str) -> np.ndarray:
    """``T_world_cam`` (4x4) of a named camera, MuJoCo convention (-z forward, +y up)."""
    cam = data.camera(camera)
    T = np.eye(4)
    T[:3, :3] = cam.xmat.reshape(3, 3)
    T[:3, 3] = cam.xpos
    return T


def far_plane(model: mujoco.MjModel) -> float:
    """Distance (m) of the far clipping plane: depth there means nothing was hit."""
    return float(model.vis.map.zfar * model.stat.extent)


def _farthest_geometry(model: mujoco.MjModel, data: mujoco.MjData, position: np.ndarray
                       ) -> float | None:
    """How far (m) the farthest rendered geometry may be from ``position``; None if it
    lies behind a plane (below the floor), whose back a render does not show."""
    offset = data.geom_xpos - position
    plane = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
    normal = data.geom_xmat[plane].reshape(-1, 3, 3)[:, :, 2]
    if np.any(np.einsum("ij,ij->i", offset[plane], normal) > 0):
        return None
    size = np.where(plane, np.hypot(model.geom_size[:, 0], model.geom_size[:, 1]),
                    model.geom_rbound)
    return float(np.max(np.linalg.norm(offset, axis=1) + size))


def _narrow(scene: mujoco.MjvScene, width: int, height: int, rows: slice, cols: slice,
            downscale: int = 1) -> mujoco.MjrRect:
    """Narrow the scene's camera frustum to the ``rows`` and ``columns`` (row 0 at the
    top) of its ``width`` x ``height`` image; the viewport that renders just them, at
    1/``downscale`` of the resolution."""
    for cam in scene.camera:  # both eyes: the render averages them
        span = cam.frustum_top - cam.frustum_bottom
        half = cam.frustum_width or 0.5 * width / height * span
        left, step = cam.frustum_center - half, 2 * half / width
        first, stop = left + cols.start * step, left + cols.stop * step
        cam.frustum_center, cam.frustum_width = 0.5 * (first + stop), 0.5 * (stop - first)
        top = cam.frustum_top
        cam.frustum_top = top - rows.start * span / height
        cam.frustum_bottom = top - rows.stop * span / height
    return mujoco.MjrRect(0, 0, max(1, (cols.stop - cols.start) // downscale),
                          max(1, (rows.stop - rows.start) // downscale))


# Scene flags a segmentation render draws with (colours by object, no lighting or
# texture); mujoco.Renderer renders depth with them too (more precise far away), as here
SEGMENT_FLAGS = (int(mujoco.mjtRndFlag.mjRND_SEGMENT), int(mujoco.mjtRndFlag.mjRND_IDCOLOR))


class Renderer:
    """Offscreen renderer for cameras of one resolution. Use as a context manager.

    A renderer belongs to the thread that made it. ``seconds`` is the wall time it has
    spent rendering.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        require_gl_backend()
        self.model = model
        self._renderer: mujoco.Renderer | None = mujoco.Renderer(model, height, width)
        self._sky = 0.999 * far_plane(model)
        self.seconds = 0.0

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    @property
    def _r(self) -> mujoco.Renderer:
        if self._renderer is None:
            raise RuntimeError("renderer is closed")
        return self._renderer

    def _render(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        start = time.perf_counter()
        r = self._r
        r.update_scene(data, camera)
        image = r.render().copy()
        self.seconds += time.perf_counter() - start
        return image

    def rgb(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """RGB image (h, w, 3) uint8, row 0 at the top."""
        return self._render(data, camera)

    def depth(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """Metric z-depth (h, w) float32 along the optical axis; ``inf`` where nothing was hit."""
        r = self._r
        r.enable_depth_rendering()
        try:
            depth = self._render(data, camera)
        finally:
            r.disable_depth_rendering()
        depth[depth >= self._sky] = np.inf
        return depth

    def rgb_and_depth(self, data: mujoco.MjData, camera: str,
                      window: tuple[slice, slice] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rgb` and :meth:`depth` of one view, as those give them; of its ``window``
        (rows, columns) only, if given. A window is all that is rendered, through the part
        of the camera's frustum it sees: per pixel as the whole image's, to four grey levels
        where textures are sampled (under one on average) and, multisampled, a pixel or two
        on its border. Without multisampling, for a perspective camera above the floor,
        both come from one render: its depth buffer is then a depth render's, except where the
        sky box is drawn, and that lies beyond all the scene's geometry. Otherwise (a
        multisampled colour render's depth buffer is not a depth render's), from a colour
        render and a depth render of the window."""
        h, w = self._r.height, self._r.width
        rows, cols = window or (slice(0, h), slice(0, w))
        m = self.model
        perspective = mujoco.mjtProjection.mjPROJ_PERSPECTIVE
        reach = (None if m.vis.quality.offsamples
                 or m.cam_projection[m.camera(camera).id] != perspective
                 else _farthest_geometry(m, data, data.camera(camera).xpos))
        start = time.perf_counter()
        rect = self._draw(data, camera, rows, cols)
        rgb = self._read_colour(rect)
        if reach is None or reach >= self._sky / 2:
            depth = self._read_depth(self._draw(data, camera, rows, cols, SEGMENT_FLAGS))
            depth[depth >= self._sky] = np.inf
        else:
            depth = self._read_depth(rect)
            depth[depth > reach] = np.inf  # the sky box
        self.seconds += time.perf_counter() - start
        return rgb, depth

    def _draw(self, data: mujoco.MjData, camera: str, rows: slice, cols: slice,
              flags: tuple[int, ...] = (), downscale: int = 1) -> mujoco.MjrRect:
        """Renders the ``rows`` and ``cols`` of a camera's image (at 1/``downscale`` of
        the resolution) with the scene's render ``flags`` also on; the viewport drawn."""
        r = self._r
        r.update_scene(data, camera)
        scene = r.scene
        rect = _narrow(scene, r.width, r.height, rows, cols, downscale)
        saved = scene.flags.copy()
        scene.flags[list(flags)] = 1
        try:
            if r._gl_context:
                r._gl_context.make_current()
            mujoco.mjr_render(rect, scene, r._mjr_context)
        finally:
            np.copyto(scene.flags, saved)
        return rect

    def _read_colour(self, rect: mujoco.MjrRect) -> np.ndarray:
        """The drawn viewport's colours (h, w, 3) uint8, row 0 at the top."""
        rgb = np.empty((rect.height, rect.width, 3), np.uint8)
        mujoco.mjr_readPixels(rgb, None, rect, self._r._mjr_context)
        return rgb[::-1].copy()

    def _read_depth(self, rect: mujoco.MjrRect) -> np.ndarray:
        """The drawn viewport's z-depth (h, w) float32 m, row 0 at the top."""
        window = np.empty((rect.height, rect.width), np.float32)  # 1 near, 0 far
        mujoco.mjr_readPixels(None, window, rect, self._r._mjr_context)
        return self._metric(window)[::-1].copy()

    def _metric(self, window: np.ndarray) -> np.ndarray:
        """z-depth (m, float32) from a perspective camera's reversed-z window depth, as
        MuJoCo's depth render computes it (float32 planes, float64 division)."""
        extent = self.model.stat.extent
        near = np.float32(self.model.vis.map.znear * extent)
        far = np.float32(self.model.vis.map.zfar * extent)
        scale = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        numerator = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        return (numerator / (window.astype(np.float64) + scale)).astype(np.float32)

    def segmentation(self, data: mujoco.MjData, camera: str, downscale: int = 1
                     ) -> np.ndarray:
        """Geom id per pixel (h, w) int32; -1 where no geom was hit. With ``downscale`` k
        > 1, of a render at 1/k of the resolution: (h // k, w // k), each value that at
        the centre of a k x k block of pixels."""
        r = self._r
        if downscale == 1:
            r.enable_segmentation_rendering()
            try:
                seg = self._render(data, camera)
            finally:
                r.disable_segmentation_rendering()
            ids = seg[..., 0].astype(np.int32)
            ids[seg[..., 1] != int(mujoco.mjtObj.mjOBJ_GEOM)] = -1
            return ids
        start = time.perf_counter()
        rect = self._draw(data, camera, slice(0, r.height), slice(0, r.width),
                          SEGMENT_FLAGS, downscale)
        colour = self._read_colour(rect)
        scene = r.scene
        segid = colour.astype(np.int32) @ np.array([1, 1 << 8, 1 << 16], np.int32)
        geoms = np.full(scene.ngeom + 1, -1, np.int32)  # segid 0: the background
        for g in scene.geoms[:scene.ngeom]:
            if g.segid >= 0 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                geoms[g.segid + 1] = g.objid
        self.seconds += time.perf_counter() - start
        return geoms[segid]
