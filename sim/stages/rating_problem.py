"""The rating function over one map (sec. 2.3): the question every placement search of
that map asks, with the answers already found.

The same question gets the same answer: methods started from one mapped state share
their first robot's rating field (a deterministic search draws nothing), and every
search of the map its occluders' hulls. A changed map is a new problem.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from taskcam.mapping import OccupancyGrid, Target
from taskcam.placement import (
    CameraModel,
    Hull,
    RatingField,
    Region,
    SearchSettings,
    TargetModel,
    Weights,
    rate_positions,
    search,
)
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.stages.timer import Timer


def camera_model(s: Scenario) -> CameraModel:
    """The scenario's camera as the rating function sees it."""
    cam = s.camera
    return CameraModel(math.radians(cam.fovy_deg), cam.height, cam.near_m, cam.far_m)


def target_model(t: Target) -> TargetModel:
    """A target as the rating function sees it (lifted along its normal, if it says so)."""
    return TargetModel(t.name, t.position + t.lift * t.normal, t.normal, t.radius, t.st_error,
                       t.half_length, t.axis)


class RatingProblem:
    """The rating of camera positions in one map, ``grid`` (not changed while this is
    searched), with the scenario's weights, search strategy and camera."""

    def __init__(self, grid: OccupancyGrid, scenario: Scenario) -> None:
        r, q = scenario.rating, scenario.search
        self.grid = grid
        self.camera = camera_model(scenario)
        self.weights = Weights(r.alpha, r.beta, r.gamma, r.delta)
        self.free_threshold = r.free_threshold
        self.settings = SearchSettings(q.strategy, q.coarse_step, q.max_distance_m, q.samples,
                                       r.unknown_occludes, r.hull_block,
                                       directions=r.tfv_directions, cone=r.expansion == "cone")
        self._fields: dict[tuple[object, ...], RatingField] = {}  # by question
        self._hulls: dict[tuple[float, ...], list[Hull]] = {}  # the map's occluders'

    def field(self, robot: str, targets: tuple[Target, ...], region: Region,
              others: list[np.ndarray], planned: np.ndarray, rng: np.random.Generator,
              timer: Timer | None) -> RatingField:
        """The rating field of ``targets`` over ``region`` for ``robot``, the other
        robots' bodies (point sets, m) occluding, with every robot at the joints
        ``planned`` (the belief's qpos). A random strategy searches afresh, drawing from
        ``rng``; a deterministic one answers a question asked before from memory. Timed as
        ``placement`` by ``timer``, if given."""
        key = (robot, tuple(t.name for t in targets), region, planned.tobytes())
        found = self._fields.get(key) if self.settings.strategy != "random" else None
        if found is None:
            with timer("placement") if timer is not None else contextlib.nullcontext():
                found = search(self.grid, [target_model(t) for t in targets], self.camera,
                               self.weights, self.free_threshold, region, self.settings, rng,
                               others, self._hulls)
            self._fields[key] = found
        return found

    def rated_at(self, targets: tuple[Target, ...], positions: np.ndarray, aims: np.ndarray,
                 others: list[np.ndarray]) -> RatingField:
        """The rating of camera ``positions`` (n, 3; m), each for its target (``aims``,
        indices into ``targets``), the other robots' bodies (point sets, m) occluding: for
        the record of a method that chooses by other means."""
        return rate_positions(self.grid, [target_model(t) for t in targets], self.camera,
                              positions, self.grid.probability_at(positions), self.weights,
                              self.settings, others, self._hulls, aims)
