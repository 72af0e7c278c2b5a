"""Natural surface texture: blotchy, multi-scale and non-repeating, as on painted, cast or
wooden surfaces. It gives the cameras the natural fiducials of sec. 2.4 (and stereo
something to match) without planted markers.

A texture declared in MJCF as ``builtin="flat"`` with ``mark="random"`` keeps its two
colours (``rgb1``, ``markrgb``); :func:`paint` replaces its pixels by fractal value noise
between them. Every texture gets its own pattern, fixed by its name, so the scene looks
the same on every run and two obstacles never share a pattern.
"""

from __future__ import annotations

import functools
import re
import zlib
from collections.abc import Iterator
from contextlib import contextmanager

import cv2
import mujoco
import numpy as np

SIZE = 512  # texels a side
OCTAVES = (8, 16, 32, 64, 128, 256, 512)  # noise cells a side, coarse to fine (512: grain)
PERSISTENCE = 0.9  # amplitude ratio from one octave to the next finer one


def noise(size: int, seed: int) -> np.ndarray:
    """Fractal value noise (size x size, float32 in [0, 1]) that tiles seamlessly."""
    rng = np.random.default_rng(seed)
    total = np.zeros((size, size), np.float32)
    amplitude = 1.0
    for cells in OCTAVES:
        coarse = rng.random((cells, cells), dtype=np.float32)
        wrapped = np.pad(coarse, 2, mode="wrap")  # periodic, so the texture tiles
        scale = size // cells  # sizes are powers of two
        big = cv2.resize(wrapped, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        offset = 2 * scale
        total += amplitude * big[offset:offset + size, offset:offset + size]
        amplitude *= PERSISTENCE
    total -= total.min()
    return total / max(float(total.max()), 1e-6)


@functools.lru_cache(maxsize=64)  # scenes of a sweep share names and colours: 768 KiB each
def _painted(name: str, base: tuple[float, ...], mark: tuple[float, ...]) -> np.ndarray:
    """The texture ``name`` in its colours (RGB uint8, read-only)."""
    level = noise(SIZE, zlib.crc32(name.encode()))
    # steepen the middle so that the noise reads as blotches, not as haze
    level = np.clip((level - 0.5) * 3.0 + 0.5, 0.0, 1.0)[..., None]
    rgb = (1 - level) * np.asarray(base) + level * np.asarray(mark)
    image = np.rint(255 * rgb).astype(np.uint8)
    image.flags.writeable = False
    return image


def paint(spec: mujoco.MjSpec) -> dict[str, np.ndarray]:
    """Fill every flat, randomly marked 2-D texture of ``spec`` with natural noise;
    returns the painted images (RGB uint8) by texture name."""
    painted = {}
    for tex in spec.textures:
        if (tex.type != mujoco.mjtTexture.mjTEXTURE_2D
                or tex.builtin != mujoco.mjtBuiltin.mjBUILTIN_FLAT
                or tex.mark != mujoco.mjtMark.mjMARK_RANDOM):
            continue
        image = _painted(tex.name, tuple(tex.rgb1), tuple(tex.markrgb))
        tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_NONE
        tex.width, tex.height, tex.nchannel = SIZE, SIZE, 3
        tex.data = image.tobytes()
        painted[tex.name] = image
    return painted


def file_name(texture: str) -> str:
    """Where a painted texture goes, relative to the exported MJCF."""
    return "textures/" + re.sub(r"[^A-Za-z0-9_.-]", "_", texture) + ".png"


@contextmanager
def as_files(spec: mujoco.MjSpec, painted: dict[str, np.ndarray]) -> Iterator[None]:
    """MJCF cannot hold pixel buffers: within this context the painted textures are
    plain builtins, so that ``spec.to_xml()`` works; :func:`link_files` then points the
    XML at image files."""
    saved = []
    for tex in spec.textures:
        if tex.name in painted:
            saved.append((tex, tex.data))
            tex.builtin, tex.width, tex.height = mujoco.mjtBuiltin.mjBUILTIN_FLAT, 8, 8
            tex.data = b""
    try:
        yield
    finally:
        for tex, data in saved:
            tex.builtin, tex.width, tex.height = mujoco.mjtBuiltin.mjBUILTIN_NONE, SIZE, SIZE
            tex.data = data


def link_files(xml: str, painted: dict[str, np.ndarray]) -> tuple[str, dict[str, bytes]]:
    """The XML with each painted texture read from a PNG file, and those files' bytes."""
    files = {}
    for name, image in painted.items():
        path = file_name(name)
        pattern = re.compile(r'<texture\b[^>]*\bname="' + re.escape(name) + r'"[^>]*/>')
        xml, n = pattern.subn(f'<texture name="{name}" type="2d" file="{path}"/>', xml)
        if n != 1:
            raise ValueError(f"texture {name!r} appears {n} times in the exported MJCF")
        ok, png = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError(f"could not encode texture {name!r} as PNG")
        files[path] = png.tobytes()
    return xml, files
