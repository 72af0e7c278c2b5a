"""Bad input is one line on stderr naming the file and the key, exit code 2, no
traceback, and nothing written or changed: unreadable files, databases that are not
taskcam's, robots standing inside things, bad tolerances (the schema's fuzz is in
test_schema_fuzz.py)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import run_taskcam
from hypothesis import given, settings
from hypothesis import strategies as st
from input_errors import SMOKE, assert_one_line_error, cli

from taskcam.calibration import CalibrationError
from taskcam.calibration.pose import DegenerateGeometryError, estimate_pose
from taskcam.mapping import MappingError, SensorModel, StereoSettings
from taskcam.placement import DetectorLimits, PlacementError
from taskcam.sim.config.scenario import load_scenario, parse_scenario
from taskcam.sim.config.scene import ObstacleConfig
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.config.sweep import GENERATED, load_sweep
from taskcam.sim.experiments.results import Results, ResultsError
from taskcam.sim.world.scene import build_scene

# ------------------------------------------------------------------ files


@pytest.mark.parametrize(("content", "found"), [
    (b'name = "caf\xe9"\n', "not UTF-8 text"),  # Latin-1
    (bytes(range(256)), "not UTF-8 text"),  # binary
    (b'seed = 1\x00\n', "valid TOML"),  # NUL: UTF-8, but not TOML
    (b"[camera\nwidth = 3\n", "valid TOML"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "not UTF-8 text"),
])
def test_an_unreadable_scenario_or_sweep_file_is_one_line(tmp_path, content, found):
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    code, err = cli("run", str(path), "--out", str(tmp_path / "out"), "--no-record")
    assert_one_line_error(code, err, path, "<file>" if "UTF-8" in found else "<syntax>")
    assert found in err
    code, err = cli("sweep", str(path), "--db", str(tmp_path / "r.sqlite"))
    assert_one_line_error(code, err, path, "<file>" if "UTF-8" in found else "<syntax>")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]  # nothing written


def test_a_sweeps_unreadable_base_scenario_is_named(tmp_path):
    (tmp_path / "base.toml").write_bytes(b"seed = \xff\n")
    spec = tmp_path / "s.toml"
    spec.write_text(SMOKE.replace('scenario = "default.toml"', 'scenario = "base.toml"'))
    code, err = cli("sweep", str(spec), "--db", str(tmp_path / "r.sqlite"))
    assert_one_line_error(code, err, tmp_path / "base.toml", "<file>")


def test_a_byte_order_mark_and_a_directory(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbfseed = 4\n")  # UTF-8 with a BOM, as some editors save
    assert load_scenario(path).seed == 4
    code, err = cli("run", str(tmp_path), "--no-record", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, err, tmp_path, "<file>")


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=200).map(str.encode))
def test_any_bytes_give_a_scenario_or_a_one_line_error(content):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.toml"
        path.write_bytes(content)
        for load in (load_scenario, load_sweep):
            try:
                load(path)
            except ScenarioError as exc:
                assert "\n" not in str(exc) and str(exc).startswith(str(path))


def test_the_console_script_refuses_a_binary_scenario(tmp_path):
    path = tmp_path / "image.toml"
    path.write_bytes(bytes(range(256)) * 4)
    done = run_taskcam("run", str(path), "--out", str(tmp_path / "out"))
    assert_one_line_error(done.returncode, done.stderr, path, "<file>")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ databases


def not_taskcam(tmp_path: Path) -> dict[str, Path]:
    """Files that exist but are not taskcam results databases."""
    files = {"text": tmp_path / "notes.sqlite", "binary": tmp_path / "blob.sqlite",
             "other_app": tmp_path / "app.sqlite", "no_tables": tmp_path / "blank.sqlite",
             "other_schema": tmp_path / "old.sqlite"}
    files["text"].write_text("my results, do not lose\n")
    files["binary"].write_bytes(bytes(range(256)) * 16)
    with contextlib.closing(sqlite3.connect(files["other_app"])) as db, db:
        db.execute("CREATE TABLE photos (id INTEGER, path TEXT)")
        db.execute("INSERT INTO photos VALUES (1, 'a.jpg')")
    with contextlib.closing(sqlite3.connect(files["no_tables"])) as db:
        db.execute("PRAGMA user_version = 7")  # a valid SQLite file without any table
    with contextlib.closing(sqlite3.connect(files["other_schema"])) as db, db:
        for table in ("sweep", "trials", "outcomes", "successes"):
            db.execute(f"CREATE TABLE {table} (x)")
    return files


@pytest.mark.parametrize("kind", ["text", "binary", "other_app", "no_tables", "other_schema"])
def test_sweep_and_report_leave_a_foreign_file_as_it_was(tmp_path, kind):
    path = not_taskcam(tmp_path)[kind]
    before = path.read_bytes()
    listing = sorted(p.name for p in tmp_path.iterdir())
    spec = tmp_path / "smoke.toml"
    spec.write_text(SMOKE)
    for argv, key in ((["sweep", str(spec), "--db", str(path)], "--db"),
                      (["sweep", str(spec), "--db", str(path), "--resume"], "--db"),
                      (["report", str(path)], "<file>"),
                      (["report", str(path), "--out", str(tmp_path / "rep")], "<file>")):
        code, err = cli(*argv)
        assert_one_line_error(code, err, path, key)
        assert path.read_bytes() == before  # byte for byte
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*listing, "smoke.toml"])
    with pytest.raises(ValueError):
        Results(path)  # the library refuses it too


@pytest.mark.slow
def test_a_sweep_on_a_scheduler_nobody_runs_exits_2_before_touching_anything(tmp_path):
    spec, db = tmp_path / "smoke.toml", tmp_path / "out" / "r.sqlite"
    spec.write_text(SMOKE)
    code, err = cli("sweep", str(spec), "--db", str(db), "--scheduler", "tcp://127.0.0.1:1")
    assert_one_line_error(code, err, "--scheduler", "scheduler")
    assert "cannot be reached" in err and "tcp://127.0.0.1:1" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["smoke.toml"]


def test_report_of_a_missing_file_or_a_directory_exits_2(tmp_path):
    code, err = cli("report", str(tmp_path / "nope.sqlite"))
    assert_one_line_error(code, err, tmp_path / "nope.sqlite", "<file>")
    assert not (tmp_path / "nope.sqlite").exists()
    code, err = cli("report", str(tmp_path))
    assert_one_line_error(code, err, tmp_path, "<file>")
    db, out = tmp_path / "r.sqlite", tmp_path / "out.md"
    Results(db).close()
    out.write_text("mine")
    code, err = cli("report", str(db), "--out", str(out))
    assert_one_line_error(code, err, "--out", "out")
    assert out.read_text() == "mine"


def record(density_index: int, trial: int, ok: bool) -> dict[str, Any]:
    return {"density_index": density_index, "trial": trial, "seed": trial, "density": 0.05,
            "achieved_density": 0.05, "obstacles": 1, "timings_s": {"total": 1.0},
            "methods": [{"method": "optimal", "placement": "rating", "secondary": True,
                         "final_displacement_m": 0.01, "steps": 2, "stopped_by": "converged",
                         "success": {"0.2": ok, "0.1": False}}]}


def test_report_reads_a_results_database_without_changing_it(tmp_path):
    db = tmp_path / "r.sqlite"
    with Results(db) as results:
        results.start({"sweep": {"densities": [0.05], "methods": [{"name": "optimal"}]}}, False)
    before = db.read_bytes()
    code, err = cli("report", str(db))  # a sweep that has not finished a trial yet
    assert_one_line_error(code, err, db, "<file>")
    assert "without a finished trial" in err
    with Results(db) as results:
        results.add(record(0, 0, True))
        results.add(record(0, 1, False))
    before = db.read_bytes()
    code, err = cli("report", str(db), "--out", str(tmp_path / "rep"))
    assert code == 0, err
    assert db.read_bytes() == before
    assert "50 [" in (tmp_path / "rep" / "r.md").read_text()  # 1 of 2 at 20 %


KILLED_MID_TRIAL = """
import os, signal, sys
from taskcam.sim.experiments.results import Results
results = Results(sys.argv[1])
results.add(json.loads(sys.argv[2]))
results.db.execute("PRAGMA cache_size = 1")  # the pages spill into the file early
results.db.execute("BEGIN")
for i in range(1, 3000):
    results.db.execute("INSERT INTO trials VALUES (0, ?, 0, 0, 0, 0, 0, ?)", (i, "x" * 900))
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_sweep_killed_mid_transaction_is_read_as_rolled_back(tmp_path):
    """report reads the last committed state without rolling the file back itself; the
    sweep (writing) lets SQLite roll it back."""
    db = tmp_path / "killed.sqlite"
    with Results(db) as results:
        results.start({"sweep": {"densities": [0.05], "methods": [{"name": "optimal"}]}}, False)
    subprocess.run([sys.executable, "-c", "import json\n" + KILLED_MID_TRIAL, str(db),
                    json.dumps(record(0, 0, True))], check=False)
    journal = tmp_path / "killed.sqlite-journal"
    assert journal.exists()  # a hot journal: the transaction was cut off
    before = db.read_bytes(), journal.read_bytes()
    code, err = cli("report", str(db), "--out", str(tmp_path / "rep"))
    assert code == 0, err
    assert (db.read_bytes(), journal.read_bytes()) == before
    with Results(db, readonly=True) as results:
        assert results.done() == {(0, 0)}
    with Results(db) as results:
        assert results.done() == {(0, 0)}
    assert not journal.exists()


