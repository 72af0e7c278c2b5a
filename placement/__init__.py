"""Camera placement: the rating function (eq. 1-4), visibility and search. Free of MuJoCo."""

from .rating import (
    CameraModel,
    Ratings,
    TargetModel,
    Weights,
    angular_visibility,
    depth_of_field,
    rate,
    resolution,
)
from .search import RatingField, Region, candidates, search, target_points
from .visibility import line_of_sight

__all__ = [
    "CameraModel",
    "RatingField",
    "Ratings",
    "Region",
    "TargetModel",
    "Weights",
    "angular_visibility",
    "candidates",
    "depth_of_field",
    "line_of_sight",
    "rate",
    "resolution",
    "search",
    "target_points",
]
