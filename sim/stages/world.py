"""The world an episode's stages share: what the planner believes and what is.

The nominal model (the scene as built) and the belief data (the commanded joints) are
what planning sees; the simulated model (the work-piece misplaced by the scenario's
errors) and its data hold the truth, which only physics and the evaluation read. The
occupancy grid is the robots' map. One generator, seeded by the scenario, draws every
random number of the run in the order the stages ask for them, but for the task's noise
(the panel's carry and steps), which has its own stream: what placement draws (IK
restarts, path samples, candidates) leaves the task's noise as it was, and paired
methods in a trial share it (common random numbers), so they differ by their
placement alone.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import mujoco
import numpy as np

from taskcam.mapping import FloorMap, OccupancyGrid, Pinhole, SensorModel
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.screen import Meter, no_meter
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.timer import Timer
from taskcam.sim.world.arm import Arm, scene_arm
from taskcam.sim.world.motion import ErrorModel, Mover
from taskcam.sim.world.render import camera_pinhole
from taskcam.sim.world.scene import Robot, Scene, build_scene, yaw_quat

# The joints and mocap bodies (positions, quaternions) of a world at one moment.
State = tuple[np.ndarray, np.ndarray, np.ndarray]
# Bodies where the world has them, not the plan: pos, quat relative to their parent.
Bodies = dict[str, tuple[np.ndarray, np.ndarray]]


def new_floor(s: Scenario, scene: Scene, reach_m: float) -> FloorMap:
    """An empty floor plan at the grid's resolution over the room the robots work in:
    the grid's floor and where the robots start, and the arm's reach (``reach_m``)
    beyond (a base may stand outside the grid and reach into it)."""
    starts = np.array([scene.start_qpos[r.qpos_adr[:2]] for r in scene.robots])
    lo = np.minimum(starts.min(axis=0), s.grid.bounds_min[:2]) - reach_m
    hi = np.maximum(starts.max(axis=0), s.grid.bounds_max[:2]) + reach_m
    return FloorMap.from_bounds(lo, hi, s.grid.resolution_m)


def new_grid(s: Scenario) -> OccupancyGrid:
    """An empty map of the scenario's grid bounds, resolution and sensor model."""
    g = s.grid
    return OccupancyGrid.from_bounds(np.array(g.bounds_min), np.array(g.bounds_max),
                                     g.resolution_m, SensorModel(*s.sensor()))


def print_nothing(line: str) -> None:
    """A world's default progress: silent."""


@dataclass(frozen=True)
class Snapshot:
    """The world's state, the plan's and the maps as they were (after mapping, say), for
    :meth:`World.restored` to start another method from."""

    qpos: np.ndarray
    ctrl: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    time: float
    grid: OccupancyGrid
    floor: FloorMap


