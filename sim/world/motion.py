"""Motion in physics: a joint-space path, timed jerk-limited (``taskcam.sim.world.timing``),
followed through position actuators, with the robot's positioning errors (sec. 2.4),
clearance and contacts watched along the way.

The planner's world is the nominal model and the commanded joints; the simulated world
(``world``, a copy of the model) is where the robot really goes. Its errors:

- joint offsets (calibration), drawn once per robot: the set point of each arm joint is
  off by a constant;
- joint noise, base position and yaw errors, drawn for every move: added to the set
  points (the base's odometry and the arm's repeatability);
- suspension: the arm's mount tilts (roll and pitch about the base's floor point) by an
  angle drawn for every move, written into the world model only.

An error stays where the move that made it left it: the next move turns it into its own
along the way (a robot does not lose its offsets by starting to move).

The planner never reads the world: it sees the commanded joints. The episode compares
the commanded camera pose with the one the world reached.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from taskcam.sim.config.stages import MotionConfig
from taskcam.sim.world.collision import Clearance, Proximity
from taskcam.sim.world.scene import ROBOT_JOINTS, Robot
from taskcam.sim.world.timing import ROBOT_LIMITS, time_path

ARM_MOUNT = "arm_base"  # the body the suspension tilts, about the base's floor point
TILT_EVERY = 10  # physics steps between updates of the building-up suspension tilt


@dataclass(frozen=True)
class MoveError:
    """The error of one move: added to the set points (9, in joint units), and the tilt
    of the arm's mount (roll, pitch; rad)."""

    setpoints: np.ndarray
    tilt: tuple[float, float]

    @staticmethod
    def none() -> MoveError:
        return MoveError(np.zeros(9), (0.0, 0.0))


class ErrorModel:
    """Draws each move's positioning error for every robot from one generator."""

    def __init__(self, cfg: MotionConfig, robots: tuple[Robot, ...],
                 rng: np.random.Generator) -> None:
        self.cfg, self.rng = cfg, rng
        self.offsets = {r.name: rng.normal(0.0, math.radians(cfg.joint_offset_deg), 6)
                        for r in robots}

    def draw(self, robot: Robot) -> MoveError:
        c, rng = self.cfg, self.rng
        base = np.array([*rng.normal(0.0, c.base_offset_m, 2),
                         rng.normal(0.0, math.radians(c.base_yaw_deg))])
        arm = self.offsets[robot.name] + rng.normal(0.0, math.radians(c.joint_noise_deg), 6)
        roll, pitch = rng.normal(0.0, math.radians(c.suspension_deg), 2)
        return MoveError(np.concatenate([base, arm]), (float(roll), float(pitch)))


@dataclass
class MotionResult:
    """What happened in the world while one robot followed its path."""

    duration_s: float  # simulated
    steps: int
    closest: Clearance  # the smallest clearances met along the way
    contact_steps: int  # physics steps with the robot touching anything but the floor
    samples: list[tuple[float, np.ndarray]]  # (simulated time s, robot joints) for records

    def summary(self) -> dict[str, float | int]:
        return {"duration_s": round(self.duration_s, 4), "steps": self.steps,
                "contact_steps": self.contact_steps,
                **{f"min_clearance_{k}": v for k, v in self.closest.summary().items()}}


def dense_path(path: np.ndarray, step_rad: float = 0.01, step_m: float = 0.01) -> np.ndarray:
    """The path with waypoints inserted so that no joint moves more than ``step_rad``
    (arm, yaw) or ``step_m`` (base x, y) between two of them."""
    if len(path) < 2:
        return path
    scale = np.array([step_m, step_m, *([step_rad] * 7)])
    counts = np.ceil(np.abs(np.diff(path, axis=0) / scale).max(axis=1)).astype(int).clip(1)
    out = [path[:1]]
    for a, b, n in zip(path[:-1], path[1:], counts, strict=True):
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.vstack(out)


