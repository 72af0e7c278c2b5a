"""Results that do not depend on the machine (docs/reproducibility.md).

The processor-dependent code paths (Mesa llvmpipe, OpenCV and Intel IPP, numpy, OpenBLAS,
glibc's maths functions) are pinned in every process a run or a sweep starts: the
``taskcam`` command (which starts again, pinned, when it was not), local sweep workers,
Dask workers. Held to stored values exactly (tests/reproducibility.json), the same on
every x86-64 machine with the same software: each library's results on fixed inputs
(sim/pinned.py's fingerprints; they change only with the libraries) and a reduced
sweep's task outcomes, run by the command (they change whenever the code changes what
an episode does). Regenerate both, and say why in the commit, with

    .venv/bin/python tests/test_reproducibility.py --regenerate
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.determinism import PINS, late_imports, started_pinned
from taskcam.sim.experiments.runner import pinned_here, run_sweep, worker_pool
from taskcam.sim.pinned import fingerprints, settings

STORED = Path(__file__).with_name("reproducibility.json")
TASKCAM = Path(sys.executable).parent / "taskcam"
# Two paired scenes (5 % and 20 % occlusion), both placements, small images, a short task
# that runs: the bases drive to their views (standing still, no camera located a target
# and no task ever ran, so the edge fits and the stop went unchecked).
SWEEP = """\
name = "reproducibility"
scenario = "default.toml"
seed = 3
trials = 1
densities = [0.05, 0.20]

[[methods]]
name = "optimal"
placement = "rating"

[[methods]]
name = "random"
placement = "biased_random"

[overrides.camera]
width = 320
height = 240
samples = 0

[overrides.mapping]
max_views = 4

[overrides.workpiece]
position_error_m = 0.01
yaw_error_deg = 2.0

[overrides.search]
check_sight = false
ik_candidates = 6
camera_z_m = [0.4, 1.3]

[overrides.motion]
joint_offset_deg = 0.0
joint_noise_deg = 0.0
base_offset_m = 0.0
base_yaw_deg = 0.0
suspension_deg = 0.0
settle_s = 0.2

[overrides.correction]
enabled = false

[overrides.task]
gain = 1.0
max_step_m = 0.2
max_steps = 4
"""
OUTCOME_KEYS = ("success", "final_displacement_m", "steps", "measurements",
                "failed_measurements", "stopped_by", "targets_measured")


def unpinned_environment() -> dict[str, str]:
    """This process's environment without the pinned variables, as a user's shell has it."""
    return {k: v for k, v in os.environ.items() if k not in PINS}


def outcomes(workdir: Path) -> dict[str, Any]:
    """The reduced sweep run by the ``taskcam`` command from an unpinned environment: per
    trial its scene and map, per method its task outcome and camera positions (m)."""
    spec, db = workdir / "reproducibility.toml", workdir / "reproducibility.sqlite"
    spec.write_text(SWEEP)
    done = subprocess.run([str(TASKCAM), "sweep", str(spec), "--db", str(db)],
                          env=unpinned_environment(), capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr
    with sqlite3.connect(db) as connection:
        records = [json.loads(r) for (r,) in connection.execute(
            "SELECT record FROM trials ORDER BY density_index, trial")]
    return {f"density {r['density_index']} trial {r['trial']}": {
        "seed": r["seed"], "achieved_density": r["achieved_density"], "mapping": r["mapping"],
        "methods": {m["method"]: {**{k: m.get(k) for k in OUTCOME_KEYS},
                                  "positions": [p["position"] for p in m["robots"]]}
                    for m in r["methods"]}} for r in records}


def command_report() -> dict[str, Any]:
    """``python -m taskcam.sim.pinned`` (it starts as the ``taskcam`` command does: sim first)
    from an environment without the pins: its settings and fingerprints."""
    done = subprocess.run([sys.executable, "-m", "taskcam.sim.pinned"], env=unpinned_environment(),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout))


def stored(part: str) -> Any:
    return json.loads(STORED.read_text())[part]


REGENERATE = "python tests/test_reproducibility.py --regenerate"


@pytest.mark.slow
def test_a_sweeps_task_outcomes_equal_the_stored_ones(tmp_path):
    stored_outcomes = stored("outcomes")
    got = outcomes(tmp_path)
    differ = {k: {"stored": stored_outcomes.get(k), "now": v} for k, v in got.items()
              if stored_outcomes.get(k) != v}
    assert any(m["steps"] > 0 for t in got.values() for m in t["methods"].values()), (
        "no task ran in the reduced sweep: it checks mapping and placement alone")
    assert not differ and got.keys() == stored_outcomes.keys(), (
        "task outcomes differ from tests/reproducibility.json: the code changed what an "
        f"episode does (then: {REGENERATE}), or, if test_each_library_computes_the_stored_"
        "fingerprints fails too, a library's arithmetic differs on this machine: "
        f"{json.dumps(differ)[:3000]}")


def assert_pinned(s: dict[str, Any]) -> None:
    """Each library runs the pinned code: llvmpipe 128-bit, OpenCV without AVX2 or
    AVX-512 and IPP's SSE4.2 kernels, numpy's baseline loops, OpenBLAS's Sandybridge
    kernels on one thread, and the process started with glibc's part."""
    assert s["started_pinned"] and s["loaded_before_pinning"] == [], s
    assert s["gl_renderer"].startswith("llvmpipe") and "128 bits" in s["gl_renderer"], s
    assert "*AVX2?" in s["opencv_cpu"] and "*AVX512-SKX?" in s["opencv_cpu"], s
    assert "SSE4.2 (y8)" in s["opencv_ipp"], s
    assert s["numpy_dispatch"] == [], s
    assert len(s["openblas"]) >= 2, s  # numpy's and scipy's at least
    assert set(s["openblas"].values()) == {"Sandybridge, 1 thread(s)"}, s


