"""The commands that do not render work where no GL backend can start.

``taskcam --help``, ``taskcam report`` (it reads only the results database) and the
one-line error of a bad scenario or sweep file need neither mujoco nor a GL context.
The machine without GL is made honestly: the commands run in an environment whose
``MUJOCO_GL`` names no backend, so importing mujoco raises, and the GL resolver keeps the
value it finds (it never probes past it). A control shows that a command that renders
does fail there.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import run_taskcam

from taskcam.sim.config.scenario import SCENARIO_DIR
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments.results import Results

NO_GL = "none-such"


def no_gl_environment() -> dict[str, str]:
    """This process's environment, with a MUJOCO_GL that mujoco refuses at import."""
    return {**os.environ, "MUJOCO_GL": NO_GL, "PYOPENGL_PLATFORM": NO_GL}


def python(code: str) -> subprocess.CompletedProcess[str]:
    """``code`` in a fresh interpreter (this venv's python), without GL."""
    return subprocess.run([sys.executable, "-c", code], env=no_gl_environment(),
                          capture_output=True, text=True, timeout=300)


def test_mujoco_cannot_load_in_the_environment_without_gl():
    done = python("import mujoco")
    assert done.returncode != 0
    assert f"MUJOCO_GL: {NO_GL}" in done.stderr, done.stderr


def test_a_command_that_renders_fails_without_gl(tmp_path):
    """The control: without GL, ``taskcam run`` on a good scenario cannot start."""
    done = run_taskcam("run", "--no-record", "--out", str(tmp_path / "out"),
                       env=no_gl_environment())
    assert done.returncode == 1, done.stderr
    assert "MUJOCO_GL" in done.stderr
    assert not (tmp_path / "out" / "summary.json").exists()


@pytest.mark.parametrize("module", ["taskcam", "taskcam.sim", "taskcam.sim.config",
                                    "taskcam.sim.config.scenario", "taskcam.sim.config.sweep",
                                    "taskcam.sim.experiments.results",
                                    "taskcam.sim.experiments.report", "taskcam.sim.world.gl",
                                    "taskcam.sim.cli"])
def test_importing_what_does_not_render_loads_no_mujoco(module):
    done = python(f"import sys, {module}\n"
                  "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mujoco'))")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", f"importing {module} loaded {done.stdout.strip()}"


def test_help_works_without_gl():
    done = run_taskcam("--help", env=no_gl_environment())
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: taskcam"), done.stdout
    for command in ("run", "sweep", "report", "figure7"):
        assert command in done.stdout
    assert done.stderr == ""
    sub = run_taskcam("report", "--help", env=no_gl_environment())
    assert sub.returncode == 0 and "usage: taskcam report" in sub.stdout, sub.stderr


def trial_record(sweep_methods: list[dict[str, Any]], density_index: int, trial: int,
                 density: float, successes: dict[str, bool]) -> dict[str, Any]:
    """A trial's record as a sweep stores it (sim/experiments/trial.py), its outcomes
    given: ``successes`` per method name, at every tolerance of the task."""
    return {
        "density_index": density_index, "trial": trial, "seed": 1000 + trial,
        "density": density, "achieved_density": density, "obstacles": 3,
        # trial k blocks each band by the density plus k points (k = 0, 1): mean + 0.5
        "blocked_by_elevation": [density + trial / 100] * 8,
        "timings_s": {"total": 1.0},
        "methods": [{"method": m["name"], "placement": m["placement"],
                     "secondary": m["secondary"], "final_displacement_m": 0.002,
                     "steps": 3, "stopped_by": "converged",
                     "success": {"0.2": successes[m["name"]], "0.1": successes[m["name"]],
                                 "0.01": False}}
                    for m in sweep_methods],
    }


@pytest.fixture
def results_db(tmp_path: Path) -> Path:
    """A small results database of the smoke sweep (its real description), written
    through the Results API: two scenes at each density; "optimal" succeeds in both,
    "random" in one of two."""
    sweep = load_sweep(SCENARIO_DIR / "smoke.toml")
    description = sweep.describe()
    methods = description["sweep"]["methods"]
    db = tmp_path / "smoke.sqlite"
    with Results(db) as results:
        results.start(description, resume=False)
        for i, density in enumerate(sweep.config.densities):
            for k in range(2):
                results.add(trial_record(methods, i, k, density,
                                         {"optimal": True, "random": k == 0}))
    return db


def test_report_works_without_gl(results_db, tmp_path):
    out = tmp_path / "report"
    before = results_db.read_bytes()
    done = run_taskcam("report", str(results_db), "--out", str(out), env=no_gl_environment())
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    table = done.stdout
    assert "Optimal (rating function)" in table and "Biased random" in table, table
    assert "100 [" in table and "50 [" in table, table  # 2 of 2 and 1 of 2
    # each density's blocked share per elevation band, the mean of its two trials
    assert "| 10-20 deg | 20-30 deg |" in table
    for d in load_sweep(SCENARIO_DIR / "smoke.toml").config.densities:
        assert f"| {100 * d:g} % | {100 * d + 0.5:.1f} |" in table, table
    for name in ("smoke.md", "smoke.csv", "smoke.png", "smoke-orderings.md",
                 "smoke-orderings.csv"):
        assert (out / name).stat().st_size > 0
    # the table, then the paper's orderings tested on it
    assert table == (out / "smoke.md").read_text() + "\n" + (
        out / "smoke-orderings.md").read_text()
    assert results_db.read_bytes() == before  # read only


def one_line_error(done: subprocess.CompletedProcess[str], source: Path, key: str) -> None:
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"taskcam: error: {source}: key '{key}'"), done.stderr
    assert "accepted: " in lines[0]
    assert "MUJOCO_GL" not in done.stderr


def test_a_bad_scenario_file_is_one_line_without_gl(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[camera]\nfovy_deg = "wide"\n')
    done = run_taskcam("run", str(bad), "--out", str(tmp_path / "out"),
                       env=no_gl_environment())
    one_line_error(done, bad, "camera.fovy_deg")
    assert not (tmp_path / "out").exists()


def test_a_bad_sweep_file_is_one_line_without_gl(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((SCENARIO_DIR / "smoke.toml").read_text().replace("trials = 2",
                                                                       "trials = 0"))
    done = run_taskcam("sweep", str(bad), "--db", str(tmp_path / "r.sqlite"),
                       env=no_gl_environment())
    one_line_error(done, bad, "trials")
    assert not (tmp_path / "r.sqlite").exists()
