"""Scenario files: TOML parsed into validated, frozen dataclasses.

Every field has a default except where noted, so a scenario file states only what it
changes. An invalid file raises ScenarioError, whose message is one line naming the
file, the key, the bad value and what is accepted. The checks live in the dataclasses
(``Checked``): a config built in code or by ``dataclasses.replace`` is checked as a
parsed one is; the parser adds the file and the key's full name.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

SCENARIO_DIR = Path(__file__).resolve().parents[2] / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "default.toml"
MAX_ROBOTS = 4


def one_line(text: str) -> str:
    """``text`` with anything unprintable (newlines included) escaped."""
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


MISSING = object()  # the value of a key a file leaves out


class ScenarioError(ValueError):
    """An invalid scenario: one line naming file, key, value and what is accepted."""

    def __init__(self, source: str, key: str, value: object, accepted: str,
                 problem: str = "bad value") -> None:
        self.source, self.key, self.value, self.accepted = source, key, value, accepted
        self.problem = problem
        found = problem if value is MISSING else f"{problem} {_shown(value)}"
        super().__init__(f"{one_line(source)}: key '{one_line(key)}': {found}; "
                         f"accepted: {one_line(accepted)}")

    def within(self, source: str, prefix: str, table: Mapping[str, Any]) -> ScenarioError:
        """This error of a field of ``table`` (read from ``source`` at ``prefix``): its key
        in full, and the value as the file wrote it."""
        value = table.get(self.key, self.value)
        key = f"{prefix}.{self.key}" if prefix else self.key
        return ScenarioError(source, key, value, self.accepted, self.problem)


def _shown(value: object) -> str:
    """A value as a message shows it: tuples as lists, one line, at most 200 characters."""
    def plain(v: object) -> object:
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, Mapping):
            return {k: plain(x) for k, x in v.items()}
        return v

    text = one_line(repr(plain(value)))
    return text if len(text) <= 200 else text[:197] + "..."


Check = tuple[Callable[[Any], bool], str]


def _check(predicate: Callable[[Any], bool], accepted: str, default: Any = dataclasses.MISSING,
           default_factory: Any = dataclasses.MISSING, required: bool = False) -> Any:
    """A dataclass field whose value must satisfy ``predicate``; ``required``: a file
    must state it even though Python code may leave it to the default."""
    meta = {"check": (predicate, accepted), "required": required}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


class Checked:
    """A config dataclass whose fields' checks run whenever one is made (parsed, built in
    code, or ``dataclasses.replace``d): an invalid value never gets in."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            check: Check | None = f.metadata.get("check")
            value = getattr(self, f.name)
            if check is not None and value is not None and not check[0](value):
                source = getattr(self, "source", f"<{type(self).__name__}>")
                raise ScenarioError(source, f.name, value, check[1])


def _positive(default: float) -> Any:
    return _check(lambda v: v > 0 and math.isfinite(v), "a number > 0", default)


def _probability(default: float | None) -> Any:
    return _check(lambda v: 0 < v < 1, "a number strictly between 0 and 1", default)


def _nonnegative(default: float) -> Any:
    return _check(lambda v: v >= 0 and math.isfinite(v), "a number >= 0", default)


@dataclass(frozen=True)
class CameraConfig(Checked):
    """The stereo head: every robot's two cameras share these."""

    fovy_deg: float = _check(lambda v: 0 < v < 180, "degrees in (0, 180)", 60.0)
    width: int = _check(lambda v: 16 <= v <= 4096, "pixels in [16, 4096]", 640)
    height: int = _check(lambda v: 16 <= v <= 4096, "pixels in [16, 4096]", 480)
    baseline_m: float = _check(lambda v: 0 < v <= 0.2, "metres in (0, 0.2]", 0.12)
    near_m: float = _positive(0.35)  # depth of field, near limit
    far_m: float = _positive(1.5)  # depth of field, far limit
    coc_px: float = _positive(1.5)  # blur-circle diameter at the depth of field's limits
    # Multisample anti-aliasing, samples per pixel (0: off; rendering about twice as fast).
    samples: int = _check(lambda v: v in (0, 2, 4, 8, 16), "0, 2, 4, 8 or 16", 4)


@dataclass(frozen=True)
class BasePose(Checked):
    """A mobile base's start pose on the floor."""

    x: float
    y: float
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class RobotsConfig(Checked):
    count: int = _check(lambda v: 1 <= v <= MAX_ROBOTS, f"an integer 1 to {MAX_ROBOTS}", 2)
    # Explicit start poses, one per robot; empty: evenly on a circle facing the work-piece.
    bases: tuple[BasePose, ...] = ()
    start_radius_m: float = _positive(1.8)
    move_base: bool = True


