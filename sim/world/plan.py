"""A planned move: the goal configuration and the joint path there, or why there is none,
with what planning cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taskcam.sim.world.ik import IKResult


@dataclass(frozen=True)
class Plan:
    """A goal configuration and the joint path there, or why there is none: ``reason``
    is None (it may be taken), "no place to stand" (no clear place the base gets to
    from which the arm reaches the pose), "no goal configuration" (no IK solution that
    keeps the clearance), "no path within the budget" or "no path within the drive"
    (the path found drives the base farther than the planner's limit)."""

    ik: IKResult | None  # the goal's IK solution (or the best attempt; None: none tried)
    reason: str | None
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))  # (k, 9) joints
    checks: int = 0  # validity checks spent
    seconds: float = 0.0  # wall clock of goal and path

    def summary(self) -> dict[str, Any]:
        """The path's waypoints, base and arm lengths, and what planning cost."""
        out: dict[str, Any] = {"reason": self.reason, "validity_checks": self.checks,
                               "time_s": round(self.seconds, 4)}
        if len(self.path):
            steps = np.diff(self.path, axis=0)
            out |= {"waypoints": len(self.path),
                    "base_path_m": round(float(np.linalg.norm(steps[:, :2], axis=1).sum()), 4),
                    "base_turn_rad": round(float(np.abs(steps[:, 2]).sum()), 4),
                    "arm_path_rad": round(float(np.linalg.norm(steps[:, 3:], axis=1).sum()), 4)}
        return out
