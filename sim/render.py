"""Offscreen rendering of the scene's cameras: RGB, metric depth, segmentation."""

from __future__ import annotations

import math
import time
from types import TracebackType

import mujoco
import numpy as np

from mapping import Pinhole


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


class Renderer:
    """Offscreen renderer for cameras of one resolution. Use as a context manager.

    A renderer belongs to the thread that made it. ``seconds`` is the wall time it has
    spent rendering.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
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

    def rgb_and_depth(self, data: mujoco.MjData, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rgb` and :meth:`depth` of one view, as those give them. Without
        multisampling, for a perspective camera above the floor, both come from one render:
        its depth buffer is then a depth render's, except where the sky box is drawn, and
        that lies beyond all the scene's geometry. Otherwise, from two renders."""
        r, m = self._r, self.model
        perspective = mujoco.mjtProjection.mjPROJ_PERSPECTIVE
        reach = (None if m.vis.quality.offsamples
                 or m.cam_projection[m.camera(camera).id] != perspective
                 else _farthest_geometry(m, data, data.camera(camera).xpos))
        if reach is None or reach >= self._sky / 2:
            return self.rgb(data, camera), self.depth(data, camera)
        rgb = self._render(data, camera)
        start = time.perf_counter()
        window = np.empty((r.height, r.width), np.float32)  # 1 at the near plane, 0 at far
        mujoco.mjr_readPixels(None, window, r._rect, r._mjr_context)
        depth = self._metric(window)[::-1].copy()  # row 0 at the top, as in rgb
        depth[depth > reach] = np.inf  # the sky box
        self.seconds += time.perf_counter() - start
        return rgb, depth

    def _metric(self, window: np.ndarray) -> np.ndarray:
        """z-depth (m, float32) from a perspective camera's reversed-z window depth, as
        MuJoCo's depth render computes it (float32 planes, float64 division)."""
        extent = self.model.stat.extent
        near = np.float32(self.model.vis.map.znear * extent)
        far = np.float32(self.model.vis.map.zfar * extent)
        scale = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        numerator = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        return (numerator / (window.astype(np.float64) + scale)).astype(np.float32)

    def segmentation(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """Geom id per pixel (h, w) int32; -1 where no geom was hit."""
        r = self._r
        r.enable_segmentation_rendering()
        try:
            seg = self._render(data, camera)
        finally:
            r.disable_segmentation_rendering()
        ids = seg[..., 0].astype(np.int32)
        ids[seg[..., 1] != int(mujoco.mjtObj.mjOBJ_GEOM)] = -1
        return ids
