"""Bad input is one line on stderr naming the file and the key, exit code 2, no
traceback, and nothing written or changed: unreadable files, databases that are not
taskcam's, robots standing inside things, bad tolerances, and a fuzz of the whole
scenario and sweep schemas."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import sqlite3
import subprocess
import sys
import tempfile
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from conftest import run_taskcam
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calibration import CalibrationError
from calibration.pose import DegenerateGeometryError, estimate_pose
from mapping import MappingError, SensorModel, StereoSettings
from placement import DetectorLimits, PlacementError
from sim.cli import main
from sim.config.scenario import (
    SCENARIO_DIR,
    ObstacleConfig,
    Scenario,
    load_scenario,
    parse_scenario,
)
from sim.config.schema import ScenarioError, build, convert, one_line
from sim.config.sweep import GENERATED, SweepConfig, load_sweep
from sim.experiments.results import Results, ResultsError
from sim.world.scene import build_scene

SMOKE = (SCENARIO_DIR / "smoke.toml").read_text()


def cli(*argv: str) -> tuple[int, str]:
    """``taskcam`` in this process: exit code and stderr."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(list(argv))
        except SystemExit as stop:  # argparse
            code = int(stop.code or 0)
    return code, err.getvalue()


def assert_one_line_error(code: int, err: str, source: Path | str, key: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"taskcam: error: {one_line(str(source))}"), err
    assert f"key '{one_line(key)}'" in lines[0] and "accepted: " in lines[0], err
    assert "Traceback" not in err


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
from sim.experiments.results import Results
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


# ------------------------------------------------------------------ schema fuzz


@dataclass(frozen=True)
class Site:
    """Where in a file an invalid value goes: the tables (name, None) and lists of tables
    (name, item class) leading to a table of class ``owner``, and a key of it (None: a key
    it does not have)."""

    steps: tuple[tuple[str, type | None], ...]
    owner: type
    key: str | None


def sites(cls: type, steps: tuple[tuple[str, type | None], ...] = ()) -> list[Site]:
    """Every place of the schema under ``cls``, walking its dataclasses: new keys are
    fuzzed without touching this test."""
    out = [Site(steps, cls, None)]
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name == "source":
            continue
        tp = hints[f.name]
        out.append(Site(steps, cls, f.name))
        if dataclasses.is_dataclass(tp):
            out += sites(typing.cast(type, tp), (*steps, (f.name, None)))
        elif item := list_item(tp):
            out += sites(item, (*steps, (f.name, item)))
    return out


def list_item(tp: Any) -> type | None:
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and args and dataclasses.is_dataclass(args[0]):
        return typing.cast(type, args[0])
    return None


# Valid scaffolding around a fuzzed key: a list's one table and what it needs beside it.
ITEMS: dict[type, dict[str, Any]] = {ObstacleConfig: {"shape": "sphere", "size": [0.1]}}
BESIDE = {"bases": {"count": 1}}  # one base: one robot


def item_of(cls: type) -> dict[str, Any]:
    """A valid table of ``cls`` with its required keys only (plus ITEMS)."""
    hints, table = typing.get_type_hints(cls), dict(ITEMS.get(cls, {}))
    simple = {str: "a", float: 0.0, int: 1, bool: True}
    for f in dataclasses.fields(cls):
        if f.name not in table and (f.metadata.get("required") or (
                f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)):
            table[f.name] = simple[hints[f.name]]
    return table


def document(site: Site, key: str, value: Any, drop: bool = False) -> tuple[dict, str]:
    """A file with ``value`` at ``key`` of the site's table (``drop``: the key left out);
    and the key as an error must name it."""
    doc: dict[str, Any] = {}
    table, path = doc, []
    for name, item in site.steps:
        table.update(BESIDE.get(name, {}))
        if item is None:
            table = table.setdefault(name, {})
            path.append(name)
        else:
            entry = item_of(item)
            table[name] = [entry]
            table = entry
            path.append(f"{name}[0]")
    if drop:
        table.pop(key, None)
    else:
        table[key] = value
    return doc, ".".join([*path, key])


