"""Inverse kinematics with mink: put a robot's camera at a point, looking at another."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from taskcam.sim.world.collision import collision_geoms
from taskcam.sim.world.scene import BASE_JOINTS, JOINT_SPEEDS, ROBOT_JOINTS, Robot

OPTICAL_AXIS = (0.0, 0.0, -1.0)  # a MuJoCo camera looks along its -z axis
SELF_MARGIN_M = 0.005  # between a robot's own links (some sit 1.5 cm apart at home)


@dataclass(frozen=True)
class IKResult:
    """A solution, or the best attempt, with its residual errors."""

    qpos: np.ndarray  # full model configuration
    position_error_m: float  # camera centre to the commanded position
    orientation_error_deg: float  # optical axis to the direction of the look-at point
    iterations: int
    converged: bool
    path: np.ndarray  # (iterations + 1, 9) the robot's joints at each iterate, from q0
    errors: np.ndarray  # (iterations + 1, 2) position (m) and angle (deg) errors there
    time_s: float = 0.0  # wall clock

    def summary(self) -> dict[str, float | int | bool]:
        return {"position_error_m": self.position_error_m,
                "orientation_error_deg": self.orientation_error_deg,
                "iterations": self.iterations, "converged": self.converged,
                "time_s": round(self.time_s, 4)}


def camera_errors(model: mujoco.MjModel, data: mujoco.MjData, site: str,
                  position: np.ndarray | None, look_at: np.ndarray) -> tuple[float, float]:
    """Position error (m) and angle (deg) between the optical axis and the look-at direction."""
    s = data.site(site)
    axis = -s.xmat.reshape(3, 3)[:, 2]
    to_target = look_at - s.xpos
    cos = float(axis @ to_target / max(np.linalg.norm(to_target), 1e-12))
    angle = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
    pos_err = 0.0 if position is None else float(np.linalg.norm(s.xpos - position))
    return pos_err, angle


@dataclass(frozen=True)
class IKSettings:
    max_iterations: int = 400
    dt: float = 0.1  # s per iteration; joint speeds bound each step
    position_tolerance_m: float = 5e-4
    orientation_tolerance_deg: float = 0.05
    posture_cost: float = 1e-3
    base_posture_cost: float = 1e-3  # the base's (x, y, yaw): higher keeps it where it is
    damping: float = 1e-4
    # give up when this many iterations gained less than a tolerance on both errors: a
    # pose out of reach stalls against the limits long before max_iterations
    stall_iterations: int = 40


def solve_camera_pose(
    model: mujoco.MjModel,
    q0: np.ndarray,
    robot: Robot,
    look_at: np.ndarray,
    position: np.ndarray | None = None,
    move_base: bool = True,
    settings: IKSettings = IKSettings(),
    avoid: Sequence[int] = (),
    margin_m: float = 0.0,
) -> IKResult:
    """Move ``robot`` (only) so its left camera sits at ``position`` looking at ``look_at``.

    With ``position`` None only the gaze is controlled. The other robots' joints, and
    the base when ``move_base`` is False, are frozen. Joint ranges and speeds are limits.
    With ``avoid`` (geom ids), the robot's collision geoms keep ``margin_m`` from them
    and its own links from each other, at every iterate: the iterates are then a
    collision-free joint-space path from ``q0`` (at the step's resolution).
    """
    started = time.perf_counter()
    config = mink.Configuration(model, q0)
    site = robot.optical_site
    look = mink.LookAtTask(site, "site", axis=OPTICAL_AXIS, cost=1.0)
    look.set_target(np.asarray(look_at, float))
    tasks: list[mink.Task] = [look]
    if position is not None:
        frame = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=0.0)
        target = config.get_transform_frame_to_world(site, "site")
        frame.set_target(mink.SE3.from_rotation_and_translation(
            target.rotation(), np.asarray(position, float)))
        tasks.append(frame)
    cost = np.full(model.nv, settings.posture_cost)
    cost[robot.dof_adr[:len(BASE_JOINTS)]] = settings.base_posture_cost
    posture = mink.PostureTask(model, cost=cost)
    posture.set_target(q0)
    tasks.append(posture)

    own = set(robot.dof_adr.tolist())
    if not move_base:
        own -= {int(robot.dof_adr[ROBOT_JOINTS.index(j)]) for j in BASE_JOINTS}
    frozen = [i for i in range(model.nv) if i not in own]
    constraints = [mink.DofFreezingTask(model, dof_indices=frozen)] if frozen else []
    speeds = {robot.joint(j): JOINT_SPEEDS[j] for j in ROBOT_JOINTS}
    limits: list[mink.Limit] = [mink.ConfigurationLimit(model),
                                mink.VelocityLimit(model, speeds)]
    if len(avoid):
        own_geoms = collision_geoms(model, robot.body_ids)
        limits.append(mink.CollisionAvoidanceLimit(
            model, [(own_geoms, list(avoid))], minimum_distance_from_collisions=margin_m,
            collision_detection_distance=margin_m + 0.1))
        limits.append(mink.CollisionAvoidanceLimit(  # its own links: only kept apart
            model, [(own_geoms, own_geoms)], minimum_distance_from_collisions=SELF_MARGIN_M,
            collision_detection_distance=SELF_MARGIN_M + 0.02))

    errors = camera_errors(model, config.data, site, position, look_at)
    path, history = [config.q[robot.qpos_adr].copy()], [errors]
    iterations = 0
    while iterations < settings.max_iterations and not _within(errors, settings):
        try:
            velocity = mink.solve_ik(config, tasks, settings.dt, "daqp",
                                     damping=settings.damping, limits=limits,
                                     constraints=constraints)
        except mink.NoSolutionFound:  # infeasible limits: report the residual so far
            break
        config.integrate_inplace(velocity, settings.dt)
        iterations += 1
        errors = camera_errors(model, config.data, site, position, look_at)
        path.append(config.q[robot.qpos_adr].copy())
        history.append(errors)
        if iterations >= settings.stall_iterations and _stalled(
                history[-1 - settings.stall_iterations], errors, settings):
            break
    return IKResult(config.q.copy(), errors[0], errors[1], iterations, _within(errors, settings),
                    np.array(path), np.array(history), time.perf_counter() - started)


def _stalled(before: tuple[float, float], now: tuple[float, float],
             settings: IKSettings) -> bool:
    return (before[0] - now[0] < settings.position_tolerance_m
            and before[1] - now[1] < settings.orientation_tolerance_deg)


def _within(errors: tuple[float, float], settings: IKSettings) -> bool:
    return (errors[0] <= settings.position_tolerance_m
            and errors[1] <= settings.orientation_tolerance_deg)
