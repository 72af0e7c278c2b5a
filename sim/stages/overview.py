"""Pictures of a run: the scene from a free camera that frames the work-piece and the
robots, the placed cameras' frusta drawn in (``overview.png``), and the episode as a
film from the same camera (``episode.mp4``, written through imageio's ffmpeg).

The free camera looks down at ELEVATION_DEG across the direction in which the framed
points spread least, so that robots standing on either side of the work-piece are seen
side by side, and stands back until their bounding sphere fills the picture's height.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np

from taskcam.mapping import Pinhole
from taskcam.sim.stages.overview_marks import project

ELEVATION_DEG = -30.0  # looking down this far below the horizon
MARGIN = 1.15  # the framed sphere's radius grown by this, so nothing touches the edge
FRUSTUM_M = 0.25  # a placed camera's frustum is drawn this deep (m)
FRUSTUM_RGBA = (0.1, 0.9, 0.3, 1.0)
FILM_FPS = 15  # frames a second of simulated time


def framing(points: np.ndarray, fovy_deg: float, aspect: float
            ) -> tuple[np.ndarray, float, float]:
    """Where a camera that frames ``points`` (n, 3; m) at a vertical field of view of
    ``fovy_deg`` in a picture of ``aspect`` (width over height) looks (the points' box's
    centre), how far it stands back from there (m) and its azimuth (deg, about +z from
    +x: it looks along the direction the points spread least along)."""
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()), 0.1) * MARGIN
    spread = points[:, :2] - centre[:2]
    if len(points) > 1 and np.ptp(spread, axis=0).max() > 1e-6:
        _, vectors = np.linalg.eigh(spread.T @ spread)
        across = vectors[:, 0]
    else:
        across = np.array([1.0, 0.0])
    fovy = math.radians(fovy_deg)
    half = min(fovy / 2, math.atan(aspect * math.tan(fovy / 2)))  # the narrower half-angle
    return centre, radius / math.sin(half), math.degrees(math.atan2(across[1], across[0]))


def eye_position(points: np.ndarray, fovy_deg: float, aspect: float) -> tuple[np.ndarray,
                                                                            np.ndarray]:
    """The eye (m, world) of :func:`framing`'s camera, and the point it looks at."""
    centre, distance, azimuth = framing(points, fovy_deg, aspect)
    a, e = math.radians(azimuth), math.radians(ELEVATION_DEG)
    forward = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    return centre - distance * forward, centre


def free_camera(model: mujoco.MjModel, points: np.ndarray, aspect: float) -> mujoco.MjvCamera:
    """A free camera that frames ``points`` (n, 3; m) in a picture of ``aspect`` (width
    over height), at the model's field of view (see :func:`framing`)."""
    centre, distance, azimuth = framing(points, float(model.vis.global_.fovy), aspect)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = centre
    cam.distance = distance
    cam.azimuth = azimuth
    cam.elevation = ELEVATION_DEG
    return cam


