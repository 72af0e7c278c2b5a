"""Choose MuJoCo's offscreen GL backend before the first ``import mujoco``.

MuJoCo reads ``MUJOCO_GL`` once, when it is imported. On a machine without a display
we want EGL (Mesa's software renderer works through it) and, failing that, OSMesa.
This module must not import mujoco.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import subprocess
import sys

BACKENDS = ("egl", "osmesa")
_LIBRARIES = {"egl": ("EGL", "libEGL.so.1"), "osmesa": ("OSMesa", "libOSMesa.so.8")}


class GLError(RuntimeError):
    """No usable offscreen GL backend."""


def _loadable(backend: str) -> bool:
    short, soname = _LIBRARIES[backend]
    for name in (ctypes.util.find_library(short), soname):
        if not name:
            continue
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return True
    return False


def _context_works(backend: str) -> bool:
    """Create and free a 1x1 MuJoCo GL context in a child process (about 0.5 s)."""
    env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
    probe = "import mujoco; c = mujoco.GLContext(1, 1); c.make_current(); c.free()"
    try:
        done = subprocess.run(
            [sys.executable, "-c", probe], env=env, capture_output=True, timeout=60
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


def resolve_gl_backend(environ: dict[str, str] | None = None) -> str:
    """Set ``MUJOCO_GL`` to a working backend and return it.

    An existing ``MUJOCO_GL`` is respected. Otherwise EGL is chosen when its library
    loads and a context can be made with it, then OSMesa. Raises GLError naming what to install.
    """
    env = os.environ if environ is None else environ
    chosen = env.get("MUJOCO_GL")
    if chosen:
        return chosen
    if environ is None and "mujoco" in sys.modules:
        raise GLError("mujoco was imported before the GL backend was chosen; import sim first")
    for backend in BACKENDS:
        if _loadable(backend) and _context_works(backend):
            env["MUJOCO_GL"] = backend
            env.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    raise GLError(
        "no offscreen GL backend: install EGL (apt-get install libegl1 libgl1-mesa-dri) "
        "or OSMesa (apt-get install libosmesa6)"
    )


def require_gl_backend() -> str:
    """The GL backend mujoco was loaded with; GLError if none was chosen before it loaded
    (a program that renders calls :func:`resolve_gl_backend` first)."""
    chosen = os.environ.get("MUJOCO_GL")
    if not chosen:
        raise GLError("no GL backend was chosen before mujoco loaded: call "
                      "taskcam.sim.world.gl.resolve_gl_backend() before importing what renders")
    return chosen
