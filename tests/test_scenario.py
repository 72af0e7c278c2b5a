"""Scenario files: defaults, validation, and the one-line errors of bad input."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from taskcam.sim.cli import main
from taskcam.sim.config.scenario import DEFAULT_SCENARIO, Scenario, load_scenario, parse_scenario
from taskcam.sim.config.scene import (
    BasePose,
    CameraConfig,
    ObstacleConfig,
    TargetConfig,
    WorkpieceConfig,
)
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.config.stages import MappingConfig
from taskcam.sim.config.sweep import MethodConfig, Sweep, SweepConfig


def test_default_file_parses_and_is_frozen():
    s = load_scenario()
    assert s.name == "default" and s.robots.count == 2
    assert s.source == str(DEFAULT_SCENARIO)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.seed = 3  # type: ignore[misc]


# (table of the scenario, its config class, field, a bad value as Python holds it, the
# same value as a file writes it): a wrong type, a failed check, or a table's cross-check
INVALID = [
    ("camera", CameraConfig, "width", 8, 8),
    ("camera", CameraConfig, "width", "wide", "wide"),
    ("camera", CameraConfig, "fovy_deg", math.nan, math.nan),
    ("camera", CameraConfig, "samples", True, True),
    ("mapping", MappingConfig, "depth_source", "sonar", "sonar"),
    ("mapping", MappingConfig, "region_half_m", (0.8, 0.8), [0.8, 0.8]),
    ("workpiece", WorkpieceConfig, "targets", (), []),
    ("workpiece", WorkpieceConfig, "targets", (TargetConfig("a"), TargetConfig("b")),
     [{"name": "a"}, {"name": "b"}]),
    ("workpiece", WorkpieceConfig, "position", [0.0, 0.0], None),  # a list is not a tuple
]


@pytest.mark.parametrize(("table", "cls", "key", "value", "written"), INVALID,
                         ids=[f"{c[0]}.{c[2]}={c[3]!r}" for c in INVALID])
def test_an_invalid_value_is_refused_every_way_a_scenario_is_built(table, cls, key, value,
                                                                   written):
    with pytest.raises(ScenarioError) as made:  # built in code
        cls(**{key: value})
    assert made.value.key == key and made.value.source == f"<{cls.__name__}>"
    with pytest.raises(ScenarioError) as replaced:  # replaced in a valid one, then nested
        dataclasses.replace(Scenario(), **{table: dataclasses.replace(cls(), **{key: value})})
    assert replaced.value.key == key
    if written is not None:  # read from a file: the key in full
        with pytest.raises(ScenarioError) as parsed:
            parse_scenario({table: {key: written}}, "bad.toml")
        assert parsed.value.key == f"{table}.{key}" and parsed.value.source == "bad.toml"


def test_a_wrong_type_in_a_nested_table_or_list_is_refused():
    with pytest.raises(ScenarioError) as error:
        Scenario(camera=MappingConfig())  # type: ignore[arg-type]
    assert error.value.key == "camera" and "fovy_deg" in error.value.accepted
    with pytest.raises(ScenarioError) as error:
        Scenario(obstacles=({"shape": "box"},))  # type: ignore[arg-type]
    assert error.value.key == "obstacles"
    with pytest.raises(ScenarioError) as error:
        BasePose(1.0, math.inf)
    assert error.value.key == "y"


def test_an_obstacle_checks_its_size_against_its_shape():
    assert ObstacleConfig("cylinder", size=(0.1, 0.3)).size == (0.1, 0.3)
    with pytest.raises(ScenarioError) as error:
        ObstacleConfig("box", size=(0.1, 0.3))
    assert error.value.key == "size" and "3 numbers for a box" in str(error.value)


def test_a_cross_field_check_runs_on_replace_and_names_both_keys():
    s = load_scenario()
    with pytest.raises(ScenarioError) as error:  # within a table
        dataclasses.replace(s, camera=dataclasses.replace(s.camera, near_m=2.0))
    assert error.value.key == "near_m" and "far_m (1.5)" in error.value.accepted
    with pytest.raises(ScenarioError) as error:  # across tables
        dataclasses.replace(s, grid=dataclasses.replace(s.grid, miss=0.001))
    assert error.value.key == "grid.miss" and "grid.clamp_min" in error.value.accepted
    assert error.value.source == str(DEFAULT_SCENARIO)


def test_the_sweep_configs_check_themselves():
    with pytest.raises(ScenarioError) as error:
        MethodConfig("best", "best_view")  # type: ignore[arg-type]
    assert error.value.key == "placement"
    with pytest.raises(ScenarioError) as error:
        dataclasses.replace(SweepConfig(), densities=(0.2, 0.2))
    assert error.value.key == "densities"
    with pytest.raises(ScenarioError) as error:
        SweepConfig(methods=(MethodConfig("a"), MethodConfig("a")))
    assert error.value.key == "methods"
    with pytest.raises(ScenarioError) as error:  # a sweep judges the task
        Sweep(SweepConfig(), Scenario(), "sweep.toml")
    assert error.value.key == "task.enabled"
    judged = Scenario(task=dataclasses.replace(Scenario().task, enabled=True))
    assert Sweep(SweepConfig(), judged, "sweep.toml").scenario is judged


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