@dataclass(frozen=True)
class World:
    """What the stages of one episode share. Its models and data are the simulation's
    state and change as the robots move; the map fills as they look."""

    scene: Scene
    belief: mujoco.MjData  # the commanded configuration, in the nominal model
    model: mujoco.MjModel  # the simulated world: errors go here
    data: mujoco.MjData
    grid: OccupancyGrid
    floor: FloorMap  # the bases' scanners' floor plan
    rng: np.random.Generator
    errors: ErrorModel  # each move's positioning error, drawn from ``rng``
    task_rng: np.random.Generator  # the task's noise: its own stream (module docstring)
    mover: Mover
    pinhole: Pinhole  # of every robot's cameras
    workpiece_error: np.ndarray  # (dx, dy, dyaw) in m, m, rad
    # each secondary target's true place off its CAD relation to the primary (m, in the
    # plate: x, y), a draw of its ST_error
    secondary_errors: dict[str, list[float]]
    recorder: Recorder
    timer: Timer
    arm: Arm  # the arm every robot carries, with its reach
    # where each robot that has moved believes its camera rests (4x4, MuJoCo convention)
    # and that belief's standard deviation (m, deg): its next correction starts there
    _at_rest: dict[str, tuple[np.ndarray, tuple[float, float]]] = field(default_factory=dict)
    # the places each robot's base can get to, as planners found them (keyed by what
    # they depend on): the methods restored from one snapshot share them
    places: dict[tuple[Any, ...], Any] = field(default_factory=dict)
    # told a line as each stage ends (``taskcam run`` prints them)
    progress: Callable[[str], None] = field(default=print_nothing)
    # a live meter inside a long stage (sim/screen.py): silent unless on a terminal
    meter: Meter = field(default=no_meter)

    @property
    def nominal(self) -> mujoco.MjModel:
        """The scene as the planner knows it."""
        return self.scene.model

    @property
    def scenario(self) -> Scenario:
        return self.scene.scenario

    # ------------------------------------------------------------ belief about the cameras

    def at_rest(self, robot: Robot) -> tuple[np.ndarray, tuple[float, float]] | None:
        """Where ``robot`` believes its camera rests and how well, once it has moved."""
        return self._at_rest.get(robot.name)

    def came_to_rest(self, robot: Robot, believed: np.ndarray,
                     sd: tuple[float, float]) -> None:
        """``robot``'s move ended with its camera believed at ``believed`` (4x4), with
        standard deviation ``sd`` (m, deg)."""
        self._at_rest[robot.name] = (believed, sd)

    @property
    def room(self) -> tuple[np.ndarray, np.ndarray]:
        """The floor the bases may stand on: the floor plan's extent (x, y; m)."""
        f = self.floor
        return f.origin, f.origin + np.array(f.shape) * f.resolution

    def planner_maps(self, kind: str) -> dict[str, Any]:
        """The maps an ArmPlanner is given in the planner's world ``kind``
        (``search.planner_world``): none in "model", where it knows the scene as it is."""
        if kind == "model":
            return {}
        return {"grid": self.grid, "floor": self.floor, "unobserved_blocks": kind == "map"}

    # ------------------------------------------------------------ state

    def hold(self) -> None:
        """After mapping's kinematic moves: the actuators hold where the robots are, and
        the planner knows it (no error has been made yet)."""
        self.data.ctrl[:] = self.scene.ctrl_for(self.data.qpos)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.belief.qpos[:] = self.data.qpos
        mujoco.mj_forward(self.nominal, self.belief)

    def state(self) -> State:
        """The world's joints and mocap bodies (positions, quaternions) as they are now,
        its poses brought up to them (after a physics step they lag by that step)."""
        d = self.data
        mujoco.mj_forward(self.model, d)
        return d.qpos.copy(), d.mocap_pos.copy(), d.mocap_quat.copy()

    def bodies(self) -> Bodies:
        """Bodies where the world has them, not the plan (pos, quat relative to their
        parent frame in the scene's spec): the arms' mounts and the work-piece."""
        bodies = self.mover.mount_overrides()
        dx, dy, dyaw = self.workpiece_error
        if dx or dy or dyaw:
            back = -math.radians(self.scenario.workpiece.yaw_deg)  # the work-piece's frame
            c, s = math.cos(back), math.sin(back)
            bodies["workpiece/workpiece"] = (np.array([c * dx - s * dy, s * dx + c * dy, 0.0]),
                                             np.array(yaw_quat(dyaw)))
        return bodies

    def to_xml(self, keyframe: str, state: State | None = None,
               bodies: Bodies | None = None) -> tuple[str, dict[str, bytes]]:
        """The scene's MJCF with the world's ``state`` (default: now) as ``keyframe``
        and its ``bodies`` where they were; the files it reads, by name."""
        return self.scene.to_xml({keyframe: self.state() if state is None else state},
                                 self.bodies() if bodies is None else bodies)

    def snapshot(self) -> Snapshot:
        """The world, the plan and the maps as they are now."""
        d = self.data
        return Snapshot(d.qpos.copy(), d.ctrl.copy(), d.mocap_pos.copy(), d.mocap_quat.copy(),
                        float(d.time), copy.deepcopy(self.grid), copy.deepcopy(self.floor))

    def restored(self, snap: Snapshot, rng: np.random.Generator,
                 task_rng: np.random.Generator) -> World:
        """This world back at ``snap``, at rest, drawing from ``rng`` from now on (the
        robots' calibration errors are drawn afresh from it) and the task's noise from
        ``task_rng``; the maps are copies of the snapshot's."""
        d = self.data
        d.qpos[:], d.ctrl[:], d.time = snap.qpos, snap.ctrl, snap.time
        d.mocap_pos[:], d.mocap_quat[:] = snap.mocap_pos, snap.mocap_quat
        d.qvel[:] = 0.0
        d.act[:] = 0.0
        self.mover.reset()
        mujoco.mj_forward(self.model, d)
        self.belief.qpos[:] = snap.qpos
        mujoco.mj_forward(self.nominal, self.belief)
        return replace(self, grid=copy.deepcopy(snap.grid), floor=copy.deepcopy(snap.floor),
                       rng=rng,
                       errors=ErrorModel(self.scenario.motion, self.scene.robots, rng),
                       task_rng=task_rng,
                       _at_rest={})


