"""Exact voxel traversal of many rays (3-D DDA, Amanatides and Woo, 1987), compiled.

Coordinates are in grid units: voxel (i, j, k) spans [i, i + 1) x [j, j + 1) x [k, k + 1),
and flat indices are C order. Directions are unit vectors in grid units; lengths are in
voxels. A segment that only touches an edge or a corner of a voxel may or may not count
as crossing it. Kernels run in parallel over rays (numba); their results do not depend
on the thread count.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _clip(o0: float, o1: float, o2: float, d0: float, d1: float, d2: float, length: float,
          n0: int, n1: int, n2: int) -> tuple[float, float]:
    """Parameter interval [t0, t1] of the segment inside the box [0, n)."""
    t0, t1 = 0.0, length
    for o, d, n in ((o0, d0, n0), (o1, d1, n1), (o2, d2, n2)):
        if d == 0.0:
            if o < 0.0 or o >= n:
                return 1.0, 0.0
            continue
        a, b = (0.0 - o) / d, (n - o) / d
        if a > b:
            a, b = b, a
        t0, t1 = max(t0, a), min(t1, b)
    return t0, t1


@nb.njit(cache=True, inline="always")
def _start(o: float, d: float, t0: float, n: int) -> tuple[int, int, float, float]:
    """Voxel index, step, first boundary crossing and crossing spacing along one axis."""
    i = int(np.floor(o + t0 * d))
    i = min(max(i, 0), n - 1)
    if d > 0.0:
        return i, 1, t0 + (i + 1 - (o + t0 * d)) / d, 1.0 / d
    if d < 0.0:
        return i, -1, t0 + (i - (o + t0 * d)) / d, -1.0 / d
    return i, 0, np.inf, np.inf


@nb.njit(cache=True)
def walk_segment(o: np.ndarray, d: np.ndarray, length: float, shape: tuple[int, int, int],
          out: np.ndarray, stop: np.ndarray, start: float = 0.0) -> int:
    """Write the flat indices that the segment from ``start`` to ``length`` crosses into
    ``out``; return how many. With a non-empty ``stop`` (flat bool), end after the first
    voxel where it is True."""
    n0, n1, n2 = shape
    t0, t1 = _clip(o[0], o[1], o[2], d[0], d[1], d[2], length, n0, n1, n2)
    t0 = max(t0, start)
    if t1 <= t0:
        return 0
    i, s0, m0, dt0 = _start(o[0], d[0], t0, n0)
    j, s1, m1, dt1 = _start(o[1], d[1], t0, n1)
    k, s2, m2, dt2 = _start(o[2], d[2], t0, n2)
    count = 0
    check = len(stop) > 0
    while True:
        v = (i * n1 + j) * n2 + k
        out[count] = v
        count += 1
        if check and stop[v]:
            break
        if m0 <= m1 and m0 <= m2:
            if m0 >= t1:
                break
            i += s0
            m0 += dt0
            if i < 0 or i >= n0:
                break
        elif m1 <= m2:
            if m1 >= t1:
                break
            j += s1
            m1 += dt1
            if j < 0 or j >= n1:
                break
        else:
            if m2 >= t1:
                break
            k += s2
            m2 += dt2
            if k < 0 or k >= n2:
                break
    return count


def max_ray_voxels(shape: tuple[int, int, int]) -> int:
    return shape[0] + shape[1] + shape[2] + 3


CHUNK = 512  # rays per parallel work item


def _prepare(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
             lengths: np.ndarray) -> tuple[tuple[int, int, int], np.ndarray, np.ndarray,
                                           np.ndarray]:
    dirs = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    origins = np.ascontiguousarray(np.broadcast_to(origins, dirs.shape), dtype=np.float64)
    lengths = np.ascontiguousarray(np.broadcast_to(lengths, len(dirs)), dtype=np.float64)
    return (int(shape[0]), int(shape[1]), int(shape[2])), origins, dirs, lengths


@nb.njit(cache=True)
def _traverse(origins: np.ndarray, dirs: np.ndarray, lengths: np.ndarray,
              shape: tuple[int, int, int], max_steps: int) -> tuple[np.ndarray, np.ndarray]:
    n = len(dirs)
    counts = np.zeros(n, dtype=np.int64)
    buf = np.empty(max_steps, dtype=np.int64)
    no_stop = np.zeros(0, dtype=np.bool_)
    for r in range(n):
        counts[r] = walk_segment(origins[r], dirs[r], lengths[r], shape, buf, no_stop)
    rays = np.empty(counts.sum(), dtype=np.int64)
    voxels = np.empty(counts.sum(), dtype=np.int64)
    at = 0
    for r in range(n):
        c = walk_segment(origins[r], dirs[r], lengths[r], shape, buf, no_stop)
        rays[at:at + c] = r
        voxels[at:at + c] = buf[:c]
        at += c
    return rays, voxels


def traverse(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
             lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every voxel each segment crosses, as (ray index, flat voxel index) pairs in order
    along each ray. ``origins`` (n, 3) or (3,), ``dirs`` (n, 3), ``lengths`` (n,)."""
    shape, origins, dirs, lengths = _prepare(shape, origins, dirs, lengths)
    return _traverse(origins, dirs, lengths, shape, max_ray_voxels(shape))


