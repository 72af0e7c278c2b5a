"""The same record from the same seed on any x86-64 machine: pin the code paths that
libraries choose for the processor they find (docs/reproducibility.md).

Mesa's software rasteriser, OpenCV, numpy, the OpenBLAS libraries bundled with numpy,
scipy and OpenCV, and glibc's maths functions each pick, at run time, code for the
instruction sets the processor has (AVX2, FMA, AVX-512): the results differ in the last
bits (fused multiply-adds round once, not twice), and the task's step loop turns those
bits into millimetres. :func:`pin` sets the environment variables that make each of
them take the code every supported machine has (SSE4.1 to AVX, no FMA), :data:`PINS`.

Each variable is read once: glibc's when the process starts, the others when their
library loads. So :func:`pin` runs before numpy, cv2, scipy or mujoco are imported and
before the first GL context (``import sim`` calls it, beside the GL backend), and every
process started afterwards (sweep workers, a Dask ``LocalCluster``) inherits the
variables. The process itself gets glibc's part only by starting again: ``pin(restart=
True)`` re-executes it with the same arguments, as the ``taskcam`` command does.

``python -m taskcam.sim.pinned`` shows what is in effect; ``python -m taskcam.sim.pinned
COMMAND ...`` runs COMMAND pinned (a Dask worker, say). This module imports nothing that it pins.
"""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping
from itertools import pairwise
from pathlib import Path

HWCAPS = "glibc.cpu.hwcaps"
GLIBC_MASK = "-AVX2,-FMA,-FMA4"  # libm's SSE2 code: its FMA variants need AVX2 and FMA

# OpenCV's dispatch groups above AVX, each with the CPU flags (Linux's names) it needs
OPENCV_ABOVE_AVX = {"AVX2": ("avx2",), "FMA3": ("fma",),
                    "AVX512-SKX": ("avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl")}


def _opencv_disabled() -> str:
    """OpenCV's groups above AVX that this processor has. One it lacks is never taken,
    so leaving it out changes no code path; naming it makes OpenCV complain on stderr
    at import. All of them where the processor's flags cannot be read."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ",".join(OPENCV_ABOVE_AVX)
    flags = set(next((line.split(":", 1)[1].split() for line in text.splitlines()
                      if line.startswith("flags")), []))
    if not flags:
        return ",".join(OPENCV_ABOVE_AVX)
    return ",".join(g for g, need in OPENCV_ABOVE_AVX.items() if flags.issuperset(need))


PINS: dict[str, str] = {
    # Mesa llvmpipe: SSE4.1, 128-bit vectors, no AVX, FMA or AVX2 in its compiled shaders
    "GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1",
    # OpenCV: its AVX code at most (compiled without FMA), and Intel IPP's SSE4.2 kernels
    # (IPP dispatches on its own, to AVX2 and AVX-512)
    "OPENCV_CPU_DISABLE": _opencv_disabled(),
    "OPENCV_IPP": "sse42",
    # numpy: its baseline loops (x86-64-v2), not the AVX2 / AVX-512 ones
    "NPY_ENABLE_CPU_FEATURES": "X86_V2",
    # OpenBLAS (numpy's, scipy's, OpenCV's): the AVX kernels without FMA, one thread
    # (how a product is split among threads changes its rounding)
    "OPENBLAS_CORETYPE": "Sandybridge",
    "OPENBLAS_NUM_THREADS": "1",
    # glibc's exp, log, pow, sin, cos, tan, atan2 (MuJoCo, numpy, Python): the SSE2 code
    "GLIBC_TUNABLES": f"{HWCAPS}={GLIBC_MASK}",
}
LOADED_TOO_SOON = ("numpy", "cv2", "scipy", "mujoco", "OpenGL")
ENTRY_MODULES = ("taskcam.sim.cli", "taskcam.sim.pinned")  # ``python -m`` forms of the command
RESTARTED = "TASKCAM_PIN_RESTARTED"  # marks a process started again (never twice)
_started_again = os.environ.pop(RESTARTED, None) is not None  # not passed on to children
_loaded_first: set[str] = set()


def _tunables(current: str | None) -> str:
    """GLIBC_TUNABLES with the hardware-capability mask, other tunables kept."""
    kept = [t for t in (current or "").split(":") if t and not t.startswith(HWCAPS + "=")]
    return ":".join([*kept, PINS["GLIBC_TUNABLES"]])


def pinned_environment(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """The variables :func:`pin` sets, given the environment ``environ`` (default: this
    process's): :data:`PINS`, GLIBC_TUNABLES merged with tunables already there."""
    env = os.environ if environ is None else environ
    return {**PINS, "GLIBC_TUNABLES": _tunables(env.get("GLIBC_TUNABLES"))}


def _started_with(name: str, value: str) -> bool:
    """Whether this process was started with ``name=value`` in its environment (Linux;
    elsewhere, whether it is in the environment now)."""
    try:
        start = Path("/proc/self/environ").read_bytes().split(b"\0")
    except OSError:
        return os.environ.get(name) == value
    return f"{name}={value}".encode() in start


def started_pinned() -> bool:
    """Whether this process started with every pinned variable (glibc's part included)."""
    return all(_started_with(k, v) for k, v in pinned_environment().items())


def _running(scripts: tuple[str, ...], modules: tuple[str, ...]) -> bool:
    """Whether this process's program is one of ``scripts`` (console scripts, by name)
    or ``python -m`` one of ``modules``."""
    if sys.argv and Path(sys.argv[0]).name in scripts:
        return True
    argv = list(getattr(sys, "orig_argv", sys.argv))
    return any(a == "-m" and b in modules for a, b in pairwise(argv))


def is_command() -> bool:
    """Whether this process is the ``taskcam`` command (its console script, or ``python
    -m taskcam.sim.cli`` / ``-m taskcam.sim.pinned``), not a program that imports taskcam."""
    return _running(("taskcam",), ENTRY_MODULES)


def is_pytest() -> bool:
    """Whether this process is a pytest session started from the command line."""
    return _running(("pytest", "py.test"), ("pytest",))


def pin(restart: bool = False, environ: MutableMapping[str, str] | None = None) -> list[str]:
    """Set the pinned variables in ``environ`` (default: this process's environment,
    inherited by every process started afterwards); the names that changed.

    With ``restart``, a process that did not start pinned executes itself again, with the
    same interpreter and arguments, so that glibc reads its part (call it before anything
    is printed or any file opened)."""
    env = os.environ if environ is None else environ
    changed = []
    for name, value in pinned_environment(env).items():
        if env.get(name) != value:
            env[name] = value
            changed.append(name)
    if changed and environ is None:
        _loaded_first.update(m for m in LOADED_TOO_SOON if m in sys.modules)
    if restart and environ is None and not started_pinned() and not _started_again:
        sys.stdout.flush()
        sys.stderr.flush()
        argv = list(getattr(sys, "orig_argv", [sys.executable, *sys.argv]))
        os.execve(sys.executable, [sys.executable, *argv[1:]], {**env, RESTARTED: "1"})
    return changed


def late_imports() -> list[str]:
    """Libraries this process loaded before :func:`pin` changed its environment: they
    keep the code they chose then (empty when pinned first)."""
    return sorted(_loaded_first)
