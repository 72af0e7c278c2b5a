"""Shared fixtures; the code paths pinned and the GL backend chosen before any test
module loads numpy or mujoco."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from taskcam.sim.determinism import is_pytest, pin, started_pinned
from taskcam.sim.world.gl import resolve_gl_backend

pin()  # processor-independent code paths here and in every process a test starts
resolve_gl_backend()  # the tests render: the GL backend before any test module loads mujoco


def pytest_configure(config: pytest.Config) -> None:
    """A session started without the pins starts again with them: glibc reads its part
    only when a process starts (sim/determinism.py)."""
    if is_pytest() and not started_pinned():
        capture = config.pluginmanager.getplugin("capturemanager")
        if capture is not None:
            capture.stop_global_capturing()  # the new session writes to the terminal
        pin(restart=True)

ROOT = Path(__file__).resolve().parent.parent
TASKCAM = Path(sys.executable).parent / "taskcam"


def run_taskcam(*args: str, cwd: Path | None = None,
                env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """The installed console script, as a user runs it (in ``env``: default, this
    process's environment)."""
    return subprocess.run([str(TASKCAM), *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=600)


@pytest.fixture(scope="session")
def default_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """``taskcam run`` on the default scenario, once per session: (run dir, summary); what
    it printed is beside the run directory (``stdout.txt``, ``stderr.txt``)."""
    out = tmp_path_factory.mktemp("default_run") / "run"
    done = run_taskcam("run", "--out", str(out))
    assert done.returncode == 0, done.stderr
    (out.parent / "stdout.txt").write_text(done.stdout)
    (out.parent / "stderr.txt").write_text(done.stderr)
    return out, json.loads((out / "summary.json").read_text())