def frustum_segments(T_world_cam: np.ndarray, pinhole: Pinhole, depth: float
                     ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 8 edges of a camera's frustum out to ``depth`` m (``T_world_cam`` in OpenCV's
    convention: +z forward)."""
    corners = np.array([[0, 0], [pinhole.width, 0], [pinhole.width, pinhole.height],
                        [0, pinhole.height]], float)
    rays = np.column_stack([(corners[:, 0] - pinhole.cx) / pinhole.fx,
                            (corners[:, 1] - pinhole.cy) / pinhole.fy, np.ones(4)])
    far = depth * rays @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    apex = T_world_cam[:3, 3]
    return [(apex, c) for c in far] + [(far[k], far[(k + 1) % 4]) for k in range(4)]


def _add_lines(scene: mujoco.MjvScene, segments: list[tuple[np.ndarray, np.ndarray]],
               rgba: tuple[float, float, float, float] = FRUSTUM_RGBA) -> None:
    for start, end in segments:
        if scene.ngeom >= scene.maxgeom:
            return
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3),
                            np.zeros(9), np.array(rgba, np.float32))
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, 3.0, start, end)
        scene.ngeom += 1


class Overview:
    """Renders the world from one free camera; the frusta of ``cameras`` (OpenCV poses,
    world) drawn in. Use as a context manager (it holds a GL context)."""

    def __init__(self, model: mujoco.MjModel, framed: np.ndarray, width: int = 640,
                 height: int = 480) -> None:
        width = min(width, model.vis.global_.offwidth)
        height = min(height, model.vis.global_.offheight)
        self.model = model
        self.renderer = mujoco.Renderer(model, height, width)
        self.camera = free_camera(model, framed, width / height)

    def __enter__(self) -> Overview:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self.renderer.close()

    def render(self, data: mujoco.MjData, frusta: list[np.ndarray] | None = None,
               pinhole: Pinhole | None = None,
               colours: list[tuple[float, float, float, float]] | None = None) -> np.ndarray:
        """The picture (h, w, 3; uint8 RGB) of the world in ``data``, the ``frusta``
        (OpenCV camera poses) drawn in, each in its ``colours`` (RGBA; default green)."""
        self.renderer.update_scene(data, camera=self.camera)
        if frusta and pinhole is not None:
            for k, T in enumerate(frusta):
                _add_lines(self.renderer.scene, frustum_segments(T, pinhole, FRUSTUM_M),
                           FRUSTUM_RGBA if colours is None else colours[k])
        return self.renderer.render().copy()

    def pixels(self, points: np.ndarray) -> np.ndarray:
        """Where world ``points`` (n, 3; m) lie in the last picture (n, 2; NaN: behind)."""
        return project(self.renderer.scene.camera[0], points, self.renderer.width,
                       self.renderer.height)

    def segmentation(self, data: mujoco.MjData) -> np.ndarray:
        """Which geom (id, -1 for none) each pixel of the picture shows."""
        self.renderer.enable_segmentation_rendering()
        try:
            self.renderer.update_scene(data, camera=self.camera)
            return self.renderer.render()[:, :, 0].copy()
        finally:
            self.renderer.disable_segmentation_rendering()


def framed_points(model: mujoco.MjModel, data: mujoco.MjData,
                  robots: list[frozenset[int]]) -> np.ndarray:
    """What a picture of an episode frames: the drawn geoms of the robots (``robots``:
    each one's body ids) and of the work-piece, their centres and their bounding
    spheres' reach up and down, in the world as ``data`` has it (m)."""
    workpiece = [b for b in range(model.nbody) if model.body(b).name.startswith("workpiece/")]
    bodies = [b for r in robots for b in r] + workpiece
    geoms = np.flatnonzero(np.isin(model.geom_bodyid, bodies) & (model.geom_group < 3))
    centres, reach = data.geom_xpos[geoms], model.geom_rbound[geoms, None]
    up = np.array([0.0, 0.0, 1.0])
    return np.concatenate([centres, centres + reach * up, centres - reach * up])


def save_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB picture as PNG (OpenCV writes BGR)."""
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")


class Film:
    """The episode from an :class:`Overview` camera, one frame each 1/FILM_FPS s of
    simulated time at most, written as H.264 MP4 by imageio's ffmpeg writer."""

    def __init__(self, path: Path, overview: Overview) -> None:
        import imageio.v2 as imageio  # an optional part: only a filmed run needs it

        self.overview = overview
        self.writer = imageio.get_writer(str(path), fps=FILM_FPS, codec="libx264",
                                         quality=7, macro_block_size=8)
        self.last_s = -math.inf
        self.frames = 0

    def frame(self, data: mujoco.MjData, time_s: float | None) -> None:
        """A frame of the world now, if ``time_s`` (simulated, s) is a frame's interval
        past the last; a still (``time_s`` None: a mapping view) is held half a second."""
        if time_s is not None and 0.0 <= time_s - self.last_s < 1.0 / FILM_FPS:
            return
        picture = self.overview.render(data)
        for _ in range(FILM_FPS // 2 if time_s is None else 1):
            self.writer.append_data(picture)
            self.frames += 1
        if time_s is not None:
            self.last_s = time_s

    def close(self) -> None:
        self.writer.close()