TOML_KINDS: dict[str, st.SearchStrategy[Any]] = {
    "string": st.text(max_size=8),
    "integer": st.integers(-(2 ** 63), 2 ** 63 - 1),
    "float": st.floats(allow_nan=False, allow_infinity=False).filter(lambda v: v != int(v)),
    "boolean": st.booleans(),
    "array": st.lists(st.integers(-3, 3), max_size=3),
    "table": st.dictionaries(st.sampled_from("abc"), st.integers(0, 3), max_size=2),
}


def optional_inner(tp: Any) -> Any:
    """``X`` of ``X | None``; else the type itself."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return next(a for a in typing.get_args(tp) if a is not type(None))
    return tp


def takes(tp: Any) -> set[str]:
    """The TOML kinds a field's type accepts."""
    tp = optional_inner(tp)
    if typing.get_origin(tp) is Literal:
        return {"string"}
    if typing.get_origin(tp) is tuple:
        return {"array"}
    if dataclasses.is_dataclass(tp):
        return {"table"}
    return {float: {"integer", "float"}, int: {"integer"}, bool: {"boolean"},
            str: {"string"}}[tp]


def wrong_kind(tp: Any) -> st.SearchStrategy[Any]:
    return st.one_of([TOML_KINDS[k] for k in sorted(set(TOML_KINDS) - takes(tp))])


def right_kind(tp: Any) -> st.SearchStrategy[Any]:
    """Values of the type's own kind, valid or not (to be filtered by its check)."""
    tp = optional_inner(tp)
    if typing.get_origin(tp) is tuple:
        return st.lists(right_kind(typing.get_args(tp)[0]), max_size=4)
    if dataclasses.is_dataclass(tp):
        return st.just(item_of(typing.cast(type, tp)))
    return {float: st.floats(allow_nan=False, allow_infinity=False) | st.integers(-10, 500)
            | st.sampled_from([0.0, -0.0, 1e-9, 0.2, 0.5, 1.0, 180.0]),
            int: st.integers(-(2 ** 63), 2 ** 63 - 1) | st.integers(-5, 70000),
            str: st.text(max_size=120), bool: st.booleans()}[tp]


def element(tp: Any) -> Any:
    """A valid element of a list of ``tp``."""
    if dataclasses.is_dataclass(tp):
        return item_of(typing.cast(type, tp))
    return {float: 0.5, int: 1, str: "a"}[tp]


def invalid(site: Site) -> st.SearchStrategy[tuple[dict, str]]:
    """Invalid files at one site, each with the key its error must name: an unknown key,
    a wrong kind of value, a value its check refuses, a non-finite number, a string not
    among the choices, a list of the wrong length or with an element of a wrong kind,
    a required key left out."""
    fields = {f.name: f for f in dataclasses.fields(site.owner)}
    if site.key is None:
        names = st.text(min_size=1, max_size=10).filter(
            lambda k: k not in fields and k != "overrides")
        return st.tuples(names, st.integers(0, 9)).map(lambda kv: document(site, *kv))
    key = site.key
    f, tp = fields[key], typing.get_type_hints(site.owner)[key]

    def at(values: st.SearchStrategy[Any], index: int | None = None) -> st.SearchStrategy:
        suffix = "" if index is None else f"[{index}]"
        return values.map(lambda v: document(site, key, v)).map(lambda d: (d[0], d[1] + suffix))

    options = [at(wrong_kind(tp))]
    check = f.metadata.get("check")
    if check is not None:
        options.append(at(right_kind(tp).filter(
            lambda v: not check[0](convert(tp, v, key, "<fuzz>")))))
    inner = optional_inner(tp)
    if inner is float:
        options.append(at(st.sampled_from([math.inf, -math.inf, math.nan])))
    if typing.get_origin(inner) is Literal:
        options.append(at(st.text(max_size=12).filter(lambda v: v not in typing.get_args(inner))))
    if typing.get_origin(inner) is tuple:
        args = typing.get_args(inner)
        if args[-1] is Ellipsis:  # a list: an element of a wrong kind after valid ones
            options.append(st.tuples(st.integers(0, 2), wrong_kind(args[0])).flatmap(
                lambda iv: at(st.just([*[element(args[0])] * iv[0], iv[1]]), iv[0])))
        else:  # a fixed length: another one, or elements of a wrong kind
            finite = right_kind(args[0])
            options.append(at(st.lists(finite, max_size=6).filter(lambda v: len(v) != len(args))))
            options.append(at(st.lists(st.text(max_size=3), min_size=len(args),
                                       max_size=len(args))))
    if f.metadata.get("required") or (f.default is dataclasses.MISSING
                                      and f.default_factory is dataclasses.MISSING):
        options.append(st.just(document(site, key, None, drop=True)))
    return st.one_of(options)


