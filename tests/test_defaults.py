"""One source of truth for defaults: the scenario table of docs/scenario.md, the code's
schema and the shipped scenario and sweep files agree."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import typing
from pathlib import Path
from typing import Any

import pytest

from taskcam.sim.config.scenario import SCENARIO_DIR, Scenario, load_scenario, parse_scenario
from taskcam.sim.config.schema import convert
from taskcam.sim.config.stages import SENSOR_DEFAULTS
from taskcam.sim.config.sweep import is_sweep_file, load_sweep

ROOT = Path(__file__).resolve().parent.parent
TABLE = ROOT / "docs" / "scenario.md"  # its section "## Keys"
SHIPPED = sorted(SCENARIO_DIR.glob("*.toml"))
SWEEPS = [p for p in SHIPPED if is_sweep_file(p)]
SCENARIOS = [p for p in SHIPPED if p not in SWEEPS]
# What a scenario file is about, its scene, rather than a setting with a default.
LAYOUT = {"name", "robots.bases", "workpiece.targets", "obstacles"}


def schema(cls: type = Scenario, prefix: str = "") -> dict[str, tuple[type, dataclasses.Field]]:
    """Every key of the scenario schema -> (the dataclass holding it, its field). Tables
    are walked into; a list of tables is a key, and so is each of its tables' keys
    (``robots.bases[].x``)."""
    hints = typing.get_type_hints(cls)
    keys: dict[str, tuple[type, dataclasses.Field]] = {}
    for f in dataclasses.fields(cls):
        if f.name == "source":
            continue
        tp, key = hints[f.name], prefix + f.name
        if dataclasses.is_dataclass(tp):
            keys |= schema(typing.cast(type, tp), key + ".")
            continue
        keys[key] = (cls, f)
        args = typing.get_args(tp)
        if typing.get_origin(tp) is tuple and args and dataclasses.is_dataclass(args[0]):
            keys |= schema(args[0], key + "[].")
    return keys


def default_of(f: dataclasses.Field) -> Any:
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default


def required(f: dataclasses.Field) -> bool:
    """Must a file state this key?"""
    return bool(f.metadata.get("required")) or (
        f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)


def key_table() -> list[tuple[list[str], list[str], str]]:
    """The scenario table (docs/scenario.md, "## Keys"): per row, the keys (``camera.fovy_deg``,
    ``obstacles[].size``), the defaults as written (one per key), the meaning."""
    text = TABLE.read_text()
    section = text[text.index("\n## Keys\n") + 1:]
    end = section.find("\n## ", 5)
    section = section if end < 0 else section[:end]
    rows = []
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        key_cell, default_cell, meaning = line.strip()[2:-2].split(" | ", 2)
        spans = re.findall(r"`([^`]*)`", key_cell)
        assert re.fullmatch(r"(`[^`]*`[ ,]*)+", key_cell), key_cell
        header = re.fullmatch(r"(\[\[?)([\w.]+)\]\]?", spans[0])
        prefix = ""
        if header:
            spans = spans[1:]
            prefix = header[2] + ("[]." if header[1] == "[[" else ".")
        keys = [prefix + s for s in spans]
        defaults = [d.strip() for d in re.findall(r"`[^`]*`|[^,`]+", default_cell) if d.strip()]
        if len(defaults) == 1:
            defaults *= len(keys)
        assert len(defaults) == len(keys), f"one default per key: {line}"
        rows.append((keys, defaults, meaning))
    return rows


def parse_literal(text: str) -> Any:
    return tomllib.loads(f"v = {text}")["v"]


def file_values(path: Path) -> dict[str, Any]:
    """Key -> value of every setting a scenario file states (lists of tables whole)."""
    out: dict[str, Any] = {}

    def walk(table: dict[str, Any], prefix: str) -> None:
        for k, v in table.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                out[prefix + k] = v
    table = tomllib.loads(path.read_text())
    table.pop("extends", None)  # the file it builds on, not a setting
    walk(table, "")
    return out


def value_at(s: Scenario, key: str) -> Any:
    for part in key.split("."):
        s = getattr(s, part)
    return s


# Defaults the table states in words, and what each means of the code's default.
PROSE = {
    ("name", "file stem"): lambda _: True,  # test_an_unnamed_file_is_named_by_its_stem
    ("robots.bases", "on a circle"): lambda d: d == () and all(
        math.isclose(math.hypot(b.x, b.y), Scenario().robots.start_radius_m)
        for b in Scenario().base_poses()),
    ("workpiece.targets", "primary + secondary"):
        lambda d: [t.role for t in d] == ["primary", "secondary"],
    ("obstacles", "none"): lambda d: d == (),
    **{(f"grid.{k}", "by depth source"): lambda d: d is None
       for k in ("hit", "miss", "clamp_min", "clamp_max")},
}


def test_every_key_of_the_schema_is_in_the_key_table_and_no_other():
    in_table = [k for keys, _, _ in key_table() for k in keys]
    assert len(in_table) == len(set(in_table)), "a key listed twice"
    assert sorted(in_table) == sorted(schema()), (
        f"not in docs/scenario.md: {sorted(set(schema()) - set(in_table))}; "
        f"not in the code: {sorted(set(in_table) - set(schema()))}")


def test_every_default_in_the_key_table_is_the_codes():
    """A default written as a TOML literal must, read by the scenario parser itself, equal
    the dataclass field's default; one written in words must be one the test knows and
    match what it says; "required" must be a key files have to state."""
    for keys, defaults, _ in key_table():
        for key, written in zip(keys, defaults, strict=True):
            owner, f = schema()[key]
            if written == "required":
                assert required(f), f"{key}: docs/scenario.md says required; the code has a default"
                continue
            assert not required(f), f"{key} is required in files; docs/scenario.md gives a default"
            if written.startswith("`"):
                hint = typing.get_type_hints(owner)[f.name]
                stated = convert(hint, parse_literal(written[1:-1]), key, "docs/scenario.md")
                assert stated == default_of(f), (
                    f"{key}: docs/scenario.md says {written}, the code {default_of(f)!r}")
            else:
                check = PROSE.get((key, written))
                assert check is not None, f"{key}: {written!r} is neither `literal` nor known"
                assert check(default_of(f)), f"{key}: {default_of(f)!r} is not {written!r}"


def test_the_sensor_models_in_the_docs_are_the_codes():
    meaning = next(m for keys, _, m in key_table() if "grid.hit" in keys)
    stated = {src: tuple(float(v) for v in vals.split(" / ")) for src, vals in
              re.findall(r"`(\w+)` ([\d.]+(?: / [\d.]+){3})", meaning)}
    assert stated == SENSOR_DEFAULTS


def test_the_mapping_threshold_is_the_same_with_or_without_the_default_file():
    """0.12 bits, as the README and default.toml give it, with or without the default
    file: the code's default and the file's may not drift apart."""
    assert parse_scenario({}).mapping.entropy_threshold_bits == 0.12
    assert load_scenario().mapping.entropy_threshold_bits == 0.12


def test_an_unnamed_file_is_named_by_its_stem(tmp_path):
    path = tmp_path / "my-scene.toml"
    path.write_text("seed = 3\n")
    assert load_scenario(path).name == "my-scene"


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_a_shipped_scenario_parses_and_builds(path):
    from taskcam.sim.world.scene import build_scene

    s = load_scenario(path)  # unknown keys, types and ranges: ScenarioError
    assert set(file_values(path)) <= set(schema())
    build_scene(s)  # the targets on the plate and in the grid, the robots clear


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_a_shipped_sweep_parses(path):
    sweep = load_sweep(path)  # its keys, its base scenario and the overrides
    assert sweep.scenario.task.enabled and sweep.config.trials >= 1


def declared() -> dict[str, dict[str, Any]]:
    """What the scenario table says a shipped file sets: file -> key -> value, from
    phrases like "`default.toml` sets `0.5`, `0.05`" (one value per key of the row)."""
    out: dict[str, dict[str, Any]] = {}
    for keys, _, meaning in key_table():
        for name, values in re.findall(r"`([\w-]+\.toml)` sets ((?:`[^`]*`(?:, )?)+)", meaning):
            literals = re.findall(r"`([^`]*)`", values)
            assert len(literals) == len(keys), f"one value per key: {meaning}"
            for key, literal in zip(keys, literals, strict=True):
                out.setdefault(name, {})[key] = parse_literal(literal)
    return out


def test_what_the_docs_say_a_shipped_file_sets_is_what_it_sets():
    said = declared()
    assert set(said) <= {p.name for p in SHIPPED}
    for name, values in said.items():
        path = SCENARIO_DIR / name
        s = load_sweep(path).scenario if path in SWEEPS else load_scenario(path)
        for key, value in values.items():
            assert value_at(s, key) == value, f"{name}: {key} is {value_at(s, key)!r}"


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_a_shipped_scenario_restates_defaults_truly(path):
    """A shipped scenario may restate a setting, as a reader's reference; it then must be
    the code's default, or a departure the scenario table declares ("`default.toml`
    sets ...", checked above). So a default that moves in the code (or a value that moves
    in the file) fails here instead of silently splitting scenarios that state the key
    from those that leave it out, as ``mapping.entropy_threshold_bits`` did (0.12 in
    default.toml and the README, 0.4 in the code). The scene itself (robots' bases,
    targets, obstacles, name) is what a scenario is for, and exempt."""
    s = load_scenario(path)
    allowed = declared().get(path.name, {})
    for key in file_values(path):
        if key in LAYOUT or key in allowed:
            continue
        f = schema()[key][1]
        assert value_at(s, key) == default_of(f), (
            f"{path.name} sets {key} = {value_at(s, key)!r}, the code's default is "
            f"{default_of(f)!r}: make them agree, or declare the departure in docs/scenario.md")
