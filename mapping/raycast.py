"""Exact voxel traversal of many rays at once (3-D DDA, Amanatides and Woo, 1987)."""

from __future__ import annotations

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


def traverse(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
             lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every voxel each segment crosses, in grid units (voxel i spans [i, i + 1)).

    ``origins`` (n, 3) or (3,), ``dirs`` (n, 3) unit vectors, ``lengths`` (n,). Returns
    (ray index, flat voxel index) pairs, in order along each ray. A segment that only
    touches an edge or a corner may or may not include the voxels meeting there.
    """
    dims = np.array(shape)
    dirs = np.asarray(dirs, dtype=float)
    origins = np.broadcast_to(np.asarray(origins, dtype=float), dirs.shape)
    t0, t1 = clip_to_box(origins, dirs, np.asarray(lengths, float), np.zeros(3), dims)
    ray = np.flatnonzero(t1 > t0)
    if len(ray) == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    d, t_end = dirs[ray], t1[ray]
    p = origins[ray] + t0[ray, None] * d
    idx = np.clip(np.floor(p).astype(np.int64), 0, dims - 1)
    step = np.sign(d).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_delta = np.where(step != 0, 1.0 / np.abs(d), np.inf)
        boundary = idx + (step > 0)
        t_max = np.where(step != 0, t0[ray, None] + (boundary - p) / d, np.inf)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    rays_out, voxels_out = [], []
    rows = np.arange(len(ray))
    while len(ray):
        rays_out.append(ray)
        voxels_out.append(idx @ strides)
        axis = np.argmin(t_max, axis=1)
        t_exit = t_max[rows, axis]
        idx[rows, axis] += step[rows, axis]
        t_max[rows, axis] += t_delta[rows, axis]
        go = (t_exit < t_end) & (idx[rows, axis] >= 0) & (idx[rows, axis] < dims[axis])
        if not go.all():
            ray, idx, t_max, step, t_delta, t_end = (
                ray[go], idx[go], t_max[go], step[go], t_delta[go], t_end[go])
            rows = np.arange(len(ray))
    return np.concatenate(rays_out), np.concatenate(voxels_out)
