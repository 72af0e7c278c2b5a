"""Scenario files: defaults, validation, and the one-line errors of bad input."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.cli import main
from sim.config.scenario import (
    DEFAULT_SCENARIO,
    Scenario,
    ScenarioError,
    load_scenario,
    parse_scenario,
)


def test_default_file_parses_and_is_frozen():
    s = load_scenario()
    assert s.name == "default" and s.robots.count == 2
    assert s.source == str(DEFAULT_SCENARIO)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.seed = 3  # type: ignore[misc]


def test_empty_table_gives_the_dataclass_defaults():
    assert parse_scenario({}) == dataclasses.replace(Scenario(), source="<string>")


def test_seed_override():
    assert load_scenario(seed=7).seed == 7


def test_circle_of_bases_faces_the_workpiece():
    s = parse_scenario({"robots": {"count": 3, "start_radius_m": 2.0}})
    for base in s.base_poses():
        assert math.hypot(base.x, base.y) == pytest.approx(2.0)
        facing = math.radians(base.yaw_deg)
        # the base's +x axis points at the work-piece centre
        assert math.cos(facing) * -base.x + math.sin(facing) * -base.y == pytest.approx(2.0)


# (toml text, key that the error must name)
BAD = {
    "unknown key": ("bogus = 1\n", "bogus"),
    "unknown nested key": ("[camera]\nzoom = 2\n", "camera.zoom"),
    "wrong type": ('[camera]\nwidth = "wide"\n', "camera.width"),
    "bool for number": ("[camera]\nfovy_deg = true\n", "camera.fovy_deg"),
    "negative fov": ("[camera]\nfovy_deg = -60.0\n", "camera.fovy_deg"),
    "near beyond far": ("[camera]\nnear_m = 2.0\nfar_m = 1.0\n", "camera.near_m"),
    "robot count 0": ("[robots]\ncount = 0\n", "robots.count"),
    "robot count 5": ("[robots]\ncount = 5\n", "robots.count"),
    "bases count": ("[robots]\ncount = 2\nbases = [{x = 1.0, y = 0.0}]\n", "robots.bases"),
    "target outside grid": ("[grid]\nbounds_min = [1.0, 1.0, 0.0]\nbounds_max = [2.0, 2.0, 1.0]\n",
                            "workpiece.targets[0]"),
    "target off the plate": ('[workpiece]\ntargets = [{name = "p", offset_m = [0.5, 0.0]}]\n',
                             "workpiece.targets[0].offset_m"),
    "two primaries": ('[workpiece]\ntargets = [{name = "a"}, {name = "b"}]\n',
                      "workpiece.targets"),
    "bad role": ('[workpiece]\ntargets = [{name = "a", role = "main"}]\n',
                 "workpiece.targets[0].role"),
    "obstacle size": ('[[obstacles]]\nshape = "box"\nsize = [0.1]\n', "obstacles[0].size"),
    "obstacle shape": ('[[obstacles]]\nshape = "cone"\nsize = [0.1]\n', "obstacles[0].shape"),
    "probability": ("[grid]\nhit = 1.5\n", "grid.hit"),
    "miss above half": ("[grid]\nmiss = 0.6\n", "grid.miss"),
    "stereo margin": ("[task]\nstereo_margin_px = 64\n", "task.stereo_margin_px"),
    "syntax": ("[camera\n", "<syntax>"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_invalid_scenario_exits_2_naming_the_key(case, tmp_path, capsys):
    text, key = BAD[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-record"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert str(path) in err and f"'{key}'" in err and "accepted" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "summary.json").exists()


def test_missing_file_and_bad_seed_exit_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml")]) == 2
    assert "nope.toml" in capsys.readouterr().err
    assert main(["run", "--seed", "-1", "--no-record", "--out", str(tmp_path)]) == 2
    assert "seed" in capsys.readouterr().err


def test_unknown_argument_exits_2(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["run", "--frobnicate"])
    assert stop.value.code == 2
    assert "frobnicate" in capsys.readouterr().err


@given(st.floats(min_value=-1e3, max_value=1e3, allow_nan=False))
def test_fovy_accepted_exactly_in_open_interval(fovy):
    accepted = 0 < fovy < 180
    try:
        s = parse_scenario({"camera": {"fovy_deg": fovy}})
    except ScenarioError as exc:
        assert not accepted and exc.key == "camera.fovy_deg"
    else:
        assert accepted and s.camera.fovy_deg == fovy
