"""Recursive mean and covariance of the camera's translation and rotation (eq. 7).

Eq. 7 updates the mean of X (3) and of every entry of R (3x3) with each new estimate,
and their covariances. Its covariance update subtracts the new mean from both factors;
we use (x - old mean)(x - new mean)ᵀ instead (Welford's form), which makes the recursion
equal the batch (population) covariance exactly rather than approximately.
"""

from __future__ import annotations

import numpy as np


class RunningPose:
    """Mean and covariance of X and of R's entries over the pose estimates so far."""

    def __init__(self) -> None:
        self.count = 0
        self.mean_X = np.zeros(3)
        self.cov_X = np.zeros((3, 3))
        self.mean_R = np.zeros((3, 3))
        self.var_R = np.zeros((3, 3))  # eq. 7's C^R(l, m), entry by entry

    def add(self, R: np.ndarray, X: np.ndarray) -> None:
        """One more estimate: rotation R (3x3) and translation X (3)."""
        i = self.count
        dX = X - self.mean_X
        self.mean_X = self.mean_X + dX / (i + 1)
        self.cov_X = (i * self.cov_X + np.outer(dX, X - self.mean_X)) / (i + 1)
        dR = R - self.mean_R
        self.mean_R = self.mean_R + dR / (i + 1)
        self.var_R = (i * self.var_R + dR * (R - self.mean_R)) / (i + 1)
        self.count = i + 1

    def summary(self) -> dict[str, object]:
        return {"count": self.count, "mean_X": self.mean_X.tolist(),
                "std_X_m": np.sqrt(np.diag(self.cov_X)).tolist(),
                "std_R_max": float(np.sqrt(self.var_R.max()))}