@pytest.fixture(scope="module")
def report() -> dict[str, Any]:
    return command_report()


def test_the_command_pins_itself_when_started_unpinned(report):
    assert_pinned(report["settings"])


def test_each_library_computes_the_stored_fingerprints(report):
    """Each differs from the stored one when its library runs other code (measured on an
    AVX-512 machine by dropping each pin: docs/reproducibility.md)."""
    assert report["fingerprints"] == stored("fingerprints"), (
        "these libraries compute differently here: docs/reproducibility.md says what each "
        f"depends on (regenerate only after a library upgrade: {REGENERATE})")


def test_this_test_session_is_pinned():
    """pytest starts again, pinned, from tests/conftest.py when it was not."""
    assert started_pinned() and late_imports() == []
    assert_pinned(settings())


@pytest.mark.slow
def test_sweep_workers_are_pinned():
    for workers in (1, 2):
        with worker_pool(workers) as pool:
            assert_pinned(pool.submit(settings).result())
            assert pool.submit(fingerprints).result() == stored("fingerprints")


def test_a_program_that_loads_numpy_first_is_not_trusted_with_trials():
    """numpy read its CPU features before sim could pin them: its sweeps run in workers."""
    probe = ("import json, numpy, taskcam.sim.experiments.runner as r, "
             "taskcam.sim.determinism as d; "
             "print(json.dumps([r.pinned_here(), d.late_imports()]))")
    done = subprocess.run([sys.executable, "-c", probe], env=unpinned_environment(),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == [False, ["numpy"]]


@pytest.mark.parametrize("pinned", [True, False])
@pytest.mark.slow
def test_dask_workers_must_start_pinned(tmp_path, pinned):
    from distributed import LocalCluster

    spec = tmp_path / "reproducibility.toml"
    spec.write_text(SWEEP)
    sweep = load_sweep(spec)
    saved = dict(os.environ)
    if not pinned:  # workers started from a shell without the pins
        for name in PINS:
            os.environ.pop(name)
    try:
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    with cluster:
        from distributed import Client

        with Client(cluster.scheduler_address) as client:
            assert set(client.run(pinned_here).values()) == {pinned}
        if not pinned:
            with pytest.raises(RuntimeError, match=r"python -m taskcam\.sim\.pinned dask worker"):
                run_sweep(sweep, tmp_path / "r.sqlite", scheduler=cluster.scheduler_address,
                          progress=False)


if __name__ == "__main__":
    import tempfile

    if sys.argv[1:] != ["--regenerate"]:
        sys.exit(f"usage: {sys.argv[0]} --regenerate  (rewrites {STORED.name})")
    with tempfile.TemporaryDirectory() as tmp:
        values = {"fingerprints": command_report()["fingerprints"], "outcomes": outcomes(Path(tmp))}
    STORED.write_text(json.dumps(values, indent=1) + "\n")
    print(f"wrote {STORED}")
