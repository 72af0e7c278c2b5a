"""Invariants over every file in scenarios/, as dm_control checks every
task: each scenario gives the same summary twice from its seed (slow: two whole episodes);
each sweep file reads (fast), and its first trial runs and makes a record the results
database takes (slow). That each file's world builds and steps physics cleanly is
tests/test_models.py's test_scenario_builds_and_steps (fast), over the same files.

The files are found, not listed: a file added to scenarios/ is checked as what it is (a
sweep file has ``methods`` or ``densities``; anything else must be a scenario).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from conftest import run_taskcam

from taskcam.sim.config.scenario import SCENARIO_DIR, load_scenario
from taskcam.sim.config.sweep import is_sweep_file, load_sweep
from taskcam.sim.experiments.results import Results
from taskcam.sim.experiments.runner import trial_specs
from taskcam.sim.experiments.trial import run_trial

FILES = sorted(SCENARIO_DIR.glob("*.toml"))


SCENARIOS = [p for p in FILES if not is_sweep_file(p)]
SWEEPS = [p for p in FILES if is_sweep_file(p)]


def test_every_file_is_a_scenario_or_a_sweep():
    assert {p.name for p in SCENARIOS} >= {"default.toml", "figure7.toml"}
    assert {p.name for p in SWEEPS} >= {"smoke.toml", "regression.toml", "table1.toml"}
    assert len(SCENARIOS) + len(SWEEPS) == len(FILES)


# ------------------------------------------------------------------ scenarios


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_each_scenario_file_reads(path):
    scenario = load_scenario(path)
    assert scenario.name == path.stem


def without_times(summary: Any) -> Any:
    """The summary without wall-clock times (``timings_s`` and every ``time_s``)."""
    if isinstance(summary, dict):
        return {k: without_times(v) for k, v in summary.items()
                if k not in ("timings_s", "time_s")}
    if isinstance(summary, list):
        return [without_times(v) for v in summary]
    return summary


def run_summary(path: Path, out: Path) -> dict[str, Any]:
    """``taskcam run`` on the file as shipped (no recording): its summary."""
    done = run_taskcam("run", str(path), "--no-record", "--out", str(out))
    assert done.returncode == 0, done.stderr
    return dict(json.loads((out / "summary.json").read_text()))


@pytest.mark.slow
@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_each_scenario_gives_the_same_summary_twice(path, request, tmp_path):
    """Two whole episodes from the file's seed. The default scenario's first is the
    session's recorded run (conftest's default_run): recording changes nothing either."""
    if path.name == "default.toml":
        _, first = request.getfixturevalue("default_run")
    else:
        first = run_summary(path, tmp_path / "first")
    second = run_summary(path, tmp_path / "second")
    assert second["robots"], second
    assert without_times(second) == without_times(first)


# ------------------------------------------------------------------ sweeps


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_each_sweep_file_reads(path):
    sweep = load_sweep(path)
    specs = trial_specs(sweep)
    assert len(specs) == sweep.config.trials * len(sweep.config.densities)
    assert {(s.density_index, s.trial) for s in specs} == {
        (i, k) for i in range(len(sweep.config.densities)) for k in range(sweep.config.trials)}


@pytest.mark.slow
@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_each_sweep_files_first_trial_runs(path, tmp_path):
    sweep = load_sweep(path)
    spec = trial_specs(sweep)[0]
    record = run_trial(spec)
    assert (record["density_index"], record["trial"], record["seed"]) == (
        spec.density_index, spec.trial, spec.seed)
    assert [m["method"] for m in record["methods"]] == [m.name for m in sweep.config.methods]
    for outcome in record["methods"]:
        assert outcome["success"], outcome  # a verdict at every tolerance
        assert all(isinstance(ok, bool) for ok in outcome["success"].values()), outcome
        for robot in outcome["robots"]:  # each move's correction, where the sweep has them
            moved = robot["placed"] and sweep.scenario.correction.enabled
            assert bool(robot["corrections"]) == moved, robot
            for c in robot["corrections"]:
                assert c["status"] in ("corrected", "uncertain", "failed"), c
                assert c["error_before"]["position_m"] > 0, c  # errors on: never exact
                assert (c["error_after"] is None) == (c["status"] == "failed"), c
    db = tmp_path / "first.sqlite"
    with Results(db) as results:  # the record is one the database takes
        results.start(sweep.describe(), resume=False)
        results.add(json.loads(json.dumps(record)))
        assert results.done() == {(spec.density_index, spec.trial)}
