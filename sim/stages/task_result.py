"""What the insertion task works with and what it ends with: the placed cameras as the
task knows them, and the task's outcome (``summary.json``'s ``task``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taskcam.sim.world.scene import Robot

TRUSTED = ("corrected", "as commanded")  # pose statuses measured with at full weight


@dataclass(frozen=True)
class Camera:
    """A placed camera: its robot, believed pose (4x4, MuJoCo camera convention), that
    pose's uncertainty (m, at a metre; its rotation's alone, rad per axis) and status
    (``corrected``, ``uncertain``, ``failed``: not corrected, or ``as commanded`` with
    correction off)."""

    robot: Robot
    believed: np.ndarray
    pose_sd_m: float = 0.0
    pose_status: str = "as commanded"
    rotation_sd_rad: float = 0.0

    @property
    def trusted(self) -> bool:
        return self.pose_status in TRUSTED


@dataclass(frozen=True)
class TaskResult:
    """What happened; ``summary()`` is ``summary.json``'s ``task``."""

    size_m: float
    tolerances: tuple[float, ...]
    attempted: bool = True  # False: no slot to guide to (the target was not located)
    frame_robots: list[str] = field(default_factory=list)  # whose sightings placed the slot
    cameras: list[dict[str, Any]] = field(default_factory=list)  # robot, pose status, sd
    final_displacement: np.ndarray | None = None  # true, panel minus slot (m)
    measured_displacement: np.ndarray | None = None  # the last measurement's
    steps: int = 0
    measurements: int = 0
    failed: list[dict[str, Any]] = field(default_factory=list)  # step, reason per camera
    lost_views: int = 0
    replacements: list[dict[str, Any]] = field(default_factory=list)
    stopped_by: str = ""
    voxels_freed: int = 0
    voxels_occupied: int = 0
    measurement: str = "relative"  # how the displacement was measured (TaskConfig)
    # per step: each camera's displacement (world, m) and its sd, or why it measured
    # nothing; the fused displacement with its covariance (m^2)
    log: list[dict[str, Any]] = field(default_factory=list)
    lying: dict[str, Any] = field(default_factory=dict)  # where the panel was perceived lying

    def success(self) -> dict[str, bool]:
        """Per tolerance (a fraction of the panel's size): whether the true final
        displacement is within it."""
        error = (np.inf if self.final_displacement is None or not self.attempted
                 else float(np.linalg.norm(self.final_displacement)))
        return {f"{t:g}": error <= t * self.size_m for t in self.tolerances}

    def summary(self) -> dict[str, Any]:
        final, measured = self.final_displacement, self.measured_displacement

        def norm(v: np.ndarray | None) -> float | None:
            return None if v is None else round(float(np.linalg.norm(v)), 6)

        return {
            "attempted": self.attempted,
            "target_frame": {"measured": bool(self.frame_robots), "robots": self.frame_robots},
            "cameras": self.cameras,
            "object_size_m": self.size_m,
            "final_displacement": None if final is None else final.round(5).tolist(),
            "final_displacement_m": norm(final), "measured_displacement_m": norm(measured),
            "success": self.success(), "steps": self.steps,
            "measurements": self.measurements, "failed_measurements": len(self.failed),
            "lost_views": self.lost_views, "replacements": self.replacements,
            "stopped_by": self.stopped_by, "failures": self.failed[:10],
            "measurement": self.measurement, "measurements_log": self.log,
            "lying": self.lying,
            "map_update": {"voxels_freed": self.voxels_freed,
                           "voxels_occupied": self.voxels_occupied}}
