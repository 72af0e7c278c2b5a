"""Where a target is in the work cell: a circular hole, or a slot found by the walls
beside it (m, world frame); the geometry every package shares about it. Free of MuJoCo."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def circle_in_plane(normal: np.ndarray, radius: float, count: int) -> np.ndarray:
    """``count`` offsets (count, 3) evenly on a circle of ``radius`` about ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    a = np.linspace(0, 2 * np.pi, count, endpoint=False)
    return radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)


@dataclass(frozen=True)
class Target:
    """A circular-hole target in the world frame (m); or, with ``half_length`` > 0, a
    slot: ``half_length`` either side along ``axis`` and ``radius`` across."""

    name: str
    role: str  # "primary" or "secondary"
    geom: str  # geom name in the simulated world's model
    position: np.ndarray  # centre of the hole's visible face
    normal: np.ndarray  # unit, pointing out of the plate
    radius: float
    st_error: float
    half_length: float = 0.0
    axis: np.ndarray | None = None
    # a slot is found by the walls beside it: half their width (m), when wider than it
    detect_radius: float = 0.0
    # the rating sees it this far (m) along its normal: a slot's site over the voxels its
    # walls' tops are mapped into (``position`` is the slot's own point, between their feet)
    lift: float = 0.0

    def rim(self, count: int = 8, scale: float = 1.0) -> np.ndarray:
        """``count`` points on the rim circle (scaled by ``scale``), shape (count, 3)."""
        return self.position + circle_in_plane(self.normal, scale * self.radius, count)

    def summary(self) -> dict[str, object]:
        out: dict[str, object] = {"name": self.name, "role": self.role,
                                  "position": self.position.tolist(),
                                  "normal": self.normal.tolist(), "radius": self.radius}
        if self.half_length > 0 and self.axis is not None:  # a slot
            out |= {"half_length": self.half_length, "axis": np.asarray(self.axis).tolist(),
                    "lift": self.lift}
        return out
