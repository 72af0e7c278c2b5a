"""Occluders for target field visibility: grid components, expanded by the target, hulled.

The paper's first two steps (sec. 2.3.3): the finite target is reduced to a point while
each occluder is expanded by the target's extent (the Minkowski sum of occluder and
target), and each expanded occluder is replaced by its convex hull. Each hull also keeps,
per face, how far the target's outline pushed that face out (``reach``): the hull of the
occluder expanded by a fraction s of the target is then ``A x <= b - (1 - s) reach``
exactly, which the sphere step uses for the exact (cone) expansion.

Occluders come from the grid as connected components (26-neighbourhood) of occupied
voxels (and, by default, never-observed ones) lying wholly above the target's plane
(what is below it cannot hide a target that faces up from it). A
component is split into blocks of at most ``block`` voxels a side before hulling, so
that a non-convex occluder (a beam on two posts) does not become one hull that swallows
the space it surrounds. Other robots' bodies come as point sets, one hull each.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

from taskcam.mapping import OccupancyGrid, circle_in_plane, stored_log_odds

from .rating import TargetModel

CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)


@dataclass(frozen=True)
class Hull:
    """A convex polytope ``A x <= b`` (outward unit normals): the hull of occluder points
    expanded by a target outline. Each vertex is an occluder point (``core``) plus an
    outline point (``spread``); ``reach`` is how far the outline pushed each face out
    (m), so the same occluder expanded by a scaled outline is exact in closed form."""

    A: np.ndarray  # (f, 3)
    b: np.ndarray  # (f,)
    reach: np.ndarray  # (f,) support of the outline along each face normal (m)
    core: np.ndarray  # (v, 3) occluder point of each vertex (m)
    spread: np.ndarray  # (v, 3) outline offset of each vertex (m)
    faces: np.ndarray  # (t, 3) vertex indices of the surface triangles

    @property
    def vertices(self) -> np.ndarray:
        return self.core + self.spread

    @property
    def triangles(self) -> np.ndarray:
        """(t, 3, 3) the hull's surface, for drawing."""
        return self.vertices[self.faces]

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        return np.all(np.atleast_2d(points) @ self.A.T <= self.b + tol, axis=1)

    def grown(self, factor: float) -> Hull:
        """The same occluder expanded by the outline scaled by ``factor`` > 0: the faces
        keep their normals (a Minkowski sum's normal fan does not change with a positive
        scale), so only their offsets and the outline parts of the vertices move."""
        return Hull(self.A, self.b + (factor - 1.0) * self.reach, factor * self.reach,
                    self.core, factor * self.spread, self.faces)


def target_outline(target: TargetModel, sides: int = 8) -> np.ndarray:
    """Offsets in the target's plane of a polygon that contains it: a disc's (``sides``
    corners, circumscribing the circle of its radius), or a slot's rectangle (its four
    corners, exactly)."""
    if target.half_length <= 0 or target.axis is None:
        return circle_in_plane(target.normal, target.radius / np.cos(np.pi / sides), sides)
    n = np.asarray(target.normal, float) / np.linalg.norm(target.normal)
    along = np.asarray(target.axis, float) - (np.asarray(target.axis, float) @ n) * n
    along /= np.linalg.norm(along)
    across = np.cross(n, along)
    return np.array([a * target.half_length * along + b * target.radius * across
                     for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))])


def hull_of(points: np.ndarray, outline: np.ndarray | None = None) -> Hull | None:
    """Convex hull of ``points`` expanded by ``outline`` offsets (n, 3), if given; None if
    it is flat or too small to hull."""
    if outline is None:
        outline = np.zeros((1, 3))
    summed = (points[:, None] + outline[None]).reshape(-1, 3)
    try:
        h = ConvexHull(summed)
    except (QhullError, ValueError):
        return None
    A = h.equations[:, :3]
    ids = np.unique(h.simplices)
    faces = np.searchsorted(ids, h.simplices)
    return Hull(A, -h.equations[:, 3], (A @ outline.T).max(axis=1),
                points[ids // len(outline)], outline[ids % len(outline)], faces)


def expand(points: np.ndarray, target: TargetModel, sides: int = 8,
           outline: np.ndarray | None = None) -> Hull | None:
    """The hull of ``points`` expanded by the target: hull(points + target outline)."""
    return hull_of(points, target_outline(target, sides) if outline is None else outline)


def grid_occluders(grid: OccupancyGrid, target: TargetModel, occupied: float = 0.5,
                   unknown_occludes: bool = True, block: int = 4) -> list[np.ndarray]:
    """Points (m) whose hull is each occluder piece: components of occupied (and unknown)
    voxels wholly above the target's plane, split into blocks of ``block`` voxels a side.
    Each piece is given by the corners of the voxels whose centres span its hull."""
    solid = grid.log_odds > stored_log_odds(occupied)
    if unknown_occludes:
        solid |= grid.log_odds == 0
    solid &= above_plane(grid, target)
    labels, count = ndimage.label(solid, structure=np.ones((3, 3, 3), dtype=bool))
    if count == 0:
        return []
    idx = np.argwhere(labels > 0)
    piece = labels[tuple(idx.T)].astype(np.int64)
    cell = idx // block
    keys = ((piece * 4096 + cell[:, 0]) * 4096 + cell[:, 1]) * 4096 + cell[:, 2]
    order = np.argsort(keys, kind="stable")
    keys, idx = keys[order], idx[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    pieces = []
    for lo, hi in zip(starts, np.r_[starts[1:], len(keys)], strict=True):
        centres = idx[lo:hi].astype(float)
        # hull(voxels) = hull(centres) + cube: only the centres' hull vertices matter
        # (a flat or tiny piece keeps every centre)
        with contextlib.suppress(QhullError, ValueError):
            centres = centres[ConvexHull(centres).vertices]
        corners = (centres[:, None, :] + CORNERS[None]).reshape(-1, 3)
        pieces.append(grid.origin + corners * grid.resolution)
    return pieces


def above_plane(grid: OccupancyGrid, target: TargetModel) -> np.ndarray:
    """Bool per voxel: does it lie wholly above the target's plane (its lowest corner)?"""
    n = target.normal / np.linalg.norm(target.normal)
    axes = [grid.origin[a] + (np.arange(grid.shape[a]) + 0.5) * grid.resolution
            - target.position[a] for a in range(3)]
    height = (n[0] * axes[0][:, None, None] + n[1] * axes[1][None, :, None]
              + n[2] * axes[2][None, None, :])
    return height - 0.5 * grid.resolution * np.abs(n).sum() > 0.0


def expanded_hulls(pieces: list[np.ndarray], target: TargetModel) -> list[Hull]:
    """Step (i) and (ii): each piece expanded by the target, then its convex hull."""
    hulls = []
    outline = target_outline(target)
    for points in pieces:
        h = expand(points, target, outline=outline)
        if h is not None:
            hulls.append(h)
    return hulls
