"""Sweeps: resumable after kill -9, the same rows whatever runs them, clear errors for bad
sweep files, trials that pair their methods, and reports that count right."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taskcam.sim.cli import main
from taskcam.sim.config.scenario import SCENARIO_DIR
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments.report import cells, markdown, wilson
from taskcam.sim.experiments.report_files import write_report
from taskcam.sim.experiments.results import Results
from taskcam.sim.experiments.runner import run_on_pool, run_sweep, trial_specs
from taskcam.sim.experiments.trial import CRASH_TRIAL_ENV, run_trial

TINY = (SCENARIO_DIR / "smoke.toml").read_text()
TABLES = ("trials", "outcomes", "successes")


def rows(db: Path) -> dict[str, list[tuple]]:
    with Results(db) as r:
        return {t: r.rows(t) for t in TABLES}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sweep") / "tiny.toml"
    path.write_text(TINY)
    return path


@pytest.fixture(scope="module")
def reference(tiny) -> dict[str, list[tuple]]:
    """The tiny sweep run straight through in this process, one trial after another."""
    db = tiny.parent / "reference.sqlite"
    done = run_sweep(load_sweep(tiny), db, workers=1, progress=False)
    assert (done.total, done.already, done.ran) == (4, 0, 4)
    return rows(db)


@pytest.mark.slow
def test_the_reference_rows_are_complete(reference):
    assert [(r[0], r[1]) for r in reference["trials"]] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert len(reference["outcomes"]) == 4 * 2
    assert len(reference["successes"]) == 4 * 2 * 3
    for _, _, _, density, achieved, obstacles, _ in reference["trials"]:
        assert abs(achieved - density) <= 0.03  # the generated density, as recorded
        assert obstacles >= 1


@pytest.mark.slow
def test_kill_9_then_resume_gives_the_rows_of_an_uninterrupted_run(tiny, reference, tmp_path):
    db = tmp_path / "killed.sqlite"
    cmd = [sys.executable, "-m", "taskcam.sim.cli", "sweep", str(tiny), "--db", str(db),
           "--workers", "2"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 600
        stored = 0
        while stored < 1 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            stored = _stored(db)
        assert proc.poll() is None, "the sweep ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its workers, mid-trial
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    with Results(db) as r:
        before = r.done()
    assert 1 <= len(before) < 4
    assert main(["sweep", str(tiny), "--db", str(db)]) == 2  # not without --resume
    done = run_sweep(load_sweep(tiny), db, workers=1, resume=True, progress=False)
    assert done.already == len(before) and done.ran == 4 - len(before)
    assert rows(db) == reference


def _stored(db: Path) -> int:
    """Trials stored in the sweep database ``db`` so far (0 before it has its tables)."""
    if not db.exists():
        return 0
    with sqlite3.connect(db) as c:
        try:
            return int(c.execute("SELECT COUNT(*) FROM trials").fetchone()[0])
        except sqlite3.OperationalError:
            return 0


def _workers(pid: int) -> list[int]:
    """The pool's worker processes among the children of process ``pid``."""
    children = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        children += [int(c) for c in (task / "children").read_text().split()]
    return [c for c in children
            if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]


