"""Timing a joint path: jerk-limited, rest-to-rest along every straight segment (ruckig).

The planner checks its joint path (k, 9; ``ROBOT_JOINTS``) for collisions along the
straight joint-space segments between waypoints, so the timed motion keeps to them: it
stops at every waypoint (a corner cannot be turned at speed without leaving the line)
and moves every joint in step along the segment. Each segment is timed as one
coordinate, the share ``s`` (0 to 1) of the segment covered, under the tightest of the
joints' limits divided by their share of the move; that is the time-optimal motion
along the line. Ruckig's own phase synchronisation of the nine joints would be the same
when it succeeds, but it falls back to time synchronisation (off the line) when the
joint limiting the speed is not the one limiting the acceleration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig
from ruckig import Trajectory as RuckigTrajectory

from taskcam.sim.world.scene import JOINT_SPEEDS, ROBOT_JOINTS

MIN_SEGMENT = 1e-12  # a segment whose joints all move less than this (m, rad) is skipped


@dataclass(frozen=True)
class JointLimits:
    """Limits per joint of ``ROBOT_JOINTS`` (9 each): base x, y (m/s, m/s^2, m/s^3),
    base yaw and the arm joints (rad/s, rad/s^2, rad/s^3)."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray


def _per_joint(base_xy: float, base_yaw: float, arm: float) -> np.ndarray:
    return np.array([base_xy, base_xy, base_yaw, *[arm] * 6])


ROBOT_LIMITS = JointLimits(
    # Speeds: JOINT_SPEEDS, also IK's. Arm: the UR5e technical specification's maximum
    # joint speed, 180 deg/s for every joint. Base: a slow indoor mobile base.
    velocity=np.array([JOINT_SPEEDS[j] for j in ROBOT_JOINTS]),
    # Not published as hard limits. Arm: 1.4 rad/s^2, URScript movej's default joint
    # acceleration (the controller's documented default for joint moves). Base:
    # 0.5 m/s^2 (~0.05 g) and 1.0 rad/s^2, gentle as indoor AMRs are, so that a payload
    # such as the tall arm does not tip; yaw reaches its speed in 1 s like x and y.
    acceleration=_per_joint(0.5, 1.0, 1.4),
    # An assumption: the acceleration is reached in 0.14 s (arm, 10 rad/s^3) and in
    # 0.25 s (base, 2 m/s^3 and 4 rad/s^3), smooth ramps such as drives' s-curves give.
    jerk=_per_joint(2.0, 4.0, 10.0),
)


@dataclass(frozen=True)
class Trajectory:
    """A timed joint path sampled every ``dt``: times (n,) s from 0, the joints'
    positions, velocities and accelerations (n, 9; joint units per s^0..2), duration
    (s; the last sample is at or just after it, at rest at the goal), and ``progress``
    (n,): the share of the path covered, 0 to 1, by joint-space distance with every
    joint measured in seconds at its speed limit (1 throughout when there is no path)."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    duration: float
    progress: np.ndarray


def _segment(velocity: float, acceleration: float, jerk: float) -> RuckigTrajectory:
    """Ruckig's rest-to-rest motion of a segment's share covered from 0 to 1 under the
    share's limits (1/s, 1/s^2, 1/s^3)."""
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [1.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [velocity], [acceleration], [jerk]
    out = RuckigTrajectory(1)
    result = Ruckig(1).calculate(inp, out)
    if result != Result.Working:
        raise ValueError(f"ruckig could not time a segment: {result}")
    return out


def time_path(path: np.ndarray, limits: JointLimits, speed_scale: float,
              dt: float) -> Trajectory:
    """The joint path (k, 9) timed rest-to-rest along each straight segment between
    consecutive waypoints, every joint within ``speed_scale`` of its velocity limit and
    within its acceleration and jerk limits, sampled every ``dt`` (s)."""
    path = np.asarray(path, float)
    steps = np.diff(path, axis=0)
    moving = np.abs(steps).max(axis=1, initial=0.0) > MIN_SEGMENT
    starts, deltas = path[:-1][moving], steps[moving]
    if not len(deltas):  # nowhere to go: at the (first) waypoint, at rest
        zero = np.zeros((1, path.shape[1]))
        return Trajectory(np.zeros(1), path[:1].copy(), zero, zero, 0.0, np.ones(1))
    # a segment's share is as limited as its most limited joint: limit / share of the move
    size = np.abs(deltas)
    share = [np.divide(lim, size, out=np.full_like(size, np.inf), where=size > 0)
             for lim in (limits.velocity * speed_scale, limits.acceleration, limits.jerk)]
    segments = [_segment(*(float(s[i].min()) for s in share)) for i in range(len(deltas))]
    durations = np.array([s.duration for s in segments])
    ends = np.cumsum(durations)
    duration = float(ends[-1])
    times = np.arange(math.ceil(duration / dt - 1e-9) + 1) * dt
    which = np.minimum(np.searchsorted(ends, times), len(segments) - 1)
    state = np.zeros((len(times), 3))  # per sample: share covered, its 1st, 2nd derivative
    state[:, 0] = 1.0  # at the end and after it: at rest at the goal
    for i in np.flatnonzero(times < duration):
        local = times[i] - (ends[which[i]] - durations[which[i]])
        state[i] = [x[0] for x in segments[which[i]].at_time(local)]
    d = deltas[which]
    lengths = np.linalg.norm(deltas / limits.velocity, axis=1)  # s at the speed limits
    before = np.concatenate([[0.0], np.cumsum(lengths)])[which]
    progress = np.clip((before + state[:, 0] * lengths[which]) / lengths.sum(), 0.0, 1.0)
    return Trajectory(times, starts[which] + state[:, :1] * d, state[:, 1:2] * d,
                      state[:, 2:3] * d, duration, progress)