@dataclass(frozen=True)
class TargetConfig(Checked):
    """A circular hole in the plate; offset in the plate frame from its centre (m)."""

    name: str = _check(lambda v: v.isidentifier(), "a name of letters, digits and _")
    role: Literal["primary", "secondary"] = "primary"
    offset_m: tuple[float, float] = (0.0, 0.0)
    radius_m: float = _check(lambda v: 0.002 <= v <= 0.1, "metres in [0.002, 0.1]", 0.02)
    st_error_m: float = _nonnegative(0.0)  # secondary-to-primary geometric tolerance (eq. 4)


def _default_targets() -> tuple[TargetConfig, ...]:
    return (
        TargetConfig("primary", "primary", (0.05, 0.0), 0.02),
        TargetConfig("secondary", "secondary", (0.17, 0.1), 0.015, 0.001),
    )


@dataclass(frozen=True)
class WorkpieceConfig(Checked):
    position: tuple[float, float] = (0.0, 0.0)  # floor position of the plate centre (m)
    yaw_deg: float = 0.0
    targets: tuple[TargetConfig, ...] = field(default_factory=_default_targets)
    # Where the work-piece really stands, off where the planner believes (standard
    # deviations, drawn per episode): only the cameras' sightings of the targets reveal it.
    position_error_m: float = _nonnegative(0.0)  # x and y each
    yaw_error_deg: float = _nonnegative(0.0)


@dataclass(frozen=True)
class PanelConfig(Checked):
    position: tuple[float, float, float] = (-0.15, 0.6, 0.0)  # bottom-edge centre (m)
    yaw_deg: float = 0.0


OBSTACLE_SIZES = {"box": 3, "cylinder": 2, "sphere": 1}


@dataclass(frozen=True)
class ObstacleConfig(Checked):
    """A primitive obstacle: box half-extents, cylinder (radius, half-height), sphere radius."""

    shape: Literal["box", "cylinder", "sphere"] = "box"
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size: tuple[float, ...] = _check(
        lambda v: 1 <= len(v) <= 3 and all(s > 0 for s in v), "1 to 3 numbers > 0", (0.1,),
        required=True)
    yaw_deg: float = 0.0


# Sensor models (hit, miss, clamp_min, clamp_max) per depth source. Rendered depth is
# exact, so one observation is near-certain; stereo depth has holes and outliers, so it
# takes several agreeing observations (five misses from unknown) to call a voxel free
# below the rating's P < 0.05. OctoMap's own defaults (0.7, 0.4, 0.12, 0.97) clamp free
# voxels at P = 0.12 and so could never mark a voxel free enough for the rating function.
SENSOR_DEFAULTS = {
    "render": (0.97, 0.04, 0.001, 0.999),
    "stereo": (0.75, 0.35, 0.01, 0.99),
}


@dataclass(frozen=True)
class GridConfig(Checked):
    """Voxel occupancy grid and its log-odds sensor model (probabilities; unset: by source)."""

    resolution_m: float = _check(lambda v: 0.005 <= v <= 0.5, "metres in [0.005, 0.5]", 0.05)
    bounds_min: tuple[float, float, float] = (-1.5, -1.5, 0.0)
    bounds_max: tuple[float, float, float] = (1.5, 1.5, 1.8)
    hit: float | None = _probability(None)
    miss: float | None = _probability(None)
    clamp_min: float | None = _probability(None)
    clamp_max: float | None = _probability(None)
    max_range_m: float = _positive(4.0)


@dataclass(frozen=True)
class MappingConfig(Checked):
    """Cooperative mapping: views chosen by expected information, then rendered."""

    depth_source: Literal["render", "stereo"] = "render"
    strategy: Literal["cooperative", "single", "random"] = "cooperative"
    gain: Literal["entropy", "unobserved", "rear_side"] = "entropy"
    max_views: int = _check(lambda v: 1 <= v <= 200, "an integer 1 to 200", 12)  # all robots
    entropy_threshold_bits: float = _check(lambda v: 0 <= v <= 1, "bits in [0, 1]", 0.12)
    region_half_m: tuple[float, float, float] = (0.8, 0.8, 0.6)  # around the primary target
    candidates_per_robot: int = _check(lambda v: 1 <= v <= 500, "an integer 1 to 500", 24)
    gain_stride: int = _check(lambda v: 1 <= v <= 64, "an integer 1 to 64", 16)
    pixel_stride: int = _check(lambda v: 1 <= v <= 16, "an integer 1 to 16", 2)
    motion_weight: float = _nonnegative(0.0)  # rate views by gain / (1 + w * metres moved)
    # P(occupied) assumed for never-observed voxels that a gain's ray passes (most space
    # is empty); 0.5 is the map's own value for them
    unknown_occupancy: float = _probability(0.05)