class Mover:
    """Moves robots in the world through their position actuators."""

    def __init__(self, world: mujoco.MjModel, data: mujoco.MjData,
                 robots: tuple[Robot, ...], cfg: MotionConfig) -> None:
        self.world, self.data, self.robots, self.cfg = world, data, robots, cfg
        by_joint = {int(j): a for a, j in enumerate(world.actuator_trnid[:, 0])}
        self.actuators = {r.name: np.array([by_joint[world.joint(r.joint(j)).id]
                                            for j in ROBOT_JOINTS]) for r in robots}
        self.mounts = {r.name: world.body(f"{r.name}/{ARM_MOUNT}").id for r in robots}
        self.mount_pose = {r.name: (world.body_pos[self.mounts[r.name]].copy(),
                                    world.body_quat[self.mounts[r.name]].copy())
                           for r in robots}
        self.proximity = {r.name: Proximity(world, r, robots) for r in robots}
        self.made = {r.name: MoveError.none() for r in robots}  # the error each robot has now
        # each mount's last tilt (roll and pitch, as repr) and the pose it left: a tilt
        # repeated on an unmoved mount is skipped (scipy's rotations cost 0.3 ms a call)
        self._tilted: dict[str, tuple[tuple[str, str], np.ndarray, np.ndarray]] = {}
        # Seconds of lead per joint: a position servo with gain kp and damping d (its kv
        # plus the joint's) trails a ramp by d / kp; commanding that much ahead cancels it.
        self.lead = {r.name: np.array([
            (-world.actuator_biasprm[a, 2] + world.dof_damping[world.jnt_dofadr[
                world.actuator_trnid[a, 0]]]) / world.actuator_gainprm[a, 0]
            for a in self.actuators[r.name]]) for r in robots}

    def mount_overrides(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Every arm mount's (pos, quat) in the world now, by body name."""
        return {f"{r.name}/{ARM_MOUNT}": (self.world.body_pos[self.mounts[r.name]].copy(),
                                          self.world.body_quat[self.mounts[r.name]].copy())
                for r in self.robots}

    def tilt(self, robot: Robot, roll: float, pitch: float, forward: bool = True) -> None:
        """Tilt the robot's arm mount about the base's floor point (in the world only)."""
        body = self.mounts[robot.name]
        key = (repr(roll), repr(pitch))  # to the bit: -0.0 is not 0.0 here
        last = self._tilted.get(robot.name)
        if last is None or last[0] != key or not (  # the mount as the last tilt left it:
                np.array_equal(self.world.body_pos[body], last[1])  # the same tilt again
                and np.array_equal(self.world.body_quat[body], last[2])):  # would not move it
            pos, quat = self.mount_pose[robot.name]
            R = Rotation.from_euler("xy", [roll, pitch])
            self.world.body_pos[body] = R.apply(pos)
            q = (R * Rotation.from_quat(quat, scalar_first=True)).as_quat(scalar_first=True)
            self.world.body_quat[body] = q
            self._tilted[robot.name] = (key, self.world.body_pos[body].copy(),
                                        self.world.body_quat[body].copy())
        if forward:
            mujoco.mj_forward(self.world, self.data)

    def reset(self) -> None:
        """Every robot as commanded: no error made, the mounts untilted (the world's
        joints are the caller's to set)."""
        for robot in self.robots:
            self.made[robot.name] = MoveError.none()
            self.tilt(robot, 0.0, 0.0, forward=False)

    def follow(self, robot: Robot, path: np.ndarray, error: MoveError,
               on_sample: Callable[[float, np.ndarray], None] | None = None,
               sample_every_s: float = 0.05) -> MotionResult:
        """Drive ``robot``'s set points along ``path`` (k, 9), then hold the goal for the
        settle time, stepping the physics throughout.

        The path is timed by ``time_path``: jerk-limited, rest-to-rest along every
        straight segment, within ``speed_scale`` of the joint speed limits and within
        the acceleration and jerk limits (``ROBOT_LIMITS``). Every physics step's set
        point is where the trajectory is at the step's end, led by the trajectory's
        velocity times the servo's lag (s; velocity feed-forward). The robot's error
        turns from the one it has (the last move's) into ``error`` with the share of the
        path covered: all of the old at the start, all of the new at the end (a move
        that continues the last one, such as going back along it and forth again, keeps
        it). ``on_sample(t, measured)`` is called every
        ``sample_every_s`` of simulated time with the joints as the robot's encoders and
        odometry read them: the true joints (servo lag included) less the errors, which
        they cannot see."""
        m, d, cfg = self.world, self.data, self.cfg
        act = self.actuators[robot.name]
        dt = m.opt.timestep
        trajectory = time_path(path, ROBOT_LIMITS, cfg.speed_scale, dt)
        check = max(1, round(cfg.check_every_s / dt))
        sample = max(1, round(sample_every_s / dt))
        own_geoms = self.proximity[robot.name].own
        floor = m.geom("floor").id
        probe = self.proximity[robot.name]
        closest = probe.measure(d)
        contacts, steps, t0 = 0, 0, d.time
        samples = [(float(d.time), d.qpos[robot.qpos_adr].copy())]
        last = len(trajectory.times) - 1
        n = last + math.ceil(cfg.settle_s / dt)
        at = np.minimum(np.arange(1, n + 1), last)  # each step's end on the trajectory
        progress = trajectory.progress[at]
        old = self.made[robot.name]
        made = old.setpoints + progress[:, None] * (error.setpoints - old.setpoints)
        tilts = np.array(old.tilt) + progress[:, None] * (np.array(error.tilt) - old.tilt)
        setpoints = (trajectory.positions[at] + made
                     + trajectory.velocities[at] * self.lead[robot.name])
        own = np.array(sorted(own_geoms))
        self.made[robot.name] = error
        for k in range(n):
            if k % TILT_EVERY == 0 or k == n - 1:
                roll, pitch = tilts[k]
                self.tilt(robot, float(roll), float(pitch), forward=False)
            d.ctrl[act] = setpoints[k]
            mujoco.mj_step(m, d)
            steps += 1
            if d.ncon:
                g1, g2 = d.contact.geom1[:d.ncon], d.contact.geom2[:d.ncon]
                touching = np.isin(g1, own) != np.isin(g2, own)
                if np.any(touching & (g1 != floor) & (g2 != floor)):
                    contacts += 1
            if steps % check == 0 or k == n - 1:
                now = probe.measure(d)
                closest = Clearance(min(closest.robots, now.robots),
                                    min(closest.world, now.world), min(closest.own, now.own))
            if steps % sample == 0 or k == n - 1:
                samples.append((float(d.time), d.qpos[robot.qpos_adr].copy()))
                if on_sample is not None:
                    on_sample(float(d.time), d.qpos[robot.qpos_adr] - made[k])
        return MotionResult(float(d.time - t0), steps, closest, contacts, samples)
