"""Placement methods by name: how the candidates for a robot's camera are chosen and in
what order they are tried.

A method is a callable that takes a :class:`MethodInput` (the targets, the camera, the
map, the placement region, a random generator, the settings, and the rating function on
request) and returns a :class:`RatingField` whose ``order`` lists the candidates to try,
first first (``order`` None: by rating, best first). The caller tries them in turn until
one is reachable and free of collision. A :class:`Method` adds what the caller checks
before it plans: whether the hole detector must find the target from there, and whether
the insertion site must be in focus and in frame.

Built-in methods are registered here by name; any other name is ``module:callable``, a
callable (or a :class:`Method`) imported from an importable module, so that every
process that runs trials (spawned or Dask workers) imports it by the same name.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from taskcam.mapping import GainModel, OccupancyGrid

from .errors import PlacementError
from .next_best_view import information_gain
from .random_views import biased_random, informed_random
from .rating import CameraModel, TargetModel
from .search import RatingField, Region


@dataclass(frozen=True)
class MethodSettings:
    """The scenario's settings of the built-in methods."""

    travel_per_m: float = 0.0  # rating: weighed by exp(-this x the base's drive beyond reach)
    informed_max_angle_deg: float = 60.0  # informed_random: off the target's normal, at most
    random_max_angle_deg: float = 60.0  # biased_random: off the target's normal, at most
    gain_samples: int = 300  # information_gain: random candidates evaluated


@dataclass(frozen=True)
class MethodInput:
    """What a placement method is given for one robot's camera (positions in m, world
    frame)."""

    targets: tuple[TargetModel, ...]  # it may view any of them
    primary: int  # the index of the primary target (what the task is about)
    camera: CameraModel
    grid: OccupancyGrid  # the robots' map, not to be changed
    region: Region  # where the camera may go: heights, the arm's reach of the base's range
    base_xy: np.ndarray  # where the robot's base stands (m)
    arm_reach_m: float  # the arm's reach from its base
    rng: np.random.Generator  # the method's only source of randomness
    settings: MethodSettings
    # the rating function over the region's known-free voxels in the depth of field,
    # other robots occluding (computed on the first call)
    rated: Callable[[], RatingField]
    # the rating function at given positions (n, 3), each for its target (indices, n):
    # for the record of a method that chooses by other means
    rate: Callable[[np.ndarray, np.ndarray], RatingField]
    # the expected information gain of views about the primary target's region
    gains: Callable[[], GainModel]


class Choose(Protocol):
    def __call__(self, given: MethodInput, /) -> RatingField: ...


@dataclass(frozen=True)
class Method:
    """A placement method and the checks its candidates pass before they are planned."""

    choose: Choose
    label: str = ""  # as reports name it
    detectable_only: bool = False  # skip candidates the hole detector cannot find it from
    site_in_frame: bool = False  # skip candidates that lose the insertion site


def travel_weighed(rated: RatingField, base: np.ndarray, per_m: float,
                   reach_m: float) -> RatingField:
    """The field ordered by its rating times exp(-``per_m`` x the base's drive to each
    candidate: its horizontal distance from ``base`` (m) beyond the arm's reach,
    ``reach_m``)."""
    drive = np.maximum(np.linalg.norm(rated.ratings.positions[:, :2] - base, axis=1)
                       - reach_m, 0.0)
    weighed = rated.ratings.total * np.exp(-per_m * drive)
    order = np.lexsort((np.arange(len(weighed)), -weighed))
    return RatingField(rated.ratings, rated.target, rated.strategy, rated.hulls,
                       order[weighed[order] > 0])


def by_rating(given: MethodInput) -> RatingField:
    """The rating function's candidates, best first (weighed by the base's travel if
    ``travel_per_m`` is set)."""
    rated = given.rated()
    if given.settings.travel_per_m > 0:
        return travel_weighed(rated, given.base_xy, given.settings.travel_per_m,
                              given.arm_reach_m)
    return rated


def by_biased_random(given: MethodInput) -> RatingField:
    """The paper's biased random positions (:func:`biased_random`), rated only for the
    record."""
    positions, aims = biased_random(given.grid, given.region, given.targets, given.rng,
                                    given.settings.random_max_angle_deg)
    recorded = given.rate(positions, aims)
    return RatingField(recorded.ratings, aims, "biased_random", recorded.hulls,
                       np.arange(len(positions)))


def by_informed_random(given: MethodInput) -> RatingField:
    """The rating function's candidates in a random order (:func:`informed_random`)."""
    return informed_random(given.rated(), given.targets, given.camera, given.rng,
                           given.settings.informed_max_angle_deg)


def by_information_gain(given: MethodInput) -> RatingField:
    """The rating function's candidates by expected information gain about the primary
    target's region (:func:`information_gain`)."""
    return information_gain(given.rated(), given.primary,
                            given.targets[given.primary].position, given.gains(), given.rng,
                            given.settings.gain_samples)


METHODS: dict[str, Method] = {
    "rating": Method(by_rating, "Optimal (rating function)", detectable_only=True,
                     site_in_frame=True),
    "biased_random": Method(by_biased_random, "Biased random"),
    "informed_random": Method(by_informed_random, "Informed random (rating candidates)",
                              detectable_only=True),
    "information_gain": Method(by_information_gain, "Next best view (information gain)",
                               detectable_only=True),
}

ACCEPTED = (", ".join(repr(n) for n in METHODS)
            + " or 'module:callable' (a placement method importable by every worker)")


def method_named(name: str) -> Method:
    """The method registered as ``name``, or the one ``module:callable`` names (a plain
    callable is a Method with no checks before planning). PlacementError says what is
    wrong with the name."""
    if name in METHODS:
        return METHODS[name]
    module_name, colon, attribute = name.partition(":")
    if not colon or not module_name or not attribute:
        raise PlacementError(f"placement method {name!r} unknown")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # anything the import raises: the name is unusable
        raise PlacementError(f"module {module_name!r} of placement method {name!r} not "
                             f"importable ({type(exc).__name__}: {exc})") from None
    found = module
    for part in attribute.split("."):
        if not hasattr(found, part):
            raise PlacementError(f"module {module_name!r} has no {attribute!r}")
        found = getattr(found, part)
    if isinstance(found, Method):
        return found
    if not callable(found):
        raise PlacementError(f"{name!r} is not callable ({type(found).__name__})")
    return Method(found, name)


def method_problem(name: str) -> str | None:
    """What is wrong with ``name`` as a placement method, or None if it names one."""
    try:
        method_named(name)
    except PlacementError as exc:
        return str(exc)
    return None


def method_label(name: str) -> str:
    """How reports name the method ``name``: its label, else the name."""
    method = METHODS.get(name)
    return method.label if method is not None and method.label else name