@pytest.mark.slow
def test_a_worker_that_dies_is_replaced_and_its_trials_run_again(tiny, reference, tmp_path):
    """SIGKILL on one worker mid-sweep (as glibc's abort on heap corruption ends one):
    the sweep carries on, on a fresh pool, and stores every trial, as an uninterrupted
    run does."""
    db = tmp_path / "died.sqlite"
    cmd = [sys.executable, "-m", "taskcam.sim.cli", "sweep", str(tiny), "--db", str(db),
           "--workers", "2"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 600
        while _stored(db) < 1 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert proc.poll() is None, "the sweep ended before a worker could be killed"
        workers = _workers(proc.pid)
        assert len(workers) == 2
        os.kill(workers[0], signal.SIGKILL)
        _, stderr = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "a worker process died" in stderr
    assert rows(db) == reference


@pytest.mark.slow
@pytest.mark.parametrize("workers", [2, 1])
def test_a_trial_that_always_crashes_is_stored_as_failed_and_the_sweep_goes_on(
        tiny, reference, tmp_path, monkeypatch, capsys, workers):
    """One trial's process dies by SIGSEGV every time (the test hook in the trial): it is
    stored as failed with the reason, every other row is the uninterrupted sweep's, the
    final line counts it, the exit status is 1 and the report lists it; a resume without
    the crash runs it again and leaves the rows of an uninterrupted sweep."""
    db = tmp_path / "crash.sqlite"
    monkeypatch.setenv(CRASH_TRIAL_ENV, "1,0")
    add = Results.add

    def slow_add(results: Results, record: dict) -> None:  # the crash comes while a record
        add(results, record)                               # is stored, before the next
        time.sleep(2.0)                                    # trial is handed to the pool

    monkeypatch.setattr(Results, "add", slow_add)
    assert main(["sweep", str(tiny), "--db", str(db), "--workers", str(workers)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert "a worker process died" in "\n".join(err)
    assert "2 trial(s) run" not in err[-1] and "0 found done, 1 failed; 3 of 4" in err[-1]
    seed = next(r[2] for r in reference["trials"] if r[:2] == (1, 0))
    with Results(db) as r:
        assert r.failures() == [(1, 0, seed, 0.2, 3, "worker died with SIGSEGV, 3 times")]
    assert rows(db) == {t: [r for r in reference[t] if r[:2] != (1, 0)] for t in TABLES}
    assert main(["report", str(db), "--out", str(tmp_path / "out")]) == 0
    assert (f"- trial 0 at 20 % (density index 1, seed {seed}): worker died with SIGSEGV, "
            "3 times") in capsys.readouterr().out
    monkeypatch.delenv(CRASH_TRIAL_ENV)
    assert main(["sweep", str(tiny), "--db", str(db), "--workers", str(workers),
                 "--resume"]) == 0
    assert "1 trial(s) run" in capsys.readouterr().err.strip().splitlines()[-1]
    assert rows(db) == reference
    with Results(db) as r:
        assert r.failures() == []


@pytest.mark.slow
def test_a_trial_that_kills_its_dask_workers_is_stored_as_failed(tiny, reference, tmp_path,
                                                                  monkeypatch, capsys):
    """On Dask, the task whose worker died runs again on another (Dask's own retries);
    one that kills every worker it runs on is stored as failed and the sweep goes on."""
    from distributed import LocalCluster

    db = tmp_path / "dask_crash.sqlite"
    monkeypatch.setenv(CRASH_TRIAL_ENV, "0,1")  # the workers inherit it
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        assert main(["sweep", str(tiny), "--db", str(db), "--scheduler",
                     cluster.scheduler_address]) == 1
    assert "1 failed; 3 of 4" in capsys.readouterr().err.strip().splitlines()[-1]
    with Results(db) as r:
        [(d, trial, _, _, runs, reason)] = r.failures()
    assert (d, trial, runs) == (0, 1, 4) and reason.startswith("Dask workers died running it")
    assert rows(db) == {t: [r for r in reference[t] if r[:2] != (0, 1)] for t in TABLES}


def test_a_failed_trial_is_stored_apart_and_leaves_when_the_trial_is(tmp_path):
    """A failure is stored per trial (a second replaces the first), is not done, and
    leaves when the trial's record is stored; a database without the table has none."""
    sweep = load_sweep(SCENARIO_DIR / "smoke.toml")
    record = {"density_index": 0, "trial": 1, "seed": 5, "density": 0.05,
              "achieved_density": 0.05, "obstacles": 2, "timings_s": {"total": 1.0},
              "methods": []}
    with Results(tmp_path / "r.sqlite") as r:
        r.db.execute("DROP TABLE IF EXISTS failed")
        assert r.failures() == []
        r.start(sweep.describe(), resume=False)
        r.add_failure(0, 1, 5, 0.05, 3, "worker died with SIGSEGV, 3 times")
        r.add_failure(0, 1, 5, 0.05, 3, "worker died with SIGABRT, 3 times")
        assert r.failures() == [(0, 1, 5, 0.05, 3, "worker died with SIGABRT, 3 times")]
        assert r.done() == set()
        r.add(record)
        assert r.failures() == [] and r.done() == {(0, 1)}


@pytest.mark.slow
def test_two_workers_give_the_same_rows(tiny, reference, tmp_path):
    db = tmp_path / "two.sqlite"
    assert main(["sweep", str(tiny), "--db", str(db), "--workers", "2"]) == 0
    assert rows(db) == reference


@pytest.mark.slow
def test_a_dask_cluster_gives_the_same_rows(tiny, reference, tmp_path):
    from distributed import LocalCluster

    db = tmp_path / "dask.sqlite"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        assert main(["sweep", str(tiny), "--db", str(db), "--scheduler",
                     cluster.scheduler_address]) == 0
    assert rows(db) == reference


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
def test_a_real_dask_cluster_loses_no_trial_when_a_worker_dies(tiny, reference, tmp_path):
    """A `dask scheduler` and two workers started as the docs say (`python -m taskcam.sim.pinned
    dask worker ADDRESS`), each its own command; one worker (its nanny and process) is
    killed mid-sweep, as a machine lost: the other runs what it held, and the rows are
    an uninterrupted sweep's."""
    from distributed import Client

    dask = str(Path(sys.executable).parent / "dask")
    address = f"tcp://127.0.0.1:{_free_port()}"
    db = tmp_path / "cluster.sqlite"
    started = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                                 address.rsplit(":", 1)[1], "--no-dashboard"],
                                start_new_session=True, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)]
    try:
        started += [subprocess.Popen([sys.executable, "-m", "taskcam.sim.pinned", dask, "worker",
                                      address, "--nthreads", "1", "--no-dashboard"],
                                     start_new_session=True, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL) for _ in range(2)]
        sweep = subprocess.Popen([sys.executable, "-m", "taskcam.sim.cli", "sweep", str(tiny),
                                  "--db", str(db), "--scheduler", address],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=180)
            deadline = time.monotonic() + 600
            while _stored(db) < 1 and time.monotonic() < deadline and sweep.poll() is None:
                time.sleep(0.2)
            assert sweep.poll() is None, "the sweep ended before a worker could be killed"
            pids = client.run(os.getpid)
            busy = [pids[w] for w, keys in client.processing().items() if keys]
            assert busy, "no worker was running a trial"
        os.killpg(os.getpgid(busy[0]), signal.SIGKILL)  # its nanny and it, mid-trial
        _, stderr = sweep.communicate(timeout=900)
        assert sweep.returncode == 0, stderr
    finally:
        for process in started:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert rows(db) == reference