def build_world(scenario: Scenario, timer: Timer, recorder: Recorder | None = None
                ) -> World:
    """The world of ``scenario``: its scene built, the work-piece misplaced in the
    simulated model, the robots' calibration errors drawn, the map empty. Raises
    ScenarioError for geometry the scenario cannot hold."""
    rng = np.random.default_rng(scenario.seed)
    with timer("build"):
        scene = build_scene(scenario)
        arm = scene_arm(scene)
    model = copy.deepcopy(scene.model)
    workpiece_error = misplace_workpiece(scenario, model, rng)
    # from a stream spawned off the run's: the draws after it are the same whether or
    # not the scenario's secondary targets have a tolerance
    secondary_errors = misplace_secondaries(scene, model, rng.spawn(1)[0])
    task_rng = rng.spawn(1)[0]
    data = scene.make_data()
    belief = scene.make_data()
    errors = ErrorModel(scenario.motion, scene.robots, rng)
    world = World(scene, belief, model, data, new_grid(scenario),
                  new_floor(scenario, scene, arm.reach_m),
                  rng, errors, task_rng,
                  Mover(model, data, scene.robots, scenario.motion),
                  camera_pinhole(model, scene.robots[0].camera), workpiece_error,
                  secondary_errors, Recorder(None, "") if recorder is None else recorder, timer,
                  arm)
    world.state()  # the world's poses brought up to its model: the work-piece where it is
    return world


def misplace_workpiece(s: Scenario, model: mujoco.MjModel, rng: np.random.Generator
                        ) -> np.ndarray:
    """Move the work-piece in ``model`` off where the planner believes it (by the
    scenario's errors); returns (dx, dy, dyaw) in m, m, rad."""
    w = s.workpiece
    if w.position_error_m == 0 and w.yaw_error_deg == 0:
        return np.zeros(3)
    dx, dy = rng.normal(0.0, w.position_error_m, 2)
    dyaw = math.radians(float(rng.normal(0.0, w.yaw_error_deg)))
    body = model.body("workpiece/workpiece").id
    model.body_pos[body, :2] += (dx, dy)
    model.body_quat[body] = yaw_quat(math.radians(w.yaw_deg) + dyaw)
    return np.array([dx, dy, dyaw])


def misplace_secondaries(scene: Scene, model: mujoco.MjModel, rng: np.random.Generator
                         ) -> dict[str, list[float]]:
    """Move each secondary target (its hole) in ``model`` off its CAD place by a draw of
    its ST_error (the secondary-to-primary tolerance, eq. 4: a standard deviation along
    each axis of the plate); returns each one's offset (m, plate x and y)."""
    out: dict[str, list[float]] = {}
    for t in scene.targets:
        if t.role != "secondary" or t.st_error <= 0:
            continue
        offset = rng.normal(0.0, t.st_error, 2)
        model.geom_pos[model.geom(t.geom).id, :2] += offset
        out[t.name] = offset.round(6).tolist()
    return out
