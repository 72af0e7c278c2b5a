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


class Renderer:
    """Offscreen renderer for cameras of one resolution. Use as a context manager.

    One render fills both the colour and the depth buffer: :meth:`rgbd` reads both,
    :meth:`rgb` and :meth:`depth` one of them. A renderer belongs to the thread that
    made it. ``seconds`` is the wall time it has spent rendering.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        self.model, self.width, self.height = model, width, height
        self._gl: mujoco.GLContext | None = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # reversed z
        self._scene = mujoco.MjvScene(model, maxgeom=10_000)
        self._option, self._perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        extent = model.stat.extent
        self._near = np.float32(model.vis.map.znear * extent)
        self._far = np.float32(model.vis.map.zfar * extent)
        self._sky = 0.999 * far_plane(model)
        self.seconds = 0.0

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        if self._gl is not None:
            self._gl.make_current()
            self._context.free()
            self._gl.free()
            self._gl = None

    def _draw(self, data: mujoco.MjData, camera: str, segment: bool = False) -> None:
        if self._gl is None:
            raise RuntimeError("renderer is closed")
        self._gl.make_current()
        self._camera.fixedcamid = self.model.camera(camera).id
        mujoco.mjv_updateScene(self.model, data, self._option, self._perturb, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = segment
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = segment
        mujoco.mjr_render(self._rect, self._scene, self._context)

    def _read(self, rgb: np.ndarray | None, depth: np.ndarray | None) -> None:
        mujoco.mjr_readPixels(rgb, depth, self._rect, self._context)

    def _metric(self, zbuffer: np.ndarray) -> np.ndarray:
        """Metric z-depth from the (reversed-z) depth buffer, rows top first."""
        near, far = self._near, self._far
        c = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        d = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        depth = (d / (zbuffer.astype(np.float64) + c)).astype(np.float32)[::-1].copy()
        depth[depth >= self._sky] = np.inf
        return depth

    def rgbd(self, data: mujoco.MjData, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rgb` and :meth:`depth` of one render."""
        start = time.perf_counter()
        self._draw(data, camera)
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        zbuffer = np.empty((self.height, self.width), np.float32)
        self._read(rgb, zbuffer)
        out = rgb[::-1].copy(), self._metric(zbuffer)
        self.seconds += time.perf_counter() - start
        return out

    def rgb(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """RGB image (h, w, 3) uint8, row 0 at the top."""
        start = time.perf_counter()
        self._draw(data, camera)
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        self._read(rgb, None)
        self.seconds += time.perf_counter() - start
        return rgb[::-1].copy()

    def depth(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """Metric z-depth (h, w) float32 along the optical axis; ``inf`` where nothing was hit."""
        start = time.perf_counter()
        self._draw(data, camera, segment=True)  # flat colours: the cheapest pass
        zbuffer = np.empty((self.height, self.width), np.float32)
        self._read(None, zbuffer)
        self.seconds += time.perf_counter() - start
        return self._metric(zbuffer)

    def segmentation(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """Geom id per pixel (h, w) int32; -1 where no geom was hit."""
        start = time.perf_counter()
        self._draw(data, camera, segment=True)
        colour = np.empty((self.height, self.width, 3), np.uint8)
        self._read(colour, None)
        self.seconds += time.perf_counter() - start
        segid = (colour[::-1].astype(np.int32) << np.array([0, 8, 16])).sum(axis=2)
        scene = self._scene
        lookup = np.full(scene.ngeom + 1, -1, np.int32)  # segment id + 1 -> geom id
        for g in scene.geoms[:scene.ngeom]:
            if g.segid != -1 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[g.segid + 1] = g.objid
        return lookup[segid]
