"""What the pins of sim/determinism.py put in effect, and a launcher.

``python -m taskcam.sim.pinned`` starts as the ``taskcam`` command does (pinned, starting again
if it was not) and prints, as JSON, each library's chosen code (:func:`settings`) and
digests of what each computes on fixed inputs (:func:`fingerprints`): the same digests
on two machines mean the same arithmetic. ``python -m taskcam.sim.pinned COMMAND ...`` runs
COMMAND with the pinned environment, e.g. ``python -m taskcam.sim.pinned dask worker
tcp://HOST:8786``.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from taskcam.sim.determinism import PINS, is_command, late_imports, pin, started_pinned
from taskcam.sim.world.gl import resolve_gl_backend

# Two hinged links over a floor, lit, seen by a camera: libm (MuJoCo's kinematics) and
# llvmpipe (its rasterising, lighting and depth) on a scene of a few triangles.
PENDULUM = """
<mujoco>
  <visual><global offwidth="64" offheight="48"/></visual>
  <worldbody>
    <light pos="0.3 -0.5 2" dir="0 0.3 -1"/>
    <geom type="plane" size="2 2 0.1" rgba="0.6 0.6 0.5 1"/>
    <camera name="eye" pos="0 -1.6 0.9" xyaxes="1 0 0 0 0.5 1"/>
    <body pos="0 0 1">
      <joint type="hinge" axis="0 1 0" damping="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.35 0 0" size="0.04" rgba="0.8 0.3 0.2 1"/>
      <body pos="0.35 0 0">
        <joint type="hinge" axis="0.3 1 0.2"/>
        <geom type="box" pos="0.15 0 0" size="0.15 0.05 0.03" rgba="0.2 0.5 0.8 1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _digest(*arrays: Any) -> str:
    """The first 12 hex digits of the sha256 of the arrays' bytes."""
    import numpy as np

    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:12]


def fingerprints() -> dict[str, str]:
    """Digests of each pinned library's results on fixed inputs (imports them all):
    ``libm`` glibc's maths functions through Python, ``numpy`` its vector loops,
    ``openblas`` products and solves, ``opencv`` a float Gaussian blur and a Laplacian,
    ``mujoco`` a pendulum's motion, ``llvmpipe`` its rendered colour and depth."""
    import cv2
    import mujoco
    import numpy as np
    import scipy.linalg

    rng = np.random.default_rng(17)
    x = rng.normal(0.0, 3.0, 4096)
    out = {"libm": _digest(np.array([f(v) for v in x for f in (
        math.exp, math.sin, math.cos, math.tan, lambda v: math.atan2(v, 0.7),
        lambda v: math.log(abs(v) + 1e-3), lambda v: abs(v) ** 1.37)]))}
    x32 = x.astype(np.float32)
    out["numpy"] = _digest(np.exp(x), np.log(np.abs(x) + 1e-3), np.abs(x) ** 1.37, np.tanh(x),
                           np.exp(x32), np.sin(x32), np.cos(x32), np.log(np.abs(x32) + 1e-3))
    A, B = rng.normal(size=(96, 96)), rng.normal(size=(96, 6))
    out["openblas"] = _digest(A @ A, A @ B, B.T @ B, np.linalg.solve(A, B),
                              scipy.linalg.lstsq(A[:, :6], x[:96])[0])
    image = rng.uniform(0.0, 255.0, (48, 64, 3)).astype(np.float32)
    out["opencv"] = _digest(cv2.GaussianBlur(image, (0, 0), 2.0),
                            cv2.Laplacian(cv2.GaussianBlur(image, (0, 0), 0.8), cv2.CV_32F))
    model = mujoco.MjModel.from_xml_string(PENDULUM)
    data = mujoco.MjData(model)
    data.qpos[:] = [0.4, -0.9]
    for _ in range(5000):  # 10 s: enough sin and cos calls for a few to differ
        mujoco.mj_step(model, data)
    out["mujoco"] = _digest(data.qpos, data.qvel, data.xquat)
    with mujoco.Renderer(model, 48, 64) as renderer:
        renderer.update_scene(data, "eye")
        rgb = renderer.render()
        renderer.enable_depth_rendering()
        renderer.update_scene(data, "eye")
        depth = renderer.render()
    out["llvmpipe"] = _digest(rgb, depth)
    return out


def _openblas() -> dict[str, str]:
    """Each loaded OpenBLAS library's kernel set ("core") and thread count."""
    found: dict[str, str] = {}
    try:
        maps = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return found
    for path in sorted({line.split()[-1] for line in maps if "openblas" in line.split()[-1]}):
        lib = ctypes.CDLL(path)
        for core in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                     "openblas_get_corename"):
            if hasattr(lib, core):
                get = getattr(lib, core)
                get.restype = ctypes.c_char_p
                threads = getattr(lib, core.replace("corename", "num_threads"))
                found[Path(path).name] = f"{get().decode()}, {threads()} thread(s)"
                break
    return found


def gl_renderer() -> str:
    """The GL_RENDERER string of a MuJoCo offscreen context, e.g. ``llvmpipe (LLVM
    15.0.6, 128 bits)``: llvmpipe's vector width (imports mujoco and PyOpenGL)."""
    import mujoco
    from OpenGL import GL

    context = mujoco.GLContext(8, 8)
    try:
        context.make_current()
        return GL.glGetString(GL.GL_RENDERER).decode()
    finally:
        context.free()


def settings() -> dict[str, Any]:
    """What is in effect in this process: the environment, and each library's chosen
    code as it reports it (imports them all)."""
    import cv2
    import numpy as np
    import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS)
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return {
        "started_pinned": started_pinned(),
        "environment": {k: os.environ.get(k) for k in PINS},
        "loaded_before_pinning": late_imports(),
        "gl_renderer": gl_renderer(),
        "opencv_cpu": cv2.getCPUFeaturesLine(),
        "opencv_ipp": cv2.ipp.getIppVersion() if cv2.ipp.useIPP() else "off",
        "numpy": np.__version__,
        "numpy_dispatch": [f for f in __cpu_dispatch__ if __cpu_features__.get(f)],
        "openblas": _openblas(),
    }


def main(argv: list[str]) -> int:
    pin(restart=is_command())  # started unpinned: again, pinned (glibc reads it at start)
    if argv:
        resolve_gl_backend()  # the program it starts (a Dask worker, say) renders
        os.execvp(argv[0], argv)
    print(json.dumps({"settings": settings(), "fingerprints": fingerprints()}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