SCENARIO_SITES = sites(Scenario)
SWEEP_SITES = sites(SweepConfig)
# Under a sweep's [overrides]: all but what each trial sets itself (tested above).
OVERRIDE_SITES = [s for s in SCENARIO_SITES
                  if (s.steps[0][0] if s.steps else s.key) not in GENERATED]


def test_the_fuzz_covers_the_schema_and_its_scaffolds_are_valid():
    keys = {s.key for s in SCENARIO_SITES}
    assert {"fovy_deg", "tolerances", "bases", "x", "size", "st_error_m"} <= keys
    assert {"densities", "methods", "placement"} <= {s.key for s in SWEEP_SITES}
    for site in SCENARIO_SITES:
        parse_scenario(document(site, "-", 0, drop=True)[0])  # the scaffolding alone
    for site in SWEEP_SITES:
        build(SweepConfig, document(site, "-", 0, drop=True)[0], "", "<fuzz>")


def toml(value: Any) -> str:
    """A value as TOML (tables inline)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isfinite(value):
            return repr(value)
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return '"' + "".join(c if c not in '"\\' and 0x20 <= ord(c) != 0x7f else
                             f"\\u{ord(c):04x}" for c in value) + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{toml(k)} = {toml(v)}" for k, v in value.items()) + "}"


def toml_file(doc: dict[str, Any]) -> str:
    return "".join(f"{toml(k)} = {toml(v)}\n" for k, v in doc.items())


def check_scenario_file(doc: dict, key: str, run: Callable[[Path], tuple[int, str]]) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.toml"
        path.write_text(toml_file(doc))
        with pytest.raises(ScenarioError) as error:  # fast: never runs an episode
            load_scenario(path)
        assert error.value.key == key, (toml_file(doc), str(error.value))
        code, err = run(path)
        assert_one_line_error(code, err, path, key)
        assert sorted(p.name for p in Path(folder).iterdir()) == ["fuzz.toml"]


def run_in_process(path: Path) -> tuple[int, str]:
    return cli("run", str(path), "--out", str(path.parent / "out"), "--no-record")


def run_console_script(path: Path) -> tuple[int, str]:
    done = run_taskcam("run", str(path), "--out", str(path.parent / "out"), "--no-record")
    return done.returncode, done.stderr


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.filter_too_much])
@given(st.sampled_from(SCENARIO_SITES).flatmap(invalid))
def test_every_invalid_scenario_exits_2_naming_its_key(case):
    check_scenario_file(*case, run_in_process)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                HealthCheck.filter_too_much])
@given(st.sampled_from(SCENARIO_SITES).flatmap(invalid))
def test_invalid_scenarios_through_the_console_script(case):
    check_scenario_file(*case, run_console_script)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.filter_too_much])
@given(st.one_of(st.sampled_from(SWEEP_SITES).flatmap(invalid).map(lambda c: (*c, False)),
                 st.sampled_from(OVERRIDE_SITES).flatmap(invalid).map(lambda c: (*c, True))))
def test_every_invalid_sweep_exits_2_naming_its_key(case):
    doc, key, override = case
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.toml"
        sweep = {"overrides": doc} if override else doc
        path.write_text(toml_file(sweep))
        source = f"{path} [overrides]" if override else path
        with pytest.raises(ScenarioError) as error:
            load_sweep(path)
        assert error.value.key == key, (toml_file(sweep), str(error.value))
        code, err = cli("sweep", str(path), "--db", str(Path(folder) / "r.sqlite"))
        assert_one_line_error(code, err, source, key)
        assert sorted(p.name for p in Path(folder).iterdir()) == ["fuzz.toml"]


def test_an_empty_sweep_file_is_a_valid_sweep(tmp_path):
    """The sweep fuzz's scaffolding: nothing but its defaults, on the default scenario."""
    path = tmp_path / "empty.toml"
    path.write_text("")
    assert load_sweep(path).config == dataclasses.replace(SweepConfig(), name="empty")
