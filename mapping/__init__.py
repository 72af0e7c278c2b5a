"""Occupancy mapping: voxel grid, sensor model, depth integration. Free of MuJoCo."""

from .camera import MUJOCO_TO_OPENCV, Pinhole, camera_to_world, opencv_pose, world_to_camera
from .grid import OccupancyGrid, SensorModel, logit
from .integrate import integrate_depth
from .raycast import clip_to_box, first_hits, traverse

__all__ = [
    "MUJOCO_TO_OPENCV",
    "OccupancyGrid",
    "Pinhole",
    "SensorModel",
    "camera_to_world",
    "clip_to_box",
    "first_hits",
    "integrate_depth",
    "logit",
    "opencv_pose",
    "traverse",
    "world_to_camera",
]
