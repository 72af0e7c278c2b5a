"""Occupancy mapping: voxel grid, sensor model, depth integration. Free of MuJoCo."""

from .cad import BoxModel, fit_model, move_object, occupancy_of, pose_covariance, voxels_of
from .cad_prior import LyingPose, Misplacement, fit_lying_pose, lying_pose, support_layer
from .camera import (
    MUJOCO_TO_OPENCV,
    Pinhole,
    camera_to_world,
    mujoco_pose,
    opencv_pose,
    world_to_camera,
)
from .errors import MappingError
from .floor_map import FloorMap, drive_lengths, ray_directions
from .grid import LOG_ODDS_SCALE, OccupancyGrid, SensorModel, logit, stored_log_odds
from .integrate import integrate_depth
from .obstacle_field import ObstacleField
from .raycast import first_hits, mark_free_image, traverse
from .stereo import StereoSettings, stereo_depth
from .targets import Target, circle_in_plane
from .views import GAINS, GainModel, View, mean_entropy, region_mask, view_rays

__all__ = [
    "GAINS",
    "LOG_ODDS_SCALE",
    "MUJOCO_TO_OPENCV",
    "BoxModel",
    "FloorMap",
    "GainModel",
    "LyingPose",
    "MappingError",
    "Misplacement",
    "ObstacleField",
    "OccupancyGrid",
    "Pinhole",
    "SensorModel",
    "StereoSettings",
    "Target",
    "View",
    "camera_to_world",
    "circle_in_plane",
    "drive_lengths",
    "first_hits",
    "fit_lying_pose",
    "fit_model",
    "integrate_depth",
    "logit",
    "lying_pose",
    "mark_free_image",
    "mean_entropy",
    "move_object",
    "mujoco_pose",
    "occupancy_of",
    "opencv_pose",
    "pose_covariance",
    "ray_directions",
    "region_mask",
    "stereo_depth",
    "stored_log_odds",
    "support_layer",
    "traverse",
    "view_rays",
    "voxels_of",
    "world_to_camera",
]
