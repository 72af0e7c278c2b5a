"""A robot's move to its placement in the world: the planned path followed in physics,
through its position actuators, with its positioning errors (sim/world/motion.py), and
with correction on, the frames its camera's pose is corrected from (sim/stages/corrector.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from taskcam.sim.screen import Advance
from taskcam.sim.stages.correction import Correction
from taskcam.sim.stages.corrector import PoseCorrector
from taskcam.sim.stages.world import World
from taskcam.sim.world.motion import MotionResult
from taskcam.sim.world.render import camera_pose
from taskcam.sim.world.scene import Robot


def move(world: World, robot: Robot, path: np.ndarray, corrector: PoseCorrector | None,
         prior_sd: tuple[float, float]) -> tuple[MotionResult, Correction | None]:
    """Follow ``path`` (k, 9 joints) in the world, recording the robot; with a
    ``corrector``, correct the camera's pose at the end (going back along the path and
    forth again if the last frame cannot be located) and leave the robot believing it.
    ``prior_sd`` is an uncorrected pose's standard deviation (m, deg). Time spent on
    frames during the move counts as correction's."""
    if corrector is None:
        return _move(world, robot, path, None, prior_sd, lambda done: None)
    # the correction's frames, shown as they are taken (the move's long part)
    with world.meter(f"{robot.name} moving, correcting its pose", "frame", None) as shown:
        return _move(world, robot, path, corrector, prior_sd, shown)


def _move(world: World, robot: Robot, path: np.ndarray, corrector: PoseCorrector | None,
          prior_sd: tuple[float, float], shown: Advance
          ) -> tuple[MotionResult, Correction | None]:
    timer, recorder = world.timer, world.recorder
    frames: Callable[[float, np.ndarray], None] | None = None
    if corrector is not None:
        with timer("correction"):
            corrector.begin(robot, path, world.at_rest(robot))
        frames = corrector.on_sample(robot)

    framing = 0.0  # wall time (s) spent on frames during the move

    def on_sample(t: float, measured: np.ndarray) -> None:
        nonlocal framing
        recorder.motion(robot.name, t, world.data, camera_pose(world.data, robot.camera))
        if frames is not None and corrector is not None:
            start = time.perf_counter()
            frames(t, measured)
            framing += time.perf_counter() - start
            shown(corrector.frames_taken)

    # a move that goes nowhere (a re-placement to where the camera is) makes no new error
    still = len(path) < 2 or float(np.abs(np.diff(path, axis=0)).max()) < 1e-9
    error = world.mover.made[robot.name] if still else world.errors.draw(robot)
    with timer("motion"):
        motion = world.mover.follow(robot, path, error, on_sample)
    if corrector is None:
        timer.move(framing, "motion", "correction")
        return motion, None
    with timer("correction"):
        correction = corrector.finish(robot, last_try=len(path) < 2)
    if correction.retrace_from is not None:  # back to where a frame was located, and forth
        again = corrector.retrace(path, correction.retrace_from)
        with timer("motion"):
            world.mover.follow(robot, again, error, on_sample)
        with timer("correction"):
            correction = corrector.finish(robot)
    believed = (correction.pose if correction.pose is not None
                else camera_pose(world.belief, robot.camera))
    world.came_to_rest(robot, believed, correction.believed_sd(prior_sd))
    timer.move(framing, "motion", "correction")
    recorder.fiducials(robot.name, correction, corrector.last_left)
    return motion, correction