@dataclass(frozen=True)
class RatingConfig(Checked):
    """Rating function exponents (eq. 1) and occupancy thresholds."""

    alpha: float = _nonnegative(1.0)  # depth of field
    beta: float = _nonnegative(1.0)  # resolution
    gamma: float = _nonnegative(1.0)  # target field visibility
    delta: float = _nonnegative(1.0)  # target angular visibility
    free_threshold: float = _probability(0.05)  # candidate voxels: P below this
    unknown_occludes: bool = True  # never-observed voxels count as occluders for TFV
    hull_block: int = _check(lambda v: 1 <= v <= 64, "an integer 1 to 64", 4)  # voxels
    # occluder expansion by the target: "cone" exact for the camera's distance, "paper"
    # the whole target everywhere (conservative near the camera)
    expansion: Literal["cone", "paper"] = "cone"
    # directions of the sphere around a target TFV is computed on (spacing about
    # sqrt(4 pi / n) rad: 1.6 deg at 16384); time grows with them
    tfv_directions: int = _check(lambda v: 1024 <= v <= 65536, "an integer 1024 to 65536",
                                 16384)


@dataclass(frozen=True)
class SearchConfig(Checked):
    # the placement method: the rating function, the paper's biased random baseline, or
    # next-best-view by expected information gain about the target region
    method: Literal["rating", "biased_random", "information_gain"] = "rating"
    random_max_angle_deg: float = _check(lambda v: 0 < v <= 90, "degrees in (0, 90]", 60.0)
    gain_samples: int = _check(lambda v: v >= 1, "an integer >= 1", 300)  # information_gain
    # reject a candidate when the nominal scene's geometry hides its target (an oracle:
    # off, each method knows only what its own model tells it)
    check_sight: bool = True
    strategy: Literal["exhaustive", "coarse", "bounded", "random"] = "exhaustive"
    coarse_step: int = _check(lambda v: 1 <= v <= 16, "an integer 1 to 16", 2)
    max_distance_m: float = _positive(1.0)  # for "bounded": from the nearest target
    samples: int = _check(lambda v: v >= 1, "an integer >= 1", 2000)  # for "random"
    ik_candidates: int = _check(lambda v: 1 <= v <= 1000, "an integer 1 to 1000", 40)
    robot_separation_m: float = _nonnegative(0.5)  # between chosen camera positions
    clearance_m: float = _nonnegative(0.03)  # robot geometry to anything else, after IK
    camera_z_m: tuple[float, float] = (0.3, 1.6)  # heights the camera may be placed at
    # Cameras go within this horizontal distance of where the robot's base stands (its
    # arm's reach plus how far it may drive): IK does not plan around obstacles yet.
    reach_m: float = _positive(1.5)


@dataclass(frozen=True)
class MotionConfig(Checked):
    """How the arms and bases move (in physics), and how imperfectly (sec. 2.4).

    The errors are standard deviations; zero is a perfect robot. Joint offsets are drawn
    once per robot and episode (calibration); joint noise, base errors and the
    suspension tilt are drawn afresh for every move. The planner never sees them.
    """

    speed_scale: float = _check(lambda v: 0 < v <= 1, "a fraction in (0, 1]", 0.5)
    settle_s: float = _nonnegative(2.0)  # held at the goal after the path (s)
    check_every_s: float = _positive(0.02)  # clearance sampled this often (s)
    ik_margin_m: float = _nonnegative(0.02)  # IK keeps this beyond search.clearance_m
    joint_offset_deg: float = _nonnegative(0.0)
    joint_noise_deg: float = _nonnegative(0.0)
    base_offset_m: float = _nonnegative(0.0)  # x and y each
    base_yaw_deg: float = _nonnegative(0.0)
    suspension_deg: float = _nonnegative(0.0)  # base roll and pitch each