@nb.njit(cache=True, parallel=True)
def _first_hits(origins: np.ndarray, dirs: np.ndarray, lengths: np.ndarray,
                shape: tuple[int, int, int], blocked: np.ndarray, max_steps: int) -> np.ndarray:
    n = len(dirs)
    hit = np.zeros(n, dtype=np.bool_)
    for chunk in nb.prange((n + CHUNK - 1) // CHUNK):
        buf = np.empty(max_steps, dtype=np.int64)
        for r in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            c = walk_segment(origins[r], dirs[r], lengths[r], shape, buf, blocked)
            hit[r] = c > 0 and blocked[buf[c - 1]]
    return hit


def first_hits(shape: tuple[int, int, int], origins: np.ndarray, dirs: np.ndarray,
               lengths: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """Boolean per ray: does its segment enter a voxel where ``blocked`` (flat) is True?"""
    shape, origins, dirs, lengths = _prepare(shape, origins, dirs, lengths)
    return _first_hits(origins, dirs, lengths, shape, np.ascontiguousarray(blocked).ravel(),
                       max_ray_voxels(shape))


@nb.njit(cache=True, inline="always")
def _stamp_free(stamp: np.ndarray, voxels: np.ndarray, count: int, occupied_code: int,
                free_code: int) -> None:
    """Stamp the first ``count`` voxels free unless stamped occupied; write only changes,
    so threads do not fight over cache lines."""
    for s in range(count):
        v = stamp[voxels[s]]
        if v != occupied_code and v != free_code:
            stamp[voxels[s]] = free_code


# ---------------------------------------------------------------- shared rays of an image


@nb.njit(cache=True, inline="always")
def _pixel_ray(p: int, cols: int, stride: int, fx: float, fy: float, cx: float, cy: float,
               R: np.ndarray, out: np.ndarray) -> None:
    """Unit world direction of the ray through pixel ``p`` (row-major, every ``stride``)."""
    x = ((p % cols) * stride - cx) / fx
    y = ((p // cols) * stride - cy) / fy
    norm = np.sqrt(x * x + y * y + 1.0)
    for a in range(3):
        out[a] = (R[a, 0] * x + R[a, 1] * y + R[a, 2]) / norm


@nb.njit(cache=True)
def _block_minima(lengths: np.ndarray, levels: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel block of side 2^l (l = 1..levels): the shortest ray and its pixel.

    Returns (minimum, pixel, offset, block rows, block columns); level l's block (bu, bv)
    is at ``offset[l] + bv * columns[l] + bu``. Level 0 is the image itself (not stored).
    Rays of NaN length do not exist; a block without rays has pixel -1.
    """
    rows = np.zeros(levels + 1, dtype=np.int64)
    cols = np.zeros(levels + 1, dtype=np.int64)
    rows[0], cols[0] = lengths.shape
    offsets = np.zeros(levels + 2, dtype=np.int64)
    for lv in range(1, levels + 1):
        rows[lv], cols[lv] = (rows[lv - 1] + 1) // 2, (cols[lv - 1] + 1) // 2
        offsets[lv + 1] = offsets[lv] + rows[lv] * cols[lv]  # offsets[1] = 0
    minimum = np.full(offsets[levels + 1], np.inf, dtype=np.float32)
    pixel = np.full(offsets[levels + 1], -1, dtype=np.int32)
    flat = lengths.ravel()
    for lv in range(1, levels + 1):
        for bv in range(rows[lv]):
            for bu in range(cols[lv]):
                best, arg = np.float32(np.inf), -1
                for cv in range(2 * bv, min(2 * bv + 2, rows[lv - 1])):
                    for cu in range(2 * bu, min(2 * bu + 2, cols[lv - 1])):
                        if lv == 1:
                            c = cv * cols[0] + cu
                            value, who = flat[c], c
                            if np.isnan(value):
                                continue
                        else:
                            c = offsets[lv - 1] + cv * cols[lv - 1] + cu
                            value, who = minimum[c], pixel[c]
                            if who < 0:
                                continue
                        if arg < 0 or value < best:
                            best, arg = value, who
                at = offsets[lv] + bv * cols[lv] + bu
                minimum[at], pixel[at] = best, arg
    return minimum, pixel, offsets, rows, cols


def image_working_bytes(rows: int, cols: int, levels: int) -> int:
    """Memory (bytes) that sharing rays needs beside the grid: the float32 ray lengths,
    and a float32 minimum and an int32 pixel per block of levels 1 to ``levels``."""
    total = rows * cols * 4
    for _ in range(levels):
        rows, cols = (rows + 1) // 2, (cols + 1) // 2
        total += rows * cols * 8
    return total


BLOCKS_PER_ITEM = 16  # top-level blocks per parallel work item


@nb.njit(cache=True, parallel=True)
def _mark_free_image(origin: np.ndarray, R: np.ndarray, fx: float, fy: float, cx: float,
                     cy: float, stride: int, lengths: np.ndarray, band_end: np.ndarray,
                     shape: tuple[int, int, int], stamp: np.ndarray, occupied_code: int,
                     free_code: int, max_steps: int) -> None:
    levels = len(band_end) - 1
    minimum, pixel, offsets, rows, cols = _block_minima(lengths, levels)
    flat = lengths.ravel()
    top = rows[levels] * cols[levels]
    items = (top + BLOCKS_PER_ITEM - 1) // BLOCKS_PER_ITEM
    no_stop = np.zeros(0, dtype=np.bool_)
    for item in nb.prange(items):
        buf = np.empty(max_steps, dtype=np.int64)
        direction = np.empty(3)
        depth = 4 * levels + 4
        st_level = np.empty(depth, dtype=np.int64)
        st_u = np.empty(depth, dtype=np.int64)
        st_v = np.empty(depth, dtype=np.int64)
        st_t = np.empty(depth)
        for k in range(item * BLOCKS_PER_ITEM, min(top, (item + 1) * BLOCKS_PER_ITEM)):
            # Threads take contiguous ranges of items: spread each over the image.
            b = (k * 7919) % top if top % 7919 else k
            st_level[0], st_t[0] = levels, 0.0
            st_u[0], st_v[0] = b % cols[levels], b // cols[levels]
            n = 1
            while n > 0:
                n -= 1
                lv, bu, bv, t_a = st_level[n], st_u[n], st_v[n], st_t[n]
                if lv == 0:
                    ray = bv * cols[0] + bu
                    t_b = flat[ray]
                    if np.isnan(t_b):
                        continue
                else:
                    at = offsets[lv] + bv * cols[lv] + bu
                    ray = pixel[at]
                    if ray < 0:
                        continue  # no ray in the block
                    # Every ray of the block reaches minimum[at]: one of them speaks for
                    # all up to there, or to the end of the level's band; the sub-blocks
                    # go on from there.
                    t_b = min(minimum[at], band_end[lv])
                if t_b > t_a:
                    _pixel_ray(ray, cols[0], stride, fx, fy, cx, cy, R, direction)
                    c = walk_segment(origin, direction, t_b, shape, buf, no_stop, t_a)
                    _stamp_free(stamp, buf, c, occupied_code, free_code)
                if lv > 0:
                    for cv in range(2 * bv, min(2 * bv + 2, rows[lv - 1])):
                        for cu in range(2 * bu, min(2 * bu + 2, cols[lv - 1])):
                            st_level[n], st_u[n], st_v[n] = lv - 1, cu, cv
                            st_t[n] = max(t_a, t_b)
                            n += 1


def mark_free_image(shape: tuple[int, int, int], origin: np.ndarray, R: np.ndarray,
                    camera: tuple[float, float, float, float], stride: int,
                    lengths: np.ndarray, stamp: np.ndarray, occupied_code: int,
                    free_code: int, band_end: np.ndarray) -> None:
    """Stamp ``free_code`` on every voxel the rays of an image cross, unless stamped
    occupied, sharing the traversal between neighbouring rays.

    Rays start at ``origin`` (grid units) through every ``stride``-th pixel of a pinhole
    camera ``(fx, fy, cx, cy)`` rotated by ``R`` (world from OpenCV camera); ``lengths``
    (rows, cols) are in voxels, NaN where a pixel has no ray. Level l groups blocks of
    2^l x 2^l rays. Up to ``band_end[l]`` (voxels; band_end[0] unused, decreasing in l),
    and no further than its shortest ray, a block is traversed by that ray only; beyond,
    by its four sub-blocks. Where a shared block is narrower than a voxel, the union of
    voxels crossed differs from the exact one only at voxels the bundle grazes.
    ``band_end`` of length 1 traverses every ray from the camera. Concurrent rays write
    the same value, so the result does not depend on threads.
    """
    shape = (int(shape[0]), int(shape[1]), int(shape[2]))
    fx, fy, cx, cy = camera
    _mark_free_image(np.ascontiguousarray(origin, dtype=np.float64),
                     np.ascontiguousarray(R, dtype=np.float64), fx, fy, cx, cy, stride,
                     np.ascontiguousarray(lengths, dtype=np.float32),
                     np.ascontiguousarray(band_end, dtype=np.float64), shape, stamp,
                     occupied_code, free_code, max_ray_voxels(shape))
