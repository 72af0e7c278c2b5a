"""The layout a recording opens on (a rerun blueprint): the 3-D world large, beside it
each robot's camera image, below it the plots.

Each image view's origin is its robot's camera (``world/<robot>/camera``, the entity
with the pinhole), so it shows whatever that camera saw last on the timeline: the depth
of a mapping view, the last frame its pose was corrected from, the look, the task's
images. Its bounds are the image's, and the image column is as wide as images of the
camera's aspect need to fill their panels in a viewer of ``VIEWER_ASPECT``.
"""

from __future__ import annotations

import math

import numpy as np
import rerun.blueprint as rrb

VIEWER_ASPECT = 2.0  # width over height of the viewer's panel area (a 16:10 screen's)
WORLD_SHARE = 0.75  # of the panel area's height: the world and the images above the plots
TITLE_SHARE = 0.04  # of the panel area's height: a view's title bar


def image_columns(robots: int) -> int:
    """How many columns the image views are laid out in: one for up to two robots."""
    return 1 if robots <= 2 else 2


def image_share(robots: int, aspect: float) -> float:
    """The share of the viewer's width the image views take so that images of
    ``aspect`` (width over height) fill their panels, ``robots`` of them in
    :func:`image_columns` columns beside the world."""
    columns = image_columns(robots)
    rows = math.ceil(robots / columns)
    height = WORLD_SHARE / rows - TITLE_SHARE  # of one image, in the area's heights
    return min(0.5, columns * height * aspect / VIEWER_ASPECT)


def layout(robots: list[str], task: bool, image: tuple[int, int],
           eye: tuple[np.ndarray, np.ndarray] | None = None) -> rrb.Blueprint:
    """The 3-D world (seen from ``eye``: its position and the point it looks at, m; the
    depth images, drawn there as point clouds, left out), each robot's camera image
    (``image``: width, height, px) with what was found in it, and below, the mapped
    region's entropy and, with the ``task``, its displacement. It opens on the ``step``
    timeline, where the plots have their data (each mapping view, each placement, the
    look and each task step is a step; the moves play on ``sim_time``); the occupancy
    grid, the rated candidates and the occluder hulls start hidden."""
    width, height = image
    bounds = rrb.VisualBounds2D(x_range=[0.0, float(width)], y_range=[0.0, float(height)])
    cameras = [rrb.Spatial2DView(origin=f"world/{r}/camera", name=f"{r}: camera",
                                 visual_bounds=bounds) for r in robots]
    controls = None if eye is None else rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital, position=eye[0], look_target=eye[1], eye_up=[0.0, 0.0, 1.0])
    world = rrb.Spatial3DView(origin="world", name="world", eye_controls=controls,
                              contents=["+ $origin/**",
                                        *(f"- world/{r}/camera/depth" for r in robots)],
                              # the map and the ratings hide the scene: shown on request
                              overrides={path: rrb.EntityBehavior(visible=False) for path in
                                         ["world/grid", *(f"world/{r}/{part}" for r in robots
                                                          for part in ("candidates", "hulls"))]})
    plots = [rrb.TimeSeriesView(origin="mapping/region_entropy_bits",
                                name="mapping: the region's entropy (bits a voxel)")]
    if task:
        plots.append(rrb.TimeSeriesView(origin="task",
                                        name="task: displacement, measurement error (m)"))
    share = image_share(len(robots), width / height)
    images = rrb.Grid(*cameras, grid_columns=image_columns(len(robots)))
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(world, images, column_shares=[1.0 - share, share]),
                     rrb.Horizontal(*plots),
                     row_shares=[WORLD_SHARE, 1.0 - WORLD_SHARE]),
        rrb.TimePanel(timeline="step", state="collapsed"),
        collapse_panels=True)
