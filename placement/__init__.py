"""Camera placement: the rating function (eq. 1-4), visibility and search. Free of MuJoCo."""

from .detectability import DetectorLimits, detectable
from .errors import PlacementError
from .methods import (
    METHODS,
    Method,
    MethodInput,
    MethodSettings,
    method_label,
    method_named,
    method_problem,
    travel_weighed,
)
from .next_best_view import information_gain, look_at
from .occluders import Hull, above_plane, expand, expanded_hulls, grid_occluders, target_outline
from .random_views import biased_random, first_within_angle, informed_random
from .rating import (
    CameraModel,
    Ratings,
    TargetModel,
    Weights,
    angular_visibility,
    depth_of_field,
    rate,
    rate_aimed,
    rate_best,
    resolution,
)
from .search import (
    RatingField,
    Region,
    SearchSettings,
    candidates,
    rate_positions,
    region_voxels,
    search,
    target_points,
)
from .tfv import ClearanceMap, clearance_map, distance_level, hull_depths, tfv_at
from .visibility import line_of_sight

__all__ = [
    "METHODS",
    "CameraModel",
    "ClearanceMap",
    "DetectorLimits",
    "Hull",
    "Method",
    "MethodInput",
    "MethodSettings",
    "PlacementError",
    "RatingField",
    "Ratings",
    "Region",
    "SearchSettings",
    "TargetModel",
    "Weights",
    "above_plane",
    "angular_visibility",
    "biased_random",
    "candidates",
    "clearance_map",
    "depth_of_field",
    "detectable",
    "distance_level",
    "expand",
    "expanded_hulls",
    "first_within_angle",
    "grid_occluders",
    "hull_depths",
    "information_gain",
    "informed_random",
    "line_of_sight",
    "look_at",
    "method_label",
    "method_named",
    "method_problem",
    "rate",
    "rate_aimed",
    "rate_best",
    "rate_positions",
    "region_voxels",
    "resolution",
    "search",
    "target_outline",
    "target_points",
    "tfv_at",
    "travel_weighed",
]