@dataclass(frozen=True)
class CorrectionConfig(Checked):
    """Correcting each camera's pose from natural fiducials after it moves (sec. 2.4):
    stereo frames are taken along the move, the fiducials tracked through them, and the
    final pose estimated from the best-rated ones (eq. 8) by ``estimator``."""

    enabled: bool = False
    estimator: Literal["linear", "kabsch", "sqpnp"] = "sqpnp"
    fiducials: int = _check(lambda v: 4 <= v <= 500, "an integer 4 to 500", 24)  # picked
    frame_every_deg: float = _positive(3.0)  # a frame when the commanded camera turned
    frame_every_m: float = _positive(0.03)  # ... or moved this much since the last
    features: int = _check(lambda v: 50 <= v <= 5000, "an integer 50 to 5000", 800)
    search_px: float = _positive(30.0)  # around a fiducial's predicted pixel
    pixel_sigma: float = _positive(0.3)  # of a keypoint's position (px)


@dataclass(frozen=True)
class TaskConfig(Checked):
    """The visually guided insertion (sec. 3): the panel is carried open-loop to a point
    ``approach_m`` above its slot (arriving ``carry_error_m`` off, std per axis), then
    steered by the placed cameras' measurements, step by step, until it stops."""

    enabled: bool = False
    # success tolerances, fractions of the panel's size; any order, distinct as the
    # records name them (6 significant digits)
    tolerances: tuple[float, ...] = _check(
        lambda v: len(v) >= 1 and all(0 < t <= 1 for t in v)
        and len({f"{t:g}" for t in v}) == len(v),
        "a non-empty list of distinct fractions in (0, 1]", (0.2, 0.1, 0.01))
    approach_m: float = _positive(0.15)
    carry_error_m: float = _nonnegative(0.03)
    step_noise_m: float = _nonnegative(0.001)  # std per axis of each step's execution
    step_scale: float = _nonnegative(0.05)  # std of each step's relative gain error
    gain: float = _check(lambda v: 0 < v <= 1, "a fraction in (0, 1]", 0.8)
    max_step_m: float = _positive(0.03)
    max_steps: int = _check(lambda v: 1 <= v <= 500, "an integer 1 to 500", 40)
    stop_m: float = _positive(0.001)  # stop when the measured displacement is below this
    lost_limit: int = _check(lambda v: 1 <= v <= 100, "an integer 1 to 100", 3)
    replace: bool = True  # re-place a camera that lost the panel lost_limit times running
    # pixels matched around the panel: at most the blurred margin (sim/stages/task.py)
    stereo_margin_px: int = _check(lambda v: 8 <= v <= 48, "an integer 8 to 48", 48)


@dataclass(frozen=True)
class Scenario(Checked):
    # names the run directory: runs/<name>-seed<N>
    name: str = _check(lambda v: 0 < len(v) <= 100 and v.isprintable() and not set(v) & set("/\\"),
                       "1 to 100 printable characters but / and \\", "default")
    seed: int = _check(lambda v: v >= 0, "an integer >= 0", 0)
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


# ---------------------------------------------------------------- parsing


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            inner = args[0]
            if dataclasses.is_dataclass(inner):
                return f"a list of tables ({', '.join(f.name for f in dataclasses.fields(inner))})"
            return f"a list of {_type_name(inner)}s"
        return f"a list of {len(args)} {_type_name(args[0])}s"
    if dataclasses.is_dataclass(tp):
        return f"a table with keys {', '.join(f.name for f in dataclasses.fields(tp))}"
    return {float: "number", int: "integer", bool: "boolean", str: "string"}.get(tp, str(tp))


def _convert(tp: Any, value: Any, key: str, source: str) -> Any:
    def bad() -> ScenarioError:
        return ScenarioError(source, key, value, _type_name(tp))

    origin = typing.get_origin(tp)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise bad()
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list):
            raise bad()
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]", source) for i, v in enumerate(value))
        if len(value) != len(args):
            raise bad()
        try:
            return tuple(_convert(a, v, key, source) for a, v in zip(args, value, strict=True))
        except ScenarioError:
            raise bad() from None  # the whole list, with what it should be
    if origin in (types.UnionType, typing.Union):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(inner) != 1:
            raise TypeError(f"unsupported field type {tp}")
        return _convert(inner[0], value, key, source)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise bad()
        return _build(typing.cast(type, tp), value, key, source)
    if tp is float:
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not number or not math.isfinite(value):
            raise bad()
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad()
        return value
    if tp is bool or tp is str:
        if not isinstance(value, tp):
            raise bad()
        return value
    raise TypeError(f"unsupported field type {tp}")


