"""The paper's Figure 7: the rating function over a planar world, one occluder in two places.

A 100 x 100 world of unit cells; the primary target at (50, 50), a secondary at
(50, 75) with a geometric tolerance (eq. 4); both face +x. The world is known (every
cell free but the occluder's). In the first instance the occluder stands aside and the
best camera position views the primary target; in the second it stands in front of the
primary, and the best position views the secondary. The rating field is computed by
the same code as in 3-D (taskcam.placement.search) on a grid one cell thick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from taskcam.mapping import OccupancyGrid, SensorModel
from taskcam.placement.rating import CameraModel, TargetModel
from taskcam.placement.search import RatingField, search

SIZE = 100
PRIMARY = TargetModel("primary", np.array([50.0, 50.0, 0.0]), np.array([1.0, 0.0, 0.0]), 1.0)
SECONDARY = TargetModel("secondary", np.array([50.0, 75.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                        1.0, st_error=0.05)
CAMERA = CameraModel(fov=math.radians(60), pixels=480, near=5.0, far=40.0)


@dataclass(frozen=True)
class Instance:
    name: str
    occluder: tuple[tuple[int, int], tuple[int, int]]  # (x0, x1), (y0, y1): cells, inclusive


INSTANCES = (
    Instance("a", ((20, 27), (80, 95))),  # aside: behind the targets
    Instance("b", ((53, 60), (25, 66))),  # in front of the primary target
)


def world(instance: Instance) -> OccupancyGrid:
    grid = OccupancyGrid.from_bounds(np.array([0.0, 0.0, -0.5]), np.array([SIZE, SIZE, 0.5]),
                                     1.0, SensorModel())
    grid.set_probability(0.01)
    (x0, x1), (y0, y1) = instance.occluder
    solid = np.zeros(grid.shape, dtype=bool)
    solid[x0:x1 + 1, y0:y1 + 1, :] = True
    grid.set_probability(0.99, solid)
    return grid


def rate_instance(instance: Instance) -> tuple[RatingField, np.ndarray]:
    """The rating field and the rating per cell (max over targets; 0 where none)."""
    field = search(world(instance), [PRIMARY, SECONDARY], CAMERA)
    image = np.zeros((SIZE, SIZE))
    cells = np.floor(field.ratings.positions[:, :2]).astype(int)
    image[cells[:, 0], cells[:, 1]] = field.ratings.total
    return field, image


def draw(image: np.ndarray, instance: Instance, best: np.ndarray, scale: int = 5) -> np.ndarray:
    """The paper's convention: darker is better. Occluder grey, targets blue, optimum red."""
    top = image.max() if image.max() > 0 else 1.0
    gray = (255 * (1 - image / top)).astype(np.uint8).T[::-1]  # rows: y from the top
    rgb = cv2.cvtColor(cv2.resize(gray, None, fx=scale, fy=scale,
                                  interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)

    def px(x: float, y: float) -> tuple[int, int]:
        return int(x * scale), int((SIZE - y) * scale)

    (x0, x1), (y0, y1) = instance.occluder
    cv2.rectangle(rgb, px(x0, y1 + 1), px(x1 + 1, y0), (120, 120, 120), -1)
    for t in (PRIMARY, SECONDARY):
        cv2.circle(rgb, px(t.position[0], t.position[1]), 2 * scale // 2 + 2, (200, 80, 0), -1)
    cx, cy = px(best[0], best[1])
    cv2.drawMarker(rgb, (cx, cy), (0, 0, 230), cv2.MARKER_TILTED_CROSS, 4 * scale, 2)
    return rgb


def figure7(out: Path) -> dict[str, Any]:
    """Write ``figure7_<instance>.png`` heatmaps and ``figure7.json`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"world": [SIZE, SIZE], "camera": CAMERA.__dict__,
                              "targets": [], "instances": []}
    for t in (PRIMARY, SECONDARY):
        report["targets"].append({"name": t.name, "position": t.position[:2].tolist(),
                                  "normal": t.normal[:2].tolist(), "st_error": t.st_error})
    for instance in INSTANCES:
        field, image = rate_instance(instance)
        i = int(field.ranked()[0])
        best = field.ratings.positions[i]
        cv2.imwrite(str(out / f"figure7_{instance.name}.png"), draw(image, instance, best))
        (x0, x1), (y0, y1) = instance.occluder
        report["instances"].append({
            "instance": instance.name,
            "occluder": {"x": [x0, x1 + 1], "y": [y0, y1 + 1]},
            "optimum": best[:2].tolist(),
            "target": [PRIMARY, SECONDARY][int(field.target[i])].name,
            "rating": field.ratings.terms(i),
            "candidates": field.evaluated,
            "image": f"figure7_{instance.name}.png",
        })
    return report
