"""A placement method of one's own: the rating function's candidates, nearest the target
first.

A placement method takes a ``taskcam.placement.MethodInput`` (the targets, the camera, the map,
the placement region, a random generator, the settings, and the rating function on
request) and returns a ``taskcam.placement.RatingField`` whose ``order`` lists the candidates to
try, first first. Wrapped in a ``taskcam.placement.Method``, it also says which checks its
candidates pass before they are planned. A scenario or sweep file names it as
``module:callable``::

    [[methods]]
    name = "nearest"
    placement = "examples.nearest_first:method"

The module must be importable in every process that runs trials: run from the
repository root with it on the path (``PYTHONPATH=.``); spawned workers inherit the
path, Dask workers need it too. ``examples/nearest_first.toml`` is a small sweep with it:

    PYTHONPATH=. taskcam sweep examples/nearest_first.toml --db runs/nearest.sqlite --workers 2

Nearer views have more pixels on the target, but they see less around it and are the
first a cluttered scene blocks; the rating function weighs both, this method only the
first.
"""

from __future__ import annotations

import numpy as np

from taskcam.placement import Method, MethodInput, RatingField


def nearest_first(given: MethodInput) -> RatingField:
    """The rating function's candidates (known free, in the depth of field) with a
    positive rating, ordered by their distance (m) from the primary target, nearest
    first (ties by index); every one aimed at the primary target."""
    rated = given.rated()
    target = given.targets[given.primary]
    distance = np.linalg.norm(rated.ratings.positions - target.position, axis=1)
    order = np.lexsort((np.arange(len(distance)), distance))
    order = order[rated.ratings.total[order] > 0]
    return RatingField(rated.ratings, np.full(len(distance), given.primary), "nearest_first",
                       rated.hulls, order)


# the checks before planning: only views the hole detector can find the target from
method = Method(nearest_first, "Nearest first (example)", detectable_only=True)