def test_an_empty_file_becomes_a_results_database(tmp_path):
    db = tmp_path / "new.sqlite"
    db.touch()
    with Results(db) as results:
        assert results.description() is None and results.done() == set()


# ------------------------------------------------------------------ robots inside things

ROBOT_CASES = {  # a scenario, the key the error names and what it must say
    "in the table": ({"robots": {"count": 1, "bases": [{"x": 0.3, "y": 0.0}]}},
                     "robots.bases[0]", "workpiece/table"),
    "in a box": ({"robots": {"count": 1, "bases": [{"x": 1.5, "y": 0.0, "yaw_deg": 90}]},
                  "obstacles": [{"shape": "box", "position": [1.5, 0.45, 0.3],
                                 "size": [0.1, 0.1, 0.3]}]},
                 "robots.bases[0]", "obstacles[0] (a box)"),
    "in a cylinder": ({"robots": {"count": 1, "bases": [{"x": 1.5, "y": 0.0}]},
                       "obstacles": [{"shape": "sphere", "position": [0, 1.2, 0.5],
                                      "size": [0.1]},
                                     {"shape": "cylinder", "position": [1.9, 0.0, 0.3],
                                      "size": [0.1, 0.3]}]},
                      "robots.bases[0]", "obstacles[1] (a cylinder)"),
    "around a sphere": ({"robots": {"count": 1, "bases": [{"x": 1.5, "y": 0.0}]},
                         "obstacles": [{"shape": "sphere", "position": [1.5, 0.0, 0.5],
                                        "size": [0.05]}]},
                        "robots.bases[0]", "obstacles[0] (a sphere)"),
    "in another robot": ({"robots": {"count": 3, "bases": [
        {"x": -1.8, "y": 0.0}, {"x": 1.5, "y": 0.0}, {"x": 1.7, "y": 0.3}]}},
        "robots.bases[1]", "r3/chassis_collision (robots.bases[2])"),
    "on a circle too small": ({"robots": {"count": 3, "start_radius_m": 0.4}},
                              "robots.start_radius_m", "workpiece/table"),
}


