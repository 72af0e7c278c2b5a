"""Scenario files: the scenario's fields, as validated frozen dataclasses.

Every field has a default except where noted, so a scenario file states only what it
changes. An invalid file raises ScenarioError, whose message is one line naming the
file, the key, the bad value and what is accepted. The checks live in the dataclasses
(``Checked``, sim/config/schema.py): a config built in code or by
``dataclasses.replace`` is checked as a parsed one is; the parser adds the file and the
key's full name. ``Scenario`` adds the checks that span fields.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from taskcam.sim.config.scene import (
    BasePose,
    CameraConfig,
    ObstacleConfig,
    PanelConfig,
    RobotsConfig,
    WorkpieceConfig,
)
from taskcam.sim.config.schema import (
    Checked,
    ScenarioError,
    build,
    checked,
    merged_tables,
    read_toml,
)
from taskcam.sim.config.stages import (
    SENSOR_DEFAULTS,
    CorrectionConfig,
    GridConfig,
    MappingConfig,
    MotionConfig,
    RatingConfig,
    SearchConfig,
    TaskConfig,
)

SCENARIO_DIR = Path(__file__).resolve().parents[2] / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "default.toml"


@dataclass(frozen=True)
class Scenario(Checked):
    # names the run directory: runs/<name>-seed<N>
    name: str = checked(lambda v: 0 < len(v) <= 100 and v.isprintable() and not set(v) & set("/\\"),
                       "1 to 100 printable characters but / and \\", "default")
    seed: int = checked(lambda v: v >= 0, "an integer >= 0", 0)
    camera: CameraConfig = field(default_factory=CameraConfig)
    robots: RobotsConfig = field(default_factory=RobotsConfig)
    workpiece: WorkpieceConfig = field(default_factory=WorkpieceConfig)
    panel: PanelConfig = field(default_factory=PanelConfig)
    obstacles: tuple[ObstacleConfig, ...] = ()
    grid: GridConfig = field(default_factory=GridConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    rating: RatingConfig = field(default_factory=RatingConfig)
    search: SearchConfig = field(default_factory=SearchConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    correction: CorrectionConfig = field(default_factory=CorrectionConfig)
    task: TaskConfig = field(default_factory=TaskConfig)
    source: str = "<defaults>"  # the file it was read from

    def __post_init__(self) -> None:
        super().__post_init__()
        _validate(self)

    def sensor(self) -> tuple[float, float, float, float]:
        """(hit, miss, clamp_min, clamp_max): the grid's, else the depth source's defaults."""
        g, default = self.grid, SENSOR_DEFAULTS[self.mapping.depth_source]
        chosen = (g.hit, g.miss, g.clamp_min, g.clamp_max)
        return tuple(d if c is None else c  # type: ignore[return-value]
                     for c, d in zip(chosen, default, strict=True))

    def base_poses(self) -> tuple[BasePose, ...]:
        """One start pose per robot: the explicit ones, else evenly on a circle."""
        if self.robots.bases:
            return self.robots.bases
        cx, cy = self.workpiece.position
        poses = []
        for i in range(self.robots.count):
            angle = math.pi + 2 * math.pi * i / self.robots.count
            poses.append(BasePose(
                cx + self.robots.start_radius_m * math.cos(angle),
                cy + self.robots.start_radius_m * math.sin(angle),
                math.degrees(math.remainder(angle + math.pi, 2 * math.pi)),
            ))
        return tuple(poses)


def _validate(s: Scenario) -> None:
    """The checks that span tables (a table's own run in its dataclass)."""
    src = s.source
    if s.robots.bases and len(s.robots.bases) != s.robots.count:
        raise ScenarioError(src, "robots.bases", len(s.robots.bases),
                            f"exactly robots.count = {s.robots.count} poses, or none")
    hit, miss, clamp_min, clamp_max = s.sensor()
    if not clamp_min < miss < 0.5 < hit < clamp_max:
        raise ScenarioError(src, "grid.miss", miss,
                            f"grid.clamp_min < grid.miss < 0.5 < grid.hit < grid.clamp_max "
                            f"(here {clamp_min}, {miss}, {hit}, {clamp_max})")


def parse_scenario(data: Mapping[str, Any], source: str = "<string>") -> Scenario:
    """Build and validate a Scenario from a parsed TOML table."""
    return build(Scenario, data, "", source)


def scenario_table(path: Path, below: tuple[Path, ...] = ()) -> dict[str, Any]:
    """A scenario (or sweep) file's table over that of the file it ``extends`` (a path
    relative to it, of a file of the same kind): tables merge key by key, any other value
    (lists included) replaces the one below; the name is never inherited. ``below``: the
    files that extend this one."""
    data = read_toml(path)
    base = data.pop("extends", None)
    if base is None:
        return data
    accepted = "the path of another file of its kind (.toml), relative to this one"
    if not isinstance(base, str) or not base.endswith(".toml"):
        raise ScenarioError(str(path), "extends", base, accepted)
    parent = (path.parent / base).resolve()
    if parent == path.resolve() or parent in below:
        raise ScenarioError(str(path), "extends", base, accepted + ", which does not "
                            "extend this one in turn", problem="a cycle of files, with value")
    if not parent.is_file():
        raise ScenarioError(str(path), "extends", base, accepted,
                            problem="no such file, with value")
    under = scenario_table(parent, (*below, path.resolve()))
    under.pop("name", None)
    return merged_tables(under, data)


def load_scenario(path: str | Path | None = None, seed: int | None = None) -> Scenario:
    """Read a scenario file (the default one when ``path`` is None), over the file it
    ``extends`` if it names one."""
    path = Path(path) if path is not None else DEFAULT_SCENARIO
    data = scenario_table(path)
    data.setdefault("name", path.stem)
    scenario = parse_scenario(data, str(path))
    if seed is not None:
        if seed < 0:
            raise ScenarioError("--seed", "seed", seed, "an integer >= 0")
        scenario = dataclasses.replace(scenario, seed=seed)
    return scenario
