"""Occlusion density (sec. 3, Table 1): how much of the view of a target is blocked.

The paper measures it as the share of the angular projection from the target onto a
target-centred circle, of radius the far limit of the depth of field, that obstacles
occlude. In 3-D the circle becomes the hemisphere above the target's surface: the
density is the fraction of directions (uniform in solid angle, above ``min_elevation``)
whose ray from the target meets an obstacle within the radius.

Obstacles are the scenario's primitives: boxes (half extents, turned about z by a yaw),
upright cylinders (radius, half height) and spheres, each by its centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Primitive:
    """An obstacle: shape ("box", "cylinder", "sphere"), centre (m), size (as the
    scenario gives it) and yaw (rad, boxes)."""

    shape: str
    centre: np.ndarray
    size: tuple[float, ...]
    yaw: float = 0.0


def hemisphere(normal: np.ndarray, count: int, min_elevation_rad: float) -> np.ndarray:
    """Unit directions (count, 3) spread evenly in solid angle over the part of the
    hemisphere about ``normal`` at least ``min_elevation_rad`` above its rim."""
    i = np.arange(count) + 0.5
    top = 1.0
    bottom = math.sin(min_elevation_rad)
    z = top - (top - bottom) * i / count  # uniform in z is uniform in solid angle
    phi = i * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    r = np.sqrt(1 - z ** 2)
    local = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    n = normal / np.linalg.norm(normal)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return local @ np.stack([e1, e2, n])


DIRECTIONS = 4000  # directions the density is counted over
MIN_ELEVATION_RAD = math.radians(10.0)  # from this elevation up
BAND_RAD = math.radians(10.0)  # elevation bands (10-20, ..., 80-90 deg) reported apart


def band_count() -> int:
    """How many elevation bands the hemisphere above MIN_ELEVATION_RAD has."""
    return round((math.pi / 2 - MIN_ELEVATION_RAD) / BAND_RAD)


def elevation_bands(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The counting directions (DIRECTIONS, 3) over the hemisphere about ``normal`` and
    the elevation band (index, lowest first) each lies in."""
    directions = hemisphere(normal, DIRECTIONS, MIN_ELEVATION_RAD)
    n = normal / np.linalg.norm(normal)
    elevation = np.arcsin(np.clip(directions @ n, -1.0, 1.0))
    band = ((elevation - MIN_ELEVATION_RAD) // BAND_RAD).astype(int)
    return directions, np.clip(band, 0, band_count() - 1)


def band_shares(blocked: np.ndarray, band: np.ndarray) -> np.ndarray:
    """The blocked share of each elevation band, given which directions are blocked."""
    count = np.bincount(band, minlength=band_count())
    return np.bincount(band, weights=blocked, minlength=band_count()) / np.maximum(count, 1)


def ray_hits(origin: np.ndarray, directions: np.ndarray, p: Primitive, reach: float
             ) -> np.ndarray:
    """Whether each ray from ``origin`` meets the primitive within ``reach`` (m)."""
    return ray_entry(origin, directions, p) <= reach


def ray_entry(origin: np.ndarray, directions: np.ndarray, p: Primitive) -> np.ndarray:
    """How far (m) each ray from ``origin`` goes before it meets the primitive (0 from
    inside it; inf: never)."""
    o = origin - p.centre
    d = directions
    if p.shape == "sphere":
        r = p.size[0]
        b = d @ o
        disc = b ** 2 - (o @ o - r * r)
        far = -b + np.sqrt(np.maximum(disc, 0.0))
        near = -b - np.sqrt(np.maximum(disc, 0.0))
        return np.where((disc >= 0) & (far >= 0), np.maximum(near, 0.0), np.inf)
    if p.shape == "box":
        c, s = math.cos(p.yaw), math.sin(p.yaw)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        o, d = R.T @ o, d @ R  # into the box's frame
        half = np.asarray(p.size)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / d, (half - o) / d
        lo = np.nanmax(np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2)), axis=1)
        hi = np.nanmin(np.where(np.isnan(t2), np.inf, np.maximum(t1, t2)), axis=1)
        inside_slab = np.all((np.abs(d) > 1e-12) | (np.abs(o) <= half), axis=1)
        return np.where(inside_slab & (hi >= np.maximum(lo, 0.0)), np.maximum(lo, 0.0), np.inf)
    # an upright cylinder: the infinite cylinder's interval, cut by the two caps
    radius, half_h = p.size[0], p.size[1]
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (o[0] * d[:, 0] + o[1] * d[:, 1])
    cc = o[0] ** 2 + o[1] ** 2 - radius ** 2
    disc = b ** 2 - 4 * a * cc
    flat = a < 1e-12
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = np.where(flat, np.where(cc <= 0, -np.inf, np.inf), (-b - root) / (2 * a))
        hi = np.where(flat, np.where(cc <= 0, np.inf, -np.inf), (-b + root) / (2 * a))
        tz1, tz2 = (-half_h - o[2]) / d[:, 2], (half_h - o[2]) / d[:, 2]
    level = np.abs(d[:, 2]) <= 1e-12  # a horizontal ray: within the caps or never
    between = abs(o[2]) <= half_h
    zlo = np.where(level, -np.inf if between else np.inf, np.minimum(tz1, tz2))
    zhi = np.where(level, np.inf if between else -np.inf, np.maximum(tz1, tz2))
    start, end = np.maximum(lo, zlo), np.minimum(hi, zhi)
    ok = (flat | (disc >= 0)) & (end >= np.maximum(start, 0.0))
    return np.where(ok, np.maximum(start, 0.0), np.inf)


def first_hits(origin: np.ndarray, directions: np.ndarray, obstacles: list[Primitive]
               ) -> np.ndarray:
    """How far (m) each ray from ``origin`` goes before its first obstacle (inf: none)."""
    first = np.full(len(directions), np.inf)
    for p in obstacles:
        first = np.minimum(first, ray_entry(np.asarray(origin, float), directions, p))
    return first


def occlusion_density(target: np.ndarray, normal: np.ndarray, obstacles: list[Primitive],
                      radius: float, count: int = DIRECTIONS,
                      min_elevation_rad: float = MIN_ELEVATION_RAD) -> float:
    """The fraction of the hemisphere's directions from the target that an obstacle
    blocks within ``radius`` (m)."""
    directions = hemisphere(normal, count, min_elevation_rad)
    return float((first_hits(target, directions, obstacles) <= radius).mean())