@pytest.mark.slow
def test_a_trial_pairs_its_methods_whatever_their_order(tiny):
    """Each method starts from the same mapped scene with its own random stream: run
    alone, or after another, it does the same."""
    sweep = load_sweep(tiny)
    spec = trial_specs(sweep)[0]
    both = run_trial(spec)
    alone = run_trial(dataclasses.replace(spec, methods=spec.methods[1:]))

    def strip(m):
        return {k: v for k, v in m.items() if k != "time_s"}

    assert strip(alone["methods"][0]) == strip(both["methods"][1])
    assert alone["achieved_density"] == both["achieved_density"]


def test_a_trial_that_fails_is_named_even_from_a_worker(tiny):
    """A scene the generator cannot make (0.95 occlusion) fails its trial; the error
    names the trial, its density and seed, in this process and from a worker's."""
    spec = dataclasses.replace(trial_specs(load_sweep(tiny))[1], density=0.95)
    named = f"in trial {spec.trial} at density 0.95 (density index {spec.density_index}, " \
            f"seed {spec.seed})"
    with pytest.raises(ValueError, match="not in") as here:
        run_trial(spec)
    assert named in here.value.__notes__[0]
    with pytest.raises(ValueError, match="not in") as there:
        list(run_on_pool([spec], 2))
    assert named in there.value.__notes__[0]


