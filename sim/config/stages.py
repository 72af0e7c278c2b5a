"""How each stage of an episode works, as a scenario sets it: the occupancy grid and
mapping, the rating function and the placement search, the arms' and bases' motion,
the pose correction and the insertion task.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from taskcam.sim.config.schema import (
    Checked,
    ScenarioError,
    checked,
    nonnegative,
    positive,
    probability,
)

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

    resolution_m: float = checked(lambda v: 0.005 <= v <= 0.5, "metres in [0.005, 0.5]", 0.05)
    bounds_min: tuple[float, float, float] = (-1.5, -1.5, 0.0)
    bounds_max: tuple[float, float, float] = (1.5, 1.5, 1.8)
    hit: float | None = probability(None)
    miss: float | None = probability(None)
    clamp_min: float | None = probability(None)
    clamp_max: float | None = probability(None)
    max_range_m: float = positive(4.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        for axis in range(3):
            if self.bounds_max[axis] - self.bounds_min[axis] < 2 * self.resolution_m:
                raise ScenarioError(self.source_name(), "bounds_max", self.bounds_max,
                                    "each bound at least two voxels above bounds_min")


ViewStrategy = Literal["cooperative", "single", "random"]  # who chooses the next view
ViewGain = Literal["entropy", "unobserved", "rear_side"]  # what a view is expected to gain


@dataclass(frozen=True)
class MappingConfig(Checked):
    """Cooperative mapping: views chosen by expected information, then rendered."""

    depth_source: Literal["render", "stereo"] = "render"
    strategy: ViewStrategy = "cooperative"
    gain: ViewGain = "entropy"
    max_views: int = checked(lambda v: 1 <= v <= 200, "an integer 1 to 200", 12)  # all robots
    entropy_threshold_bits: float = checked(lambda v: 0 <= v <= 1, "bits in [0, 1]", 0.12)
    region_half_m: tuple[float, float, float] = (0.8, 0.8, 0.6)  # around the primary target
    candidates_per_robot: int = checked(lambda v: 1 <= v <= 500, "an integer 1 to 500", 24)
    gain_stride: int = checked(lambda v: 1 <= v <= 64, "an integer 1 to 64", 16)
    pixel_stride: int = checked(lambda v: 1 <= v <= 16, "an integer 1 to 16", 2)
    motion_weight: float = nonnegative(0.0)  # rate views by gain / (1 + w * metres moved)
    # P(occupied) assumed for never-observed voxels that a gain's ray passes (most space
    # is empty); 0.5 is the map's own value for them
    unknown_occupancy: float = probability(0.05)


@dataclass(frozen=True)
class RatingConfig(Checked):
    """Rating function exponents (eq. 1) and occupancy thresholds."""

    alpha: float = nonnegative(1.0)  # depth of field
    beta: float = nonnegative(1.0)  # resolution
    gamma: float = nonnegative(1.0)  # target field visibility
    delta: float = nonnegative(1.0)  # target angular visibility
    # Weigh the rating by exp(-travel_per_m x how far the base must drive to the
    # candidate: its horizontal distance from the base beyond the arm's reach, m); 0 is
    # off, as in the paper, whose rating has no cost of moving
    travel_per_m: float = nonnegative(0.0)
    free_threshold: float = probability(0.05)  # candidate voxels: P below this
    unknown_occludes: bool = True  # never-observed voxels count as occluders for TFV
    hull_block: int = checked(lambda v: 1 <= v <= 64, "an integer 1 to 64", 4)  # voxels
    # occluder expansion by the target: "cone" exact for the camera's distance, "paper"
    # the whole target everywhere (conservative near the camera)
    expansion: Literal["cone", "paper"] = "cone"
    # directions of the sphere around a target TFV is computed on (spacing about
    # sqrt(4 pi / n) rad: 1.6 deg at 16384); time grows with them
    tfv_directions: int = checked(lambda v: 1024 <= v <= 65536, "an integer 1024 to 65536",
                                 16384)


def check_placement_method(config: Checked, key: str, name: str) -> None:
    """ScenarioError (at ``key`` of ``config``) unless ``name`` names a placement method:
    a registered one, or a ``module:callable`` this process imports."""
    from taskcam.placement.methods import ACCEPTED, method_problem  # here: the config imports light

    problem = method_problem(name)
    if problem is not None:
        raise ScenarioError(config.source_name(), key, name, f"{ACCEPTED}; {problem}")


@dataclass(frozen=True)
class SearchConfig(Checked):
    RETIRED: ClassVar[dict[str, str]] = {
        "reach_m": "bases drive along planned paths: search.drive_path_m (how far a base may "
                   "drive to a view, m, along its path)",
        "drive_m": "a base's drive is measured along its path now: search.drive_path_m (how "
                   "far a base may drive to a view, m, along its path; default 6)",
        "random_max_angle_deg": "split by method: informed_max_angle_deg (informed_random, "
                                "the biased random of earlier versions) and "
                                "biased_random_max_angle_deg (the paper's biased random)"}

    # the placement method, by its registered name (placement/methods.py: "rating",
    # "biased_random", "informed_random", "information_gain") or a user's own as
    # "module:callable"
    method: str = "rating"
    # biased_random: the largest angle between a target's normal and the direction from
    # it to the camera (degrees; the paper's bounded target angular view)
    biased_random_max_angle_deg: float = checked(lambda v: 0 < v <= 90, "degrees in (0, 90]",
                                                 60.0)
    # informed_random: the same bound over the rating function's candidates
    informed_max_angle_deg: float = checked(lambda v: 0 < v <= 90, "degrees in (0, 90]", 60.0)
    gain_samples: int = checked(lambda v: v >= 1, "an integer >= 1", 300)  # information_gain
    # reject a candidate when the nominal scene's geometry hides its target (an oracle:
    # off, each method knows only what its own model tells it)
    check_sight: bool = True
    strategy: Literal["exhaustive", "coarse", "bounded", "random"] = "exhaustive"
    coarse_step: int = checked(lambda v: 1 <= v <= 16, "an integer 1 to 16", 2)
    max_distance_m: float = positive(1.0)  # for "bounded": from the nearest target
    samples: int = checked(lambda v: v >= 1, "an integer >= 1", 2000)  # for "random"
    ik_candidates: int = checked(lambda v: 1 <= v <= 1000, "an integer 1 to 1000", 40)
    robot_separation_m: float = nonnegative(0.5)  # between chosen camera positions
    clearance_m: float = nonnegative(0.03)  # robot geometry to anything else, after IK
    camera_z_m: tuple[float, float] = (0.3, 1.6)  # heights the camera may be placed at
    # How far a robot's base may drive to a view (m, along its path over the floor it
    # knows clear): by default it may cross the room it has mapped, the default grid's 3 m
    # square walked round half its edge; its camera goes wherever the arm reaches from there
    drive_path_m: float = nonnegative(6.0)
    # The path search's budget per candidate, in validity checks (each a MuJoCo distance
    # query of the robot's pose, about 0.1 ms: 2 s at most): a count, not seconds, so
    # that the same seed plans the same path on any machine
    planning_checks: int = checked(lambda v: 100 <= v <= 1_000_000, "an integer 100 to 1000000",
                                   20000)
    # What the planner knows of the clutter (the obstacles wholly inside the map's grid):
    # "map", what the robots mapped, space they never observed taken as blocked (the
    # cameras' voxels for the arm, the bases' scans of the floor for the base); "map_seen",
    # only what they saw occupied (the unobserved taken as free: optimistic); "model", the
    # scene exactly (an oracle, as check_sight is)
    planner_world: Literal["map", "map_seen", "model"] = "map"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_placement_method(self, "method", self.method)
        if self.camera_z_m[0] >= self.camera_z_m[1]:
            raise ScenarioError(self.source_name(), "camera_z_m", self.camera_z_m,
                                "[low, high] with low < high")


@dataclass(frozen=True)
class MotionConfig(Checked):
    """How the arms and bases move (in physics), and how imperfectly (sec. 2.4).

    The errors are standard deviations; zero is a perfect robot. Joint offsets are drawn
    once per robot and episode (calibration); joint noise, base errors and the
    suspension tilt are drawn afresh for every move. The planner never sees them.
    """

    speed_scale: float = checked(lambda v: 0 < v <= 1, "a fraction in (0, 1]", 0.5)
    settle_s: float = nonnegative(2.0)  # held at the goal after the path (s)
    check_every_s: float = positive(0.02)  # clearance sampled this often (s)
    ik_margin_m: float = nonnegative(0.02)  # IK keeps this beyond search.clearance_m
    joint_offset_deg: float = nonnegative(0.0)
    joint_noise_deg: float = nonnegative(0.0)
    base_offset_m: float = nonnegative(0.0)  # x and y each
    base_yaw_deg: float = nonnegative(0.0)
    suspension_deg: float = nonnegative(0.0)  # base roll and pitch each


@dataclass(frozen=True)
class CorrectionConfig(Checked):
    """Correcting each camera's pose from natural fiducials after it moves (sec. 2.4):
    stereo frames are taken along the move, the fiducials tracked through them, and the
    final pose estimated from the best-rated ones (eq. 8) by ``estimator``. With
    ``frames = "overlap"`` a frame is taken when fewer than ``frame_overlap`` of the last
    located frame's fiducials are predicted findable, and at every fixed step while the
    view shares that much with the goal's; with ``"track"`` only when the overlap
    falls (the track's frames alone, kept for comparison); with ``"fixed"`` whenever the
    camera turned ``frame_every_deg`` or moved ``frame_every_m``. A keypoint's right
    pixel is found by ``stereo``: "correlation" along its row, "descriptors" matched
    to the right image's keypoints, or "flow" (optical flow from the left image).
    ``frames = "fixed"`` is the first tracker's rule, kept for comparison."""

    enabled: bool = False
    estimator: Literal["linear", "kabsch", "sqpnp"] = "sqpnp"
    fiducials: int = checked(lambda v: 4 <= v <= 500, "an integer 4 to 500", 24)  # picked
    detector: Literal["sift", "orb"] = "sift"
    stereo: Literal["correlation", "descriptors", "flow"] = "descriptors"
    frames: Literal["overlap", "track", "fixed"] = "overlap"
    frame_overlap: float = checked(lambda v: 0 < v < 1, "a number between 0 and 1", 0.5)
    frame_every_deg: float = positive(3.0)  # a frame when the commanded camera turned
    frame_every_m: float = positive(0.03)  # ... or moved this much since the last
    features: int = checked(lambda v: 50 <= v <= 5000, "an integer 50 to 5000", 800)
    search_px: float = positive(30.0)  # around a fiducial's predicted pixel
    pixel_sigma: float = positive(0.3)  # of a keypoint's position (px)


@dataclass(frozen=True)
class TaskConfig(Checked):
    """The visually guided insertion (sec. 3): the panel is carried open-loop to a point
    ``approach_m`` above its slot (arriving ``carry_error_m`` off, std per axis), then
    steered by the placed cameras' measurements, step by step, until it stops."""

    RETIRED: ClassVar[dict[str, str]] = {
        "stop_m": "the task stops on confidence: task.stop_share (a fraction of the tightest "
                  "tolerance) and task.stop_sigmas"}

    enabled: bool = False
    # success tolerances, fractions of the panel's size; any order, distinct as the
    # records name them (6 significant digits)
    tolerances: tuple[float, ...] = checked(
        lambda v: len(v) >= 1 and all(0 < t <= 1 for t in v)
        and len({f"{t:g}" for t in v}) == len(v),
        "a non-empty list of distinct fractions in (0, 1]", (0.2, 0.1, 0.01))
    approach_m: float = positive(0.15)
    carry_error_m: float = nonnegative(0.03)
    step_noise_m: float = nonnegative(0.001)  # std per axis of each step's execution
    step_scale: float = nonnegative(0.05)  # std of each step's relative gain error
    gain: float = checked(lambda v: 0 < v <= 1, "a fraction in (0, 1]", 0.8)
    max_step_m: float = positive(0.03)
    max_steps: int = checked(lambda v: 1 <= v <= 500, "an integer 1 to 500", 40)
    # "relative": panel minus slot fitted to edges in each camera's own images;
    # "absolute": the panel from stereo points and the slot from the holes' frame
    measurement: Literal["relative", "absolute"] = "relative"
    # stop when the fused displacement is within stop_share of the tightest tolerance and
    # its bound at stop_sigmas standard deviations within the tolerance itself, or
    # stopping there is likelier to end within it than one more (erring) step
    stop_share: float = checked(lambda v: 0 < v <= 1, "a fraction in (0, 1]", 0.5)
    stop_sigmas: float = nonnegative(2.0)
    lost_limit: int = checked(lambda v: 1 <= v <= 100, "an integer 1 to 100", 3)
    replace: bool = True  # re-place a camera that lost the panel lost_limit times running
    # pixels matched around the panel: at most the blurred margin (sim/stages/task.py)
    stereo_margin_px: int = checked(lambda v: 8 <= v <= 48, "an integer 8 to 48", 48)
