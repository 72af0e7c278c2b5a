"""Timing a joint path: limits kept, at rest at every waypoint, on the straight segments."""

from __future__ import annotations

import numpy as np
import pytest

from taskcam.sim.world.scene import JOINT_SPEEDS, ROBOT_JOINTS
from taskcam.sim.world.timing import ROBOT_LIMITS, time_path

DT = 0.002  # s, the physics timestep
TOL = 1e-6  # relative, on the limits


def random_path(seed: int, k: int) -> np.ndarray:
    """``k`` waypoints (k, 9): random steps of up to 0.6 m or rad, some joints still.
    The second segment moves base yaw by 1 rad and the arm's joints by 2 rad: yaw limits
    the speed along it and the arm the acceleration (ruckig's phase synchronisation of
    the nine joints leaves the line there)."""
    rng = np.random.default_rng(seed)
    steps = rng.uniform(-0.6, 0.6, (k - 1, 9)) * (rng.uniform(size=(k - 1, 9)) > 0.3)
    steps[min(1, k - 2)] = [0.0, 0.0, 1.0, *[2.0] * 6]
    return np.cumsum(np.vstack([rng.uniform(-1, 1, 9), steps]), axis=0)


CASES = [(seed, k, scale) for seed, k in ((0, 2), (1, 3), (2, 6), (3, 10))
         for scale in (0.3, 1.0)]


@pytest.mark.parametrize(("seed", "k", "scale"), CASES)
def test_every_joint_keeps_its_velocity_acceleration_and_jerk_limits(seed, k, scale):
    trajectory = time_path(random_path(seed, k), ROBOT_LIMITS, scale, DT)
    assert np.allclose(np.diff(trajectory.times), DT)
    v_max = ROBOT_LIMITS.velocity * scale * (1 + TOL)
    a_max, j_max = ROBOT_LIMITS.acceleration * (1 + TOL), ROBOT_LIMITS.jerk * (1 + TOL)
    velocity = np.diff(trajectory.positions, axis=0) / DT  # finite differences
    acceleration = np.diff(velocity, axis=0) / DT
    assert np.all(np.abs(velocity) <= v_max) and np.all(np.abs(acceleration) <= a_max)
    assert np.all(np.abs(trajectory.velocities) <= v_max)
    assert np.all(np.abs(trajectory.accelerations) <= a_max)
    assert np.all(np.abs(np.diff(trajectory.accelerations, axis=0) / DT) <= j_max)
    # the trajectory's own derivatives are its positions' (to the sampling's error)
    assert np.abs(velocity - trajectory.velocities[1:]).max() < j_max.max() * DT


@pytest.mark.parametrize(("seed", "k", "scale"), CASES)
def test_it_rests_at_every_waypoint_and_keeps_to_the_straight_segments(seed, k, scale):
    path = random_path(seed, k)
    trajectory = time_path(path, ROBOT_LIMITS, scale, DT)
    q = trajectory.positions
    assert np.array_equal(q[0], path[0]) and np.allclose(q[-1], path[-1], atol=1e-12)
    for ends in (trajectory.velocities, trajectory.accelerations):
        assert not ends[0].any() and not ends[-1].any()
    # every waypoint is passed, in order, and at rest: its samples barely move
    passes = [int(np.argmin(np.abs(q - w).max(axis=1))) for w in path]
    assert passes[0] == 0 and passes[-1] == len(q) - 1 and np.all(np.diff(passes) > 0)
    for w, i in zip(path, passes, strict=True):
        assert np.abs(q[i] - w).max() < 1e-6
        assert np.abs(trajectory.velocities[i]).max() < 1e-2
    # between two waypoints the joints lie on the segment joining them, going forward
    for a, b, i, j in zip(path[:-1], path[1:], passes[:-1], passes[1:], strict=True):
        share = (q[i:j + 1] - a) @ (b - a) / ((b - a) @ (b - a))
        assert np.abs(q[i:j + 1] - (a + share[:, None] * (b - a))).max() < 1e-9
        assert np.all(np.diff(share) >= -1e-12) and share[0] > -1e-9 and share[-1] < 1 + 1e-9


