"""What stands in the work cell, as a scenario sets it: the robots and their stereo
cameras, the work-piece and its target holes, the panel, the obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from taskcam.sim.config.schema import Checked, ScenarioError, checked, nonnegative, positive

MAX_ROBOTS = 4


@dataclass(frozen=True)
class CameraConfig(Checked):
    """The stereo head: every robot's two cameras share these."""

    fovy_deg: float = checked(lambda v: 0 < v < 180, "degrees in (0, 180)", 60.0)
    width: int = checked(lambda v: 16 <= v <= 4096, "pixels in [16, 4096]", 640)
    height: int = checked(lambda v: 16 <= v <= 4096, "pixels in [16, 4096]", 480)
    baseline_m: float = checked(lambda v: 0 < v <= 0.2, "metres in (0, 0.2]", 0.12)
    near_m: float = positive(0.35)  # depth of field, near limit
    far_m: float = positive(1.5)  # depth of field, far limit
    coc_px: float = positive(1.5)  # blur-circle diameter at the depth of field's limits
    # Multisample anti-aliasing, samples per pixel (0: off; rendering about twice as fast).
    samples: int = checked(lambda v: v in (0, 2, 4, 8, 16), "0, 2, 4, 8 or 16", 4)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.near_m >= self.far_m:
            raise ScenarioError(self.source_name(), "near_m", self.near_m,
                                f"less than far_m ({self.far_m})")


@dataclass(frozen=True)
class BasePose(Checked):
    """A mobile base's start pose on the floor."""

    x: float
    y: float
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class RobotsConfig(Checked):
    count: int = checked(lambda v: 1 <= v <= MAX_ROBOTS, f"an integer 1 to {MAX_ROBOTS}", 2)
    # Explicit start poses, one per robot; empty: evenly on a circle facing the work-piece.
    bases: tuple[BasePose, ...] = ()
    start_radius_m: float = positive(1.8)
    move_base: bool = True
    # The arm on each mobile base (sim/world/robot_model.py, docs/robots.md): "taskcam"
    # (the project's UR5e-class arm), "menagerie:NAME" (MuJoCo Menagerie's robot NAME),
    # or an MJCF file's path, relative to the scenario file.
    model: str = checked(lambda v: v == "taskcam" or v.startswith("menagerie:")
                         or v.endswith(".xml"),
                         '"taskcam", "menagerie:NAME" or the path of an MJCF file (.xml)',
                         "taskcam")
    # the arm's site on its last link where the stereo head mounts (+z out of the flange)
    mount: str = "attachment_site"


@dataclass(frozen=True)
class TargetConfig(Checked):
    """A circular hole: in the plate, or on a fixture of its own that the work-piece
    carries elsewhere in the work cell (a post with a small plate on top, rigidly
    mounted, so that the hole keeps its relation to the slot within ``st_error_m``);
    offset in the work-piece's frame from the plate's centre (m)."""

    name: str = checked(lambda v: v.isidentifier(), "a name of letters, digits and _")
    role: Literal["primary", "secondary"] = "primary"
    offset_m: tuple[float, float] = (0.0, 0.0)
    radius_m: float = checked(lambda v: 0.002 <= v <= 0.1, "metres in [0.002, 0.1]", 0.02)
    st_error_m: float = nonnegative(0.0)  # secondary-to-primary geometric tolerance (eq. 4)
    mount: Literal["plate", "fixture"] = "plate"
    # a fixture's top (m above the floor), where its hole is
    height_m: float = checked(lambda v: 0.1 <= v <= 1.5, "metres in [0.1, 1.5]", 0.52)


def _default_targets() -> tuple[TargetConfig, ...]:
    return (
        TargetConfig("wide", "primary", (0.05, 0.0), 0.02),
        TargetConfig("narrow", "secondary", (0.17, 0.1), 0.015, 0.001),
    )


@dataclass(frozen=True)
class WorkpieceConfig(Checked):
    position: tuple[float, float] = (0.0, 0.0)  # floor position of the plate centre (m)
    yaw_deg: float = 0.0
    targets: tuple[TargetConfig, ...] = field(default_factory=_default_targets)
    # Where the work-piece really stands, off where the planner believes (standard
    # deviations, drawn per episode): only the cameras' sightings of the targets reveal it.
    position_error_m: float = nonnegative(0.0)  # x and y each
    yaw_error_deg: float = nonnegative(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        source = self.source_name()
        names = [t.name for t in self.targets]
        if [t.role for t in self.targets].count("primary") != 1:
            raise ScenarioError(source, "targets", names, "exactly one target with role 'primary'")
        for i, name in enumerate(names):
            if names.index(name) != i:
                raise ScenarioError(source, f"targets[{i}].name", name, "a unique name")


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
    size: tuple[float, ...] = checked(
        lambda v: 1 <= len(v) <= 3 and all(s > 0 for s in v), "1 to 3 numbers > 0", (0.1,),
        required=True)
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.size) != OBSTACLE_SIZES[self.shape]:
            raise ScenarioError(self.source_name(), "size", self.size,
                                f"{OBSTACLE_SIZES[self.shape]} numbers for a {self.shape}")
