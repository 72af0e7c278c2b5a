"""Next-best-view placement by expected information gain: a baseline for the rating
function.

An exploration planner, asked where to put the camera for the task, would choose the
view that teaches it most about the target region: here, among the candidates the
rating function's region allows (known free, within reach and height), a random
subset of ``samples`` is each given a camera looking at the target, and rated by the
expected information gain of that view over the target region (taskcam.mapping.GainModel:
visibility-weighted entropy). Candidates are tried best first. Depth of field,
resolution and the target's own visibility play no part, which is what sets it apart
from the rating function.
"""

from __future__ import annotations

import numpy as np

from taskcam.mapping import GainModel, View

from .search import RatingField


def look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``T_world_cam`` (4x4, OpenCV convention: +z forward, +y down) of a camera at
    ``position`` looking at ``target``, its x axis horizontal (m)."""
    z = np.asarray(target, float) - position
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:  # looking straight up or down
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = position
    return T


def information_gain(rated: RatingField, aim: int, target: np.ndarray, gains: GainModel,
                     rng: np.random.Generator, samples: int = 300) -> RatingField:
    """The candidates of ``rated`` ordered by the expected information gain of a view
    from there at ``target`` (m), best first (ties by index); at most ``samples`` of
    them, drawn at random. Every candidate is assigned target index ``aim``; its rating
    is kept for the record."""
    n = len(rated.target)
    drawn = np.sort(rng.choice(n, min(samples, n), replace=False))
    positions = rated.ratings.positions[drawn]
    gain = gains.gains([View(look_at(p, target)) for p in positions])
    order = drawn[np.lexsort((drawn, -gain))]
    return RatingField(rated.ratings, np.full(n, aim), "information_gain", rated.hulls, order)