@pytest.mark.parametrize("case", sorted(ROBOT_CASES))
def test_a_robot_inside_something_is_refused_naming_both(case):
    data, key, what = ROBOT_CASES[case]
    with pytest.raises(ScenarioError) as error:
        build_scene(parse_scenario(data, "scene.toml"))
    assert error.value.key == key
    assert f"overlaps {what} by" in str(error.value)


@pytest.mark.parametrize("obstacle", [
    {"shape": "sphere", "position": [1.5, 0.0, 2.2], "size": [0.2]},  # above the robot
    {"shape": "box", "position": [1.5, 0.45, 0.3], "size": [0.1, 0.1, 0.3]},  # beside it
    {"shape": "cylinder", "position": [1.5, -0.42, 0.3], "size": [0.1, 0.3]},
])
def test_a_robot_beside_or_under_something_is_accepted(obstacle):
    """The check is on the real geometry: a footprint that overlaps an obstacle's from
    below, or a box that clears the chassis at this heading, is fine."""
    s = parse_scenario({"robots": {"count": 1, "bases": [{"x": 1.5, "y": 0.0}]},
                        "obstacles": [obstacle]})
    assert len(build_scene(s).robots) == 1


def test_run_and_sweep_refuse_a_robot_in_the_table(tmp_path):
    bad = '[robots]\ncount = 1\nbases = [{ x = 0.2, y = 0.1 }]\n'
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    code, err = cli("run", str(path), "--out", str(tmp_path / "out"), "--no-record")
    assert_one_line_error(code, err, path, "robots.bases[0]")
    assert "workpiece/table" in err and not (tmp_path / "out").exists()
    spec = tmp_path / "sweep.toml"
    spec.write_text(SMOKE + "\n[overrides.robots]\ncount = 1\nbases = [{ x = 0.2, y = 0.1 }]\n")
    code, err = cli("sweep", str(spec), "--db", str(tmp_path / "r.sqlite"))
    assert_one_line_error(code, err, f"{spec} [overrides]", "robots.bases[0]")
    assert not (tmp_path / "r.sqlite").exists()


# ------------------------------------------------------------------ tolerances


