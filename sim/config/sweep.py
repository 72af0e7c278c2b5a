"""Sweep files: many paired trials over occlusion densities, for tables like Table 1.

A sweep file (TOML) names a base scenario, the occlusion densities to generate scenes
at, the placement methods to compare on each scene, and overrides of the base
scenario's tables (e.g. a smaller camera image, to make trials cheaper)::

    name = "table1"
    scenario = "default.toml"   # relative to the sweep file, or the packaged scenarios
    seed = 0
    trials = 300                # paired scenes per density
    densities = [0.05, 0.20, 0.35]

    [[methods]]
    name = "optimal"
    placement = "rating"        # a method's name (placement/methods.py) or "module:callable"
    secondary = true            # may the method use secondary targets?

    [overrides.camera]          # merged into the base scenario
    width = 320

Trial ``k`` at density ``i`` is seeded from (``seed``, ``i``, ``k``) alone, so a trial
gives the same result whichever worker runs it, in whatever order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from taskcam.sim.config.scenario import SCENARIO_DIR, Scenario, parse_scenario, scenario_table
from taskcam.sim.config.schema import (
    Checked,
    ScenarioError,
    build,
    checked,
    merged_tables,
)
from taskcam.sim.config.stages import check_placement_method


@dataclass(frozen=True)
class MethodConfig(Checked):
    """A placement method, run on every scene of the sweep."""

    name: str = checked(lambda v: v.replace("_", "").isalnum(), "letters, digits and _",
                       "optimal")
    # a registered placement method (placement/methods.py) or a user's "module:callable"
    placement: str = "rating"
    secondary: bool = True  # may it place cameras for secondary targets, and use them?

    def __post_init__(self) -> None:
        super().__post_init__()
        check_placement_method(self, "placement", self.placement)


def _paper_methods() -> tuple[MethodConfig, ...]:
    return (MethodConfig("optimal", "rating", True),
            MethodConfig("optimal_primary", "rating", False),
            MethodConfig("random", "biased_random", True),
            MethodConfig("random_primary", "biased_random", False),
            MethodConfig("nbv", "information_gain", False))


@dataclass(frozen=True)
class SweepConfig(Checked):
    name: str = "sweep"
    scenario: str = "default.toml"  # the base scenario
    seed: int = checked(lambda v: v >= 0, "an integer >= 0", 0)
    trials: int = checked(lambda v: v >= 1, "an integer >= 1", 300)  # per density
    densities: tuple[float, ...] = checked(
        lambda v: len(v) >= 1 and all(0 <= d < 0.9 for d in v) and len(set(v)) == len(v),
        "a non-empty list of distinct fractions in [0, 0.9)", (0.05, 0.2, 0.35))
    methods: tuple[MethodConfig, ...] = checked(
        lambda v: len(v) >= 1 and len({m.name for m in v}) == len(v),
        "a non-empty list of methods with unique names", default_factory=_paper_methods)


@dataclass(frozen=True)
class Sweep(Checked):
    """A sweep file, read: its settings and the base scenario with the overrides (which
    must run the task: a sweep judges it)."""

    config: SweepConfig
    scenario: Scenario
    source: str

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.scenario.task.enabled:
            raise ScenarioError(self.scenario.source, "task.enabled", False,
                                "true: a sweep judges the task")

    def trial_seed(self, density_index: int, trial: int) -> int:
        """The scenario seed of trial ``trial`` at density ``density_index``."""
        state = np.random.SeedSequence([self.config.seed, density_index, trial])
        return int(state.generate_state(1)[0])

    def describe(self) -> dict[str, Any]:
        """What the results depend on (stored with them, checked on resume)."""
        return {"sweep": dataclasses.asdict(self.config),
                "scenario": dataclasses.asdict(dataclasses.replace(self.scenario, source="")),
                "scenes": SCENE_GENERATOR}


# Which scenes a sweep's seeds make (sim/experiments/generate.py): a new name whenever
# the generator makes other scenes from the same seeds, so that a database of the old
# ones is not resumed with new ones
SCENE_GENERATOR = "clutter about the slot, its density held from the near to the far limit"

# Scenario keys a sweep sets for each trial itself, and why
GENERATED = {"obstacles": "each trial generates its own at the sweep's densities",
             "seed": "each trial is seeded from the sweep's seed, density and trial"}


def is_sweep_file(path: str | Path) -> bool:
    """Whether a TOML file (over the file it extends) is a sweep file: it has
    ``methods`` or ``densities``; anything else is a scenario file."""
    table = scenario_table(Path(path))
    return "methods" in table or "densities" in table


def load_sweep(path: str | Path, trials: int | None = None) -> Sweep:
    """Read a sweep file; ``trials`` overrides its trials per density. Raises
    ScenarioError naming the file and key of anything invalid."""
    path = Path(path)
    data = scenario_table(path)  # over the sweep file it extends, if it names one
    overrides = data.pop("overrides", {})
    if not isinstance(overrides, Mapping):
        raise ScenarioError(str(path), "overrides", overrides,
                            "a table of scenario tables to override")
    for key, why in GENERATED.items():
        if key in overrides:
            raise ScenarioError(str(path), f"overrides.{key}", overrides[key],
                                f"no override: {why}", problem="not overridable, with value")
    data.setdefault("name", path.stem)
    config = build(SweepConfig, data, "", str(path))
    if trials is not None:
        if trials < 1:
            raise ScenarioError("--trials", "trials", trials, "an integer >= 1")
        config = dataclasses.replace(config, trials=trials)
    base_path = path.parent / config.scenario
    if not base_path.exists() and (SCENARIO_DIR / config.scenario).exists():
        base_path = SCENARIO_DIR / config.scenario
    if not base_path.exists():
        raise ScenarioError(str(path), "scenario", config.scenario,
                            f"a scenario file beside the sweep file or in {SCENARIO_DIR.name}/")
    base = scenario_table(base_path)
    base.setdefault("name", base_path.stem)
    parse_scenario(base, str(base_path))  # the base file's own errors name it
    source = f"{path} [overrides]"
    scenario = parse_scenario(merged_tables(base, {**overrides, "obstacles": []}), source)
    return Sweep(config, scenario, str(path))