def _build(cls: type, table: Mapping[str, Any], prefix: str, source: str) -> Any:
    """An instance of the dataclass ``cls`` from ``table`` (at key ``prefix`` of the file
    ``source``): unknown keys, missing required ones, wrong types and failed checks raise
    ScenarioError naming the key in full."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.name != "source"}
    for key in table:
        if key not in fields:
            name = f"{prefix}.{key}" if prefix else key
            raise ScenarioError(source, name, table[key], "keys " + ", ".join(fields),
                                problem="unknown key, with value")
    kwargs = {"source": source} if "source" in {f.name for f in dataclasses.fields(cls)} else {}
    for name, f in fields.items():
        key = f"{prefix}.{name}" if prefix else name
        if name not in table:
            if f.metadata.get("required") or (f.default is dataclasses.MISSING
                                              and f.default_factory is dataclasses.MISSING):
                raise ScenarioError(source, key, MISSING,
                                    f"{_type_name(hints[name])} (required)", problem="missing")
            continue
        kwargs[name] = _convert(hints[name], table[name], key, source)
    try:
        return cls(**kwargs)  # the fields' checks and cross-checks (Checked)
    except ScenarioError as exc:
        raise exc.within(source, prefix, table) from None


def _validate(s: Scenario) -> None:
    src = s.source
    if s.camera.near_m >= s.camera.far_m:
        raise ScenarioError(src, "camera.near_m", s.camera.near_m,
                            f"less than camera.far_m ({s.camera.far_m})")
    if s.robots.bases and len(s.robots.bases) != s.robots.count:
        raise ScenarioError(src, "robots.bases", len(s.robots.bases),
                            f"exactly robots.count = {s.robots.count} poses, or none")
    g = s.grid
    for axis in range(3):
        if g.bounds_max[axis] - g.bounds_min[axis] < 2 * g.resolution_m:
            raise ScenarioError(src, "grid.bounds_max", list(g.bounds_max),
                                "each bound at least two voxels above grid.bounds_min")
    hit, miss, clamp_min, clamp_max = s.sensor()
    if not clamp_min < miss < 0.5 < hit < clamp_max:
        raise ScenarioError(src, "grid.miss", miss,
                            f"grid.clamp_min < grid.miss < 0.5 < grid.hit < grid.clamp_max "
                            f"(here {clamp_min}, {miss}, {hit}, {clamp_max})")
    if s.search.camera_z_m[0] >= s.search.camera_z_m[1]:
        raise ScenarioError(src, "search.camera_z_m", list(s.search.camera_z_m),
                            "[low, high] with low < high")
    targets = s.workpiece.targets
    primaries = [t for t in targets if t.role == "primary"]
    if len(primaries) != 1:
        raise ScenarioError(src, "workpiece.targets", [t.name for t in targets],
                            "exactly one target with role 'primary'")
    names = [t.name for t in targets]
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise ScenarioError(src, f"workpiece.targets[{i}].name", name, "a unique name")
    for i, o in enumerate(s.obstacles):
        if len(o.size) != OBSTACLE_SIZES[o.shape]:
            raise ScenarioError(src, f"obstacles[{i}].size", list(o.size),
                                f"{OBSTACLE_SIZES[o.shape]} numbers for a {o.shape}")


def parse_scenario(data: Mapping[str, Any], source: str = "<string>") -> Scenario:
    """Build and validate a Scenario from a parsed TOML table."""
    return typing.cast(Scenario, _build(Scenario, data, "", source))


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file's table; ScenarioError if it cannot be read, is not UTF-8 text, or is
    not TOML."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(str(path), "<file>", str(path),
                            f"a readable TOML file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        found = f"byte 0x{raw[exc.start]:02x} at offset {exc.start}"
        raise ScenarioError(str(path), "<file>", found, "a TOML file in UTF-8",
                            problem="not UTF-8 text:") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), "<syntax>", str(exc), "valid TOML") from None


def load_scenario(path: str | Path | None = None, seed: int | None = None) -> Scenario:
    """Read a scenario file (the default one when ``path`` is None)."""
    path = Path(path) if path is not None else DEFAULT_SCENARIO
    data = read_toml(path)
    data.setdefault("name", path.stem)
    scenario = parse_scenario(data, str(path))
    if seed is not None:
        if seed < 0:
            raise ScenarioError("--seed", "seed", seed, "an integer >= 0")
        scenario = dataclasses.replace(scenario, seed=seed)
    return scenario
