"""Exact voxel traversal of many rays at once (3-D DDA, Amanatides and Woo, 1987).

Coordinates are in grid units: voxel (i, j, k) spans [i, i + 1) x [j, j + 1) x [k, k + 1).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np


def clip_to_box(origins: np.ndarray, dirs: np.ndarray, length: np.ndarray,
                lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameter interval [t0, t1] of each segment ``origin + t dir``, t in [0, length],
    inside the box; empty where t1 <= t0. ``dirs`` need not be unit."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / dirs
        ta, tb = (lo - origins) * inv, (hi - origins) * inv
    tmin = np.nan_to_num(np.minimum(ta, tb), nan=-np.inf)
    tmax = np.nan_to_num(np.maximum(ta, tb), nan=np.inf)
    return np.maximum(tmin.max(axis=1), 0.0), np.minimum(tmax.min(axis=1), length)


def _walk(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
          lengths: np.ndarray, stop: np.ndarray | None = None
          ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (ray index, flat voxel index) for every ray still going, one voxel per step.

    A ray ends when its segment does, when it leaves the grid, or, with ``stop`` (flat
    bool per voxel), right after it enters a voxel where ``stop`` is True.
    """
    dims = np.array(shape)
    dirs = np.asarray(dirs, dtype=float)
    origins = np.broadcast_to(np.asarray(origins, dtype=float), dirs.shape)
    t0, t1 = clip_to_box(origins, dirs, np.asarray(lengths, float), np.zeros(3), dims)
    ray = np.flatnonzero(t1 > t0)
    if len(ray) == 0:
        return
    d, t_end = dirs[ray], t1[ray]
    p = origins[ray] + t0[ray, None] * d
    idx = np.clip(np.floor(p).astype(np.int64), 0, dims - 1)
    step = np.sign(d).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_delta = np.where(step != 0, 1.0 / np.abs(d), np.inf)
        t_max = np.where(step != 0, t0[ray, None] + (idx + (step > 0) - p) / d, np.inf)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    flat = idx @ strides
    flat_step = step * strides
    while len(ray):
        yield ray, flat
        rows = np.arange(len(ray))
        axis = np.argmin(t_max, axis=1)
        t_exit = t_max[rows, axis]
        idx[rows, axis] += step[rows, axis]
        t_max[rows, axis] += t_delta[rows, axis]
        flat = flat + flat_step[rows, axis]
        moved = idx[rows, axis]
        go = (t_exit < t_end) & (moved >= 0) & (moved < dims[axis])
        if stop is not None:
            go &= ~stop[flat - flat_step[rows, axis]]
        if not go.all():
            ray, idx, t_max, step, t_delta, t_end, flat, flat_step = (
                ray[go], idx[go], t_max[go], step[go], t_delta[go], t_end[go], flat[go],
                flat_step[go])


def traverse(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
             lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every voxel each segment crosses: (ray index, flat voxel index) pairs.

    ``origins`` (n, 3) or (3,), ``dirs`` (n, 3) unit vectors, ``lengths`` (n,). A
    segment that only touches an edge or a corner may or may not include the voxels
    meeting there.
    """
    steps = list(_walk(shape, origins, dirs, lengths))
    if not steps:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    return np.concatenate([r for r, _ in steps]), np.concatenate([v for _, v in steps])


def first_hits(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
               lengths: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """Boolean per ray: does its segment enter a voxel where ``blocked`` (flat) is True?

    Each ray stops at its first blocked voxel, so cluttered scenes cost less.
    """
    hit = np.zeros(len(dirs), dtype=bool)
    for ray, flat in _walk(shape, origins, dirs, lengths, stop=blocked):
        hit[ray[blocked[flat]]] = True
    return hit
