"""A fuzz of the whole scenario and sweep schemas: every generated invalid file exits 2
with one line naming its key, in this process and through the console script."""

from __future__ import annotations

import dataclasses
import math
import tempfile
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import pytest
from conftest import run_taskcam
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from input_errors import assert_one_line_error, cli

from taskcam.sim.config.scenario import Scenario, load_scenario, parse_scenario
from taskcam.sim.config.scene import ObstacleConfig
from taskcam.sim.config.schema import ScenarioError, build, convert
from taskcam.sim.config.sweep import GENERATED, SweepConfig, load_sweep

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
