"""Random camera positions with heuristic bounds: the paper's biased random baseline, and
an informed variant that draws from the rating function's own candidates.

``biased_random`` is the paper's ("vision system position is selected randomly with some
heuristic constraints (bounded region of placement, bounded target angular view)"): any
voxel centre of the grid in the placement region, observed or not, free or not, within
an angle of a target's normal, in a random order. Nothing of the rating function takes
part: a draw the robot cannot take (in collision, out of reach) is refused by the
planner, and the next is tried.

``informed_random`` orders the rating function's candidates at random (known free, in
the depth of field) within an angle of a target's normal; occlusion and the rest of the
rating play no part in the order.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from taskcam.mapping import OccupancyGrid

from .rating import CameraModel, TargetModel
from .search import RatingField, Region, region_voxels


def first_within_angle(positions: np.ndarray, targets: Sequence[TargetModel],
                       max_angle_deg: float, near: float = 0.0,
                       far: float = np.inf) -> np.ndarray:
    """Per position (n, 3; m): the index of the first target it sees at most
    ``max_angle_deg`` off the target's normal, from ``near`` to ``far`` (m) away; -1
    where none."""
    which = np.full(len(positions), -1)
    for k, t in reversed(list(enumerate(targets))):  # the first qualifying target wins
        view = positions - t.position
        distance = np.linalg.norm(view, axis=1)
        n = t.normal / np.linalg.norm(t.normal)
        cos = (view @ n) / np.maximum(distance, 1e-12)
        ok = ((distance > 0) & (distance >= near) & (distance <= far)
              & (cos >= np.cos(np.radians(max_angle_deg))))
        which[ok] = k
    return which


def biased_random(grid: OccupancyGrid, region: Region, targets: Sequence[TargetModel],
                  rng: np.random.Generator, max_angle_deg: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The paper's biased random placement: every voxel centre of ``grid`` in ``region``
    (whatever the map holds there) that sees a target at most ``max_angle_deg`` off its
    normal, in a random order. Returns the positions (n, 3; m) and the index of the
    target each is aimed at (the first it qualifies for)."""
    positions = region_voxels(grid, region)
    which = first_within_angle(positions, targets, max_angle_deg)
    order = rng.permutation(np.flatnonzero(which >= 0))
    return positions[order], which[order]


def informed_random(rated: RatingField, targets: Sequence[TargetModel], camera: CameraModel,
                    rng: np.random.Generator, max_angle_deg: float = 60.0) -> RatingField:
    """The rating function's candidates (known free, within reach) that see a target
    within the depth of field and at most ``max_angle_deg`` off its normal, in a random
    order; occlusion and the rest of the rating are ignored. Each candidate keeps its
    rating (for the record) and is assigned the first target it qualifies for."""
    which = first_within_angle(rated.ratings.positions, targets, max_angle_deg,
                               camera.near, camera.far)
    admissible = np.flatnonzero(which >= 0)
    return RatingField(rated.ratings, np.where(which >= 0, which, rated.target),
                       "informed_random", rated.hulls, rng.permutation(admissible))