@pytest.mark.parametrize(("seed", "k", "scale"), CASES)
def test_no_segment_is_faster_than_its_slowest_joint_at_the_speed_limit(seed, k, scale):
    path = random_path(seed, k)
    trajectory = time_path(path, ROBOT_LIMITS, scale, DT)
    bound = (np.abs(np.diff(path, axis=0)) / (ROBOT_LIMITS.velocity * scale)).max(axis=1).sum()
    assert trajectory.duration >= bound
    assert trajectory.duration <= trajectory.times[-1] < trajectory.duration + DT


@pytest.mark.parametrize(("joint", "distance", "scale"),
                         [("base_x", 3.0, 1.0), ("shoulder_pan", 2.0, 0.25),
                          ("base_yaw", -4.0, 0.5)])
def test_a_long_move_of_one_joint_takes_distance_over_speed_plus_the_ramps(
        joint, distance, scale):
    i = ROBOT_JOINTS.index(joint)
    v, a = ROBOT_LIMITS.velocity[i] * scale, ROBOT_LIMITS.acceleration[i]
    j = ROBOT_LIMITS.jerk[i]
    assert v >= a * a / j and abs(distance) >= v * (v / a + a / j)  # both limits reached
    path = np.zeros((2, 9))
    path[1, i] = distance
    trajectory = time_path(path, ROBOT_LIMITS, scale, DT)
    assert trajectory.duration == pytest.approx(abs(distance) / v + v / a + a / j, abs=1e-6)
    assert np.abs(trajectory.velocities[:, i]).max() == pytest.approx(v, rel=1e-9)
    assert np.abs(trajectory.accelerations[:, i]).max() == pytest.approx(a, rel=1e-6)
    assert not np.delete(trajectory.positions, i, axis=1).any()


def test_progress_runs_from_0_to_1_by_distance():
    path = random_path(4, 5)
    trajectory = time_path(path, ROBOT_LIMITS, 0.5, DT)
    p = trajectory.progress
    assert p[0] == 0.0 and p[-1] == 1.0 and np.all(np.diff(p) >= 0)
    lengths = np.linalg.norm(np.diff(path, axis=0) / ROBOT_LIMITS.velocity, axis=1)
    at_waypoint = np.cumsum(lengths) / lengths.sum()
    passes = [int(np.argmin(np.abs(trajectory.positions - w).max(axis=1))) for w in path[1:]]
    assert p[passes] == pytest.approx(at_waypoint, abs=1e-6)


def test_a_path_of_one_place_takes_no_time_and_repeated_waypoints_none_either():
    here = random_path(5, 2)[0]
    still = time_path(here[None], ROBOT_LIMITS, 0.5, DT)
    assert still.duration == 0.0 and still.times.tolist() == [0.0]
    assert np.array_equal(still.positions, here[None]) and not still.velocities.any()
    assert still.progress.tolist() == [1.0]  # nothing left to cover
    path = random_path(5, 3)
    repeated = np.vstack([path[:2], path[1:2], path[2:], path[2:]])
    assert time_path(repeated, ROBOT_LIMITS, 0.5, DT).duration == pytest.approx(
        time_path(path, ROBOT_LIMITS, 0.5, DT).duration, abs=1e-12)


def test_the_speed_limits_are_the_ones_ik_uses():
    assert ROBOT_LIMITS.velocity.tolist() == [JOINT_SPEEDS[j] for j in ROBOT_JOINTS]
    assert ROBOT_LIMITS.velocity[3:] == pytest.approx(np.radians(180))  # UR5e: 180 deg/s
    for limit in (ROBOT_LIMITS.acceleration, ROBOT_LIMITS.jerk):
        assert limit.shape == (9,) and np.all(limit > 0)