@pytest.mark.parametrize(("edit", "key"), [
    ('densities = [0.05, 0.2]', "densities"),
    ('placement = "rating"', "methods[0].placement"),
    ('width = 320', "camera.width"),
    ('seed = 7', "speed"),
])
def test_a_bad_sweep_file_exits_2_naming_the_key(tiny, tmp_path, capsys, edit, key):
    bad_values = {"densities": 'densities = [0.05, 1.5]',
                  "methods[0].placement": 'placement = "psychic"',
                  "camera.width": 'width = "wide"', "speed": 'seed = 7\nspeed = 3'}
    path = tmp_path / "bad.toml"
    path.write_text(TINY.replace(edit, bad_values[key], 1))
    db = tmp_path / "bad.sqlite"
    assert main(["sweep", str(path), "--db", str(db)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'{key}'" in err[0] and str(path) in err[0]
    assert "Traceback" not in err[0]
    assert not db.exists()  # nothing started, nothing written


@pytest.mark.slow
def test_a_database_of_another_sweep_is_refused(tiny, reference, tmp_path, capsys):
    db = tmp_path / "other.sqlite"
    with Results(db) as r:
        r.start({"sweep": {"seed": 99}}, resume=False)
    assert main(["sweep", str(tiny), "--db", str(db), "--resume"]) == 2
    assert "different sweep" in capsys.readouterr().err


def test_a_database_of_scenes_another_generator_made_is_not_resumed(tmp_path):
    """The same sweep, its trials made by an older scene generator (its
    description without ``scenes``): refused, since the same seeds now make other
    scenes; with today's generator named, taken."""
    sweep = load_sweep(SCENARIO_DIR / "smoke.toml")
    old = {k: v for k, v in sweep.describe().items() if k != "scenes"}
    with Results(tmp_path / "old.sqlite") as r:
        r.start(old, resume=False)
        refused = r.refusal(sweep.describe(), resume=True)
        assert refused is not None and "different sweep" in str(refused)
    with Results(tmp_path / "new.sqlite") as r:
        r.start(sweep.describe(), resume=False)
        assert r.refusal(sweep.describe(), resume=True) is None


def test_wilson_interval_matches_hand_calculation():
    # 5 of 10 at z = 1.96: centre 0.5, half-width 1.96/(1+0.38416) * sqrt(0.025 + 0.0096040)
    lo, hi = wilson(5, 10)
    half = 1.959963984540054 / (1 + 1.959963984540054 ** 2 / 10) * math.sqrt(
        0.25 / 10 + 1.959963984540054 ** 2 / 400)
    assert lo == pytest.approx(0.5 - half) and hi == pytest.approx(0.5 + half)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    assert wilson(0, 2)[0] == 0.0 and wilson(0, 2)[1] == pytest.approx(0.6576, abs=1e-4)
    assert wilson(3, 3)[1] == 1.0
    for n in range(1, 60):  # the interval holds its estimate, rounding included
        for k in range(n + 1):
            lo, hi = wilson(k, n)
            assert 0.0 <= lo <= k / n <= hi <= 1.0


@pytest.mark.slow
def _median_p90(values: list[float], form: str) -> str:
    """Sorted ``values``' median / 90th percentile (linear between ranks), or "-"."""
    if not values:
        return "-"
    median = (values[(len(values) - 1) // 2] + values[len(values) // 2]) / 2
    at = 0.9 * (len(values) - 1)
    above = values[min(int(at) + 1, len(values) - 1)]
    p90 = values[int(at)] + (at - int(at)) * (above - values[int(at)])
    return f"{form.format(median)} / {form.format(p90)}"


def test_the_report_matches_a_hand_count(tiny, reference, tmp_path):
    db = tmp_path / "report.sqlite"
    shutil.copy(tiny.parent / "reference.sqlite", db)
    near_m = load_sweep(tiny).scenario.camera.near_m  # the density is held from there
    # count from the stored trial records, not from the tables the report reads
    count: dict[tuple[str, float, float], list[int]] = {}
    with sqlite3.connect(db) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            for m in json.loads(record)["methods"]:
                for tol, ok in m["success"].items():
                    n = count.setdefault((m["method"], density, float(tol)), [0, 0])
                    n[0] += 1
                    n[1] += bool(ok)
    table = cells(db)
    assert {(c.method, c.density, c.tolerance): [c.trials, c.successes] for c in table} == count
    out = write_report(db, tmp_path / "out")
    text = out["markdown"]
    # the table, then each density's blocked share per elevation band, by hand
    bands: dict[float, list[list[float]]] = {}
    with sqlite3.connect(db) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            bands.setdefault(density, []).append(json.loads(record)["blocked_by_elevation"])
    assert text.startswith(markdown(table) + "\n")
    for density, rows in bands.items():
        means = [sum(column) / len(rows) for column in zip(*rows, strict=True)]
        assert ("| " + " | ".join([f"{100 * density:g} %"] + [f"{100 * v:.1f}" for v in means])
                + " |") in text
    # the tasks that ended at the step limit, by hand
    limit: dict[tuple[str, float], list[int]] = {}
    with sqlite3.connect(db) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            for m in json.loads(record)["methods"]:
                if m["steps"] > 0:
                    n = limit.setdefault((m["method"], density), [0, 0])
                    n[0] += m["stopped_by"] == "max_steps"
                    n[1] += 1
    line = next(x for x in text.splitlines() if x.startswith("Tasks that ended at the step"))
    assert line.endswith(": " + "; ".join(
        f"{method} " + ", ".join(f"{at} of {n} at {100 * d:g} %"
                                 for (other, d), (at, n) in sorted(limit.items())
                                 if other == method)
        for method in sorted({m for m, _ in limit})))
    # what each method's cameras did, by hand from the same records
    by_cell: dict[tuple[str, float], list[dict]] = {}
    with sqlite3.connect(db) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            for m in json.loads(record)["methods"]:
                by_cell.setdefault((m["method"], density), []).append(m)
    for (method, density), runs in by_cell.items():
        n = len(runs)
        placed = sum(r["placed"] for m in runs for r in m["robots"]) / n
        saw = sum(r["placed"] and r["seen"] for m in runs for r in m["robots"]) / n
        blind = sum(not any(r["placed"] and r["seen"] for r in m["robots"]) for m in runs)
        moved = sum(m["replacements"] or 0 for m in runs) / n
        finals = sorted(1e3 * m["final_displacement_m"] for m in runs if m["attempted"])
        steps = sorted(m["steps"] for m in runs if m["attempted"])
        final = _median_p90(finals, "{:.2f}")
        faced = sorted(r["faced_density"] for m in runs for r in m["robots"] if r["placed"])
        middle = (faced[(len(faced) - 1) // 2] + faced[len(faced) // 2]) / 2 if faced else None
        nearer = sum(r["slot_distance_m"] < near_m for m in runs for r in m["robots"]
                     if r["placed"])
        assert (f"| {method} | {100 * density:g} % | {n} | {placed:.2f} | {saw:.2f} | "
                f"{round(100 * blind / n)} % | {moved:.2f} | {final} | "
                f"{_median_p90(steps, '{:g}')} | "
                f"{'-' if middle is None else f'{100 * middle:.1f}'} | {nearer} |") in text
    # the blocked share within each radius of the slot, by hand
    radii: dict[float, list[list[list[float]]]] = {}
    with sqlite3.connect(db) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            radii.setdefault(density, []).append(json.loads(record)["density_by_radius"])
    for density, rows in radii.items():
        assert rows[0][0][0] == near_m
        means = [sum(r[k][1] for r in rows) / len(rows) for k in range(len(rows[0]))]
        assert ("| " + " | ".join([f"{100 * density:g} %"] + [f"{100 * v:.1f}" for v in means])
                + " |") in text
    assert text == (tmp_path / "out" / "report.md").read_text()
    assert "(100)" in text  # the paper's optimal at 5 %, 20 % tolerance, with secondary
    csv_lines = (tmp_path / "out" / "report.csv").read_text().splitlines()
    assert len(csv_lines) == 1 + len(count)
    assert (tmp_path / "out" / "report.png").stat().st_size > 10_000
