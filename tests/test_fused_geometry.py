"""bench/analyses/fused_geometry.py: what the stereo geometry allows the task's fused
displacement, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.analyses.fused_geometry import fused_p95, steps, view_covariance

F, B = 416.0, 0.12


def test_a_view_is_lateral_across_its_sight_line_and_axial_along_it_by_hand():
    """From 1 m straight above: sqrt(2) z / f 0.1 px across (x, y), sqrt(2) z^2 / (f b)
    0.1 px along (z). Two views at right angles fuse, on the axis both see across, to
    the lateral sd over sqrt(2); on each one's depth axis, its axial sd with the other's
    lateral, by inverse variance."""
    slot = np.zeros(3)
    lateral, axial = math.sqrt(2) / F * 0.1, math.sqrt(2) / (F * B) * 0.1
    above = view_covariance(np.array([0.0, 0.0, 1.0]), slot, F, B)
    assert np.allclose(np.diag(above), [lateral ** 2, lateral ** 2, axial ** 2])
    side = view_covariance(np.array([1.0, 0.0, 0.0]), slot, F, B)
    assert np.allclose(np.diag(side), [axial ** 2, lateral ** 2, lateral ** 2])
    both = fused_p95([above, side])
    assert both is not None
    combined = 1 / math.sqrt(1 / lateral ** 2 + 1 / axial ** 2)  # x: lateral above, axial aside
    assert both == pytest.approx(1.96 * np.array([combined, lateral / math.sqrt(2), combined]))
    assert fused_p95([]) is None


def test_each_step_counts_the_cameras_that_fitted_the_slot_where_they_stood():
    """A summary by hand: r2 moved before step 1; at step 0 only r1 fitted the slot
    (r2 measured through a secondary target), at step 1 both."""
    def placement(step, position):
        return {"step": step, "pose": {"position": position}}

    summary = {
        "target_frame": {"targets": {"slot": {"position": [0.0, 0.0, 0.0]}}},
        "robots": [{"name": "r1", "placements": [placement(None, [0.0, 0.0, 1.0])]},
                   {"name": "r2", "placements": [placement(None, [0.0, 2.0, 0.0]),
                                                 placement(0, [1.0, 0.0, 0.0])]}],
        "task": {"measurements_log": [
            {"step": 0, "true_displacement": [0.0, 0.0, 0.01],
             "fused": {"displacement": [0.001, 0.0, 0.01]},
             "cameras": {"r1": {"edges": {"slot": 300}}, "r2": {"edges": {"slot": 0},
                                                              "via": "secondary"}}},
            {"step": 1, "true_displacement": [0.0, 0.0, 0.0],
             "fused": {"displacement": [0.0, -0.0005, 0.0]},
             "cameras": {"r1": {"edges": {"slot": 300}}, "r2": {"edges": {"slot": 120}}}},
            {"step": 2, "true_displacement": [0.0, 0.0, 0.0], "cameras": {}}]}}
    rows = steps(summary, F, B)
    assert len(rows) == 2  # the step without a fused displacement is not counted
    alone = fused_p95([view_covariance(np.array([0.0, 0.0, 1.0]), np.zeros(3), F, B)])
    assert np.allclose(rows[0]["fitted"], alone)
    every = fused_p95([view_covariance(np.array([0.0, 0.0, 1.0]), np.zeros(3), F, B),
                       view_covariance(np.array([0.0, 2.0, 0.0]), np.zeros(3), F, B)])
    assert np.allclose(rows[0]["every"], every)  # r2 stood at its first place at step 0
    both = fused_p95([view_covariance(np.array([0.0, 0.0, 1.0]), np.zeros(3), F, B),
                      view_covariance(np.array([1.0, 0.0, 0.0]), np.zeros(3), F, B)])
    assert np.allclose(rows[1]["fitted"], both)
    assert np.allclose(rows[0]["measured"], [0.001, 0.0, 0.0])
    assert rows[0]["true_m"] == pytest.approx(0.01)