@pytest.mark.parametrize(("tolerances", "ok"), [
    ([], False), ([0.0], False), ([-0.1], False), ([1.5], False), ([0.1, 0.1], False),
    ([0.1, 0.10000001], False),  # the same tolerance as the records name it (%g)
    ([1.0], True), ([0.01, 0.2], True), ([0.1, 0.10001], True),  # any order
])
def test_tolerances(tolerances, ok):
    data = {"task": {"tolerances": tolerances}}
    if ok:
        assert parse_scenario(data).task.tolerances == tuple(tolerances)
    else:
        with pytest.raises(ScenarioError) as error:
            parse_scenario(data)
        assert error.value.key == "task.tolerances"


def test_a_sweep_may_not_override_what_each_trial_sets(tmp_path):
    for key, value in (("obstacles", '[{ shape = "sphere", size = [0.1] }]'), ("seed", "3")):
        assert key in GENERATED
        spec = tmp_path / f"{key}.toml"
        spec.write_text(SMOKE.replace("[overrides.camera]", f"[overrides]\n{key} = {value}\n\n"
                                      "[overrides.camera]"))
        code, err = cli("sweep", str(spec), "--db", str(tmp_path / "r.sqlite"))
        assert_one_line_error(code, err, spec, f"overrides.{key}")


@pytest.mark.parametrize(("name", "why"), [
    ("optimal", "unknown"),
    ("no_such_module_anywhere:method", "not importable"),
    ("taskcam.placement.methods:no_such_method", "has no"),
    ("taskcam.placement.methods:ACCEPTED", "not callable"),
])
def test_a_placement_method_that_does_not_resolve_is_refused_naming_why(tmp_path, name, why):
    """In a sweep file's methods and a scenario's search.method alike: one line, exit 2,
    the accepted names and what is wrong with this one."""
    spec = tmp_path / "sweep.toml"
    spec.write_text(SMOKE.replace('placement = "biased_random"', f'placement = "{name}"'))
    code, err = cli("sweep", str(spec), "--db", str(tmp_path / "r.sqlite"))
    assert_one_line_error(code, err, spec, "methods[1].placement")
    assert why in err and "'informed_random'" in err and "module:callable" in err
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(f'[search]\nmethod = "{name}"\n')
    code, err = cli("run", str(scenario), "--out", str(tmp_path / "run"))
    assert_one_line_error(code, err, scenario, "search.method")
    assert why in err


def test_configs_made_in_code_are_checked_too():
    with pytest.raises(ScenarioError):
        ObstacleConfig("sphere", (0, 0, 0), (-1.0,))
    s = load_scenario()
    with pytest.raises(ScenarioError) as error:  # two explicit bases for one robot
        dataclasses.replace(s, robots=dataclasses.replace(s.robots, count=1))
    assert error.value.key == "robots.bases"


def test_each_package_has_one_error_type_naming_the_value_and_what_is_accepted(tmp_path):
    for error in (MappingError, PlacementError, CalibrationError, ScenarioError, ResultsError):
        assert issubclass(error, ValueError)  # callers' ``except ValueError`` still hold
    assert issubclass(DegenerateGeometryError, CalibrationError)
    with pytest.raises(MappingError, match=r"num_disparities 24: a positive multiple of 16"):
        StereoSettings(num_disparities=24)
    with pytest.raises(MappingError, match=r"clamp_min < miss < 0.5 < hit.*hit=0.4"):
        SensorModel(hit=0.4)
    with pytest.raises(PlacementError, match=r"max_off_normal_deg 95: degrees in \(0, 90\)"):
        DetectorLimits(max_off_normal_deg=95)
    points = np.eye(3)
    with pytest.raises(CalibrationError, match="'ransac'; one of linear, kabsch, sqpnp"):
        estimate_pose(points, points, points[:, :2], np.eye(3), method="ransac")
    with Results(tmp_path / "r.sqlite") as results, \
            pytest.raises(ResultsError, match="no table 'runs'; accepted: trials, outcomes"):
        results.rows("runs")




def test_the_tasks_slot_must_lie_inside_the_grid():
    """With the task on, the slot is the primary target: a work-piece whose
    slot (x = -0.15 from its centre) lies outside the grid is refused naming
    ``workpiece.position``; with the task off only the holes (x = 0.05, 0.17) must be."""
    data = {"grid": {"bounds_min": [-0.1, -1.5, 0.0]}, "task": {"enabled": True}}
    with pytest.raises(ScenarioError) as error:
        build_scene(parse_scenario(data, "scene.toml"))
    assert error.value.key == "workpiece.position"
    assert "slot (the task's primary target, at [-0.15, 0.0, 0.52])" in str(error.value)
    data["task"]["enabled"] = False
    assert len(build_scene(parse_scenario(data, "scene.toml")).targets) == 2
