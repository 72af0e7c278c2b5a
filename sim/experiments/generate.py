"""Random scenes at a requested occlusion density (Table 1's 5 %, 20 %, 35 %).

Obstacles (boxes and upright cylinders standing on the floor) are drawn one at a time
around the primary target, within the depth of field's far limit; one is kept if it
stays clear of the work-piece, the panel's way to its slot and the robots' bases, and
does not push the density (placement/density.py) past the request by more than the
tolerance. Drawing stops once the density is within half a point of the request (or,
after many draws, within the tolerance). The
achieved density is returned with the obstacles, to be recorded per trial.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from placement.density import Primitive, occlusion_density
from sim.config.scenario import ObstacleConfig, Scenario

TOLERANCE = 0.02  # the achieved density is within this of the request
AIM = 0.005  # drawing stops this close below the request
MAX_DRAWS = 2000


@dataclass(frozen=True)
class KeepOut:
    """A vertical cylinder obstacles must not enter: centre (x, y) and radius (m)."""

    x: float
    y: float
    radius: float


def keep_outs(s: Scenario) -> list[KeepOut]:
    """Where a scenario's obstacles must not stand: the work-piece (0.55 m about its
    centre), the panel where it lies (0.25 m: its way to the slot is then within these
    two) and each robot's base (0.7 m: room to turn and reach)."""
    return [KeepOut(*s.workpiece.position, 0.55), KeepOut(*s.panel.position[:2], 0.25),
            *[KeepOut(b.x, b.y, 0.7) for b in s.base_poses()]]


def primitive(o: ObstacleConfig) -> Primitive:
    return Primitive(o.shape, np.asarray(o.position, float), tuple(o.size),
                     math.radians(o.yaw_deg))


def footprint(o: ObstacleConfig) -> float:
    """The radius (m) of a circle about the obstacle's centre covering its footprint."""
    if o.shape == "box":
        return math.hypot(o.size[0], o.size[1])
    return o.size[0]


def draw(rng: np.random.Generator, target: np.ndarray, radius: float) -> ObstacleConfig:
    """One random obstacle standing on the floor, 0.25 m to 0.8 radius from the target
    (horizontally), tall enough to reach above the work-piece."""
    distance = rng.uniform(0.25, 0.8 * radius)
    angle = rng.uniform(0, 2 * math.pi)
    x, y = target[0] + distance * math.cos(angle), target[1] + distance * math.sin(angle)
    if rng.random() < 0.7:
        half = (rng.uniform(0.04, 0.15), rng.uniform(0.04, 0.25), rng.uniform(0.25, 0.6))
        return ObstacleConfig("box", (x, y, half[2]), half, float(rng.uniform(0, 180)))
    r, h = rng.uniform(0.03, 0.1), rng.uniform(0.25, 0.6)
    return ObstacleConfig("cylinder", (x, y, h), (r, h))


def generate(request: float, target: np.ndarray, normal: np.ndarray, radius: float,
             keep_out: list[KeepOut], rng: np.random.Generator
             ) -> tuple[tuple[ObstacleConfig, ...], float]:
    """Obstacles occluding ``request`` (a fraction) of the target's hemisphere within
    ``radius``, and the density achieved. Raises ValueError if it cannot be reached."""
    if not 0 <= request < 0.9:
        raise ValueError(f"occlusion density {request} is not in [0, 0.9)")
    chosen: list[ObstacleConfig] = []
    density = 0.0
    for _ in range(MAX_DRAWS):
        if density >= request - AIM:
            break
        o = draw(rng, target, radius)
        if any(math.hypot(o.position[0] - k.x, o.position[1] - k.y) < footprint(o) + k.radius
               for k in keep_out):
            continue
        trial = occlusion_density(target, normal, [primitive(c) for c in (*chosen, o)], radius)
        if trial > request + TOLERANCE or trial <= density:
            continue  # too much, or hides nothing new
        chosen.append(o)
        density = trial
    if abs(density - request) > TOLERANCE:
        raise ValueError(f"could not reach occlusion density {request:.2f} "
                         f"(got {density:.3f} after {MAX_DRAWS} draws)")
    return tuple(chosen), density
