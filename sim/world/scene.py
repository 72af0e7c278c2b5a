"""Scene assembly: a scenario and the MJCF models of ``models/`` composed with MjSpec."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from taskcam.mapping import Target
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.world.fixtures import add_fixture
from taskcam.sim.world.robot_model import camera_robot
from taskcam.sim.world.textures import as_files, link_files, paint

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
WORKPIECE_XML = MODELS_DIR / "workpiece.xml"
PANEL_XML = MODELS_DIR / "panel.xml"
OBSTACLES_XML = MODELS_DIR / "obstacles.xml"
ROBOT_JOINTS = (
    "base_x", "base_y", "base_yaw",
    "shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3",
)
BASE_JOINTS = ROBOT_JOINTS[:3]
HOLE_LIFT = 0.0005  # m: a hole's dark face lies this far above the plate (no z-fighting)
# Maximum joint speeds (m/s, rad/s): UR5e arm joints 180 deg/s; a slow mobile base.
JOINT_SPEEDS = dict.fromkeys(ROBOT_JOINTS[3:], math.pi) | {
    "base_x": 0.5, "base_y": 0.5, "base_yaw": 1.0,
}


def yaw_quat(yaw_rad: float) -> list[float]:
    """Quaternion (w, x, y, z) of a rotation by ``yaw_rad`` about +z."""
    return [math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)]


@dataclass(frozen=True)
class Robot:
    """Names and indices of one attached camera robot."""

    name: str  # "r1"
    qpos_adr: np.ndarray  # qpos index of each of ROBOT_JOINTS
    dof_adr: np.ndarray  # dof index of each of ROBOT_JOINTS
    body_ids: frozenset[int]  # every body of the robot

    @property
    def prefix(self) -> str:
        return f"{self.name}/"

    @property
    def camera(self) -> str:
        return f"{self.name}/left"

    @property
    def right_camera(self) -> str:
        return f"{self.name}/right"

    @property
    def optical_site(self) -> str:
        return f"{self.name}/left_optical"

    @property
    def head_body(self) -> str:
        return f"{self.name}/head"

    @property
    def base_body(self) -> str:
        return f"{self.name}/base"

    def joint(self, name: str) -> str:
        return f"{self.name}/{name}"


@dataclass
class Scene:
    """The compiled world of one scenario, and where everything is in it."""

    scenario: Scenario
    spec: mujoco.MjSpec
    model: mujoco.MjModel
    robots: tuple[Robot, ...]
    targets: tuple[Target, ...]
    start_qpos: np.ndarray
    textures: dict[str, np.ndarray]  # painted (sim/world/textures.py), by name

    def robot_geoms(self) -> np.ndarray:
        """Bool per geom id: does it belong to a robot?"""
        bodies = frozenset().union(*(r.body_ids for r in self.robots))
        return np.array([int(b) in bodies for b in self.model.geom_bodyid])

    @property
    def primary(self) -> Target:
        return next(t for t in self.targets if t.role == "primary")

    def make_data(self, qpos: np.ndarray | None = None) -> mujoco.MjData:
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.start_qpos if qpos is None else qpos
        data.ctrl[:] = self.ctrl_for(data.qpos)
        mujoco.mj_forward(self.model, data)
        return data

    def set_robot(self, data: mujoco.MjData, robot: Robot, qpos: np.ndarray,
                  model: mujoco.MjModel | None = None) -> None:
        """Put one robot's joints at their values in ``qpos`` (a full configuration), in
        ``data`` of ``model`` (default: the scene's nominal model)."""
        data.qpos[robot.qpos_adr] = qpos[robot.qpos_adr]
        mujoco.mj_forward(self.model if model is None else model, data)

    def ctrl_for(self, qpos: np.ndarray) -> np.ndarray:
        """Position-actuator set points that hold ``qpos``."""
        return qpos[self.model.jnt_qposadr[self.model.actuator_trnid[:, 0]]]

    def to_xml(self, states: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
               bodies: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
               ) -> tuple[str, dict[str, bytes]]:
        """MJCF of the scene with keyframe ``start`` and one keyframe per named world state
        (qpos, mocap positions, mocap quaternions), e.g. ``final``, and no other; and the
        files it reads (painted textures, by path relative to it). ``bodies`` overrides
        named bodies' (pos, quat) relative to their parents (the world at those states,
        e.g. the arms' tilted mounts), in every keyframe: a keyframe holds only joints and
        mocap bodies, so states with bodies apart need a scene each."""
        for name, (pos, quat) in (bodies or {}).items():
            body = self.spec.body(name)
            body.pos, body.quat = list(pos), list(quat)
        for key in list(self.spec.keys):
            if key.name != "start" and key.name not in states:
                self.spec.delete(key)
        mocap = self.model.body_mocapid >= 0
        start = (self.start_qpos, self.model.body_pos[mocap].ravel(),
                 self.model.body_quat[mocap].ravel())
        for name, (qpos, mpos, mquat) in {"start": start, **states}.items():
            key = self.spec.key(name)
            if key is None:
                key = self.spec.add_key(name=name)
            key.qpos = qpos.tolist()
            key.ctrl = self.ctrl_for(qpos).tolist()
            key.mpos = np.ravel(mpos).tolist()
            key.mquat = np.ravel(mquat).tolist()
        with as_files(self.spec, self.textures):
            self.spec.compile()  # to_xml needs a compiled spec; self.model stays as it was
            xml = str(self.spec.to_xml())
        xml, files = link_files(xml, self.textures)
        return copied_assets(xml, self.spec, files)


def copied_assets(xml: str, spec: mujoco.MjSpec, files: dict[str, bytes]
                  ) -> tuple[str, dict[str, bytes]]:
    """The XML with every mesh or texture file read from an absolute path (an arm brought
    in: sim/world/robot_model.py) read instead from a copy beside it, under ``assets/``,
    and those copies added to ``files``."""
    for asset in [*spec.meshes, *spec.textures]:
        source = Path(asset.file) if asset.file else None
        if source is None or not source.is_absolute():
            continue
        copy = f"assets/{source.parent.name}/{source.name}"
        xml = xml.replace(f'file="{asset.file}"', f'file="{copy}"')
        files[copy] = source.read_bytes()
    return xml, files


def save_scene(directory: Path, xml: str, files: dict[str, bytes],
               name: str = "scene.xml") -> Path:
    """Write :meth:`Scene.to_xml`'s MJCF as ``directory/name`` with the files it reads
    beside it; returns the scene file's path."""
    for path, content in files.items():
        (directory / path).parent.mkdir(parents=True, exist_ok=True)
        (directory / path).write_bytes(content)
    scene = directory / name
    scene.write_text(xml)
    return scene

def _world(spec: mujoco.MjSpec, s: Scenario) -> None:
    spec.modelname = f"taskcam_{s.name}"
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.stat.extent = 4.0
    spec.stat.center = [0.0, 0.0, 0.8]
    spec.visual.map.znear = 0.005  # x extent: 2 cm
    spec.visual.map.zfar = 10.0  # x extent: 40 m
    spec.visual.global_.offwidth = max(640, s.camera.width)
    spec.visual.global_.offheight = max(480, s.camera.height)
    spec.visual.quality.offsamples = s.camera.samples
    # The cameras carry no lamp: the headlight lights without a direction (its ambient
    # alone), so that a surface looks the same whichever way a camera turns. Its diffuse
    # and specular (MuJoCo's default) shaded every surface by the rendering camera's
    # direction, which moved the natural fiducials' keypoints from view to view: a
    # wrist's 30-40 deg turn moved a tracked pose ~1.5 mm (docs/pose-correction.md).
    # 0.75 is the light a surface facing the camera had (ambient 0.35 + diffuse 0.4).
    spec.visual.headlight.ambient = [0.75, 0.75, 0.75]
    spec.visual.headlight.diffuse = [0.0, 0.0, 0.0]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                     rgb1=[0.6, 0.75, 0.9], rgb2=[0.1, 0.15, 0.25], width=64, height=64)
    spec.add_texture(name="floor", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT, mark=mujoco.mjtMark.mjMARK_RANDOM,
                     rgb1=[0.34, 0.35, 0.37], markrgb=[0.2, 0.21, 0.23], width=8, height=8)
    spec.add_material(name="floor", textures=["", "floor"], texuniform=True,
                      texrepeat=[0.5, 0.5], reflectance=0.0)
    world = spec.worldbody
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[6, 6, 0.05],
                   material="floor")
    world.add_light(name="sun", pos=[0.5, -0.5, 4.0], dir=[-0.1, 0.1, -1.0],
                    diffuse=[0.6, 0.6, 0.6], castshadow=False)


def _workpiece(spec: mujoco.MjSpec, s: Scenario) -> tuple[Target, ...]:
    wp = mujoco.MjSpec.from_file(str(WORKPIECE_XML))
    plate = wp.geom("plate")
    half_x, half_y = float(plate.size[0]), float(plate.size[1])
    top = float(plate.pos[2] + plate.size[2])
    hole_depth = float(wp.geom("hole_wide").size[1])  # every hole is as deep
    listed = {f"hole_{t.name}" for t in s.workpiece.targets}
    for geom in list(wp.geoms):
        if geom.name.startswith("hole_") and geom.name not in listed:
            wp.delete(geom)
    yaw = math.radians(s.workpiece.yaw_deg)
    rot = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                    [0, 0, 1]])
    origin = np.array([*s.workpiece.position, 0.0])
    lo, hi = np.array(s.grid.bounds_min), np.array(s.grid.bounds_max)
    targets = []
    for i, t in enumerate(s.workpiece.targets):
        ox, oy = t.offset_m
        if t.mount == "fixture":
            face = add_fixture(wp, t, s.source, i)
        elif abs(ox) + t.radius_m > half_x or abs(oy) + t.radius_m > half_y:
            raise ScenarioError(s.source, f"workpiece.targets[{i}].offset_m", list(t.offset_m),
                                f"a hole on the plate: |x| + radius <= {half_x}, "
                                f"|y| + radius <= {half_y}")
        else:
            face = top
        geom = wp.geom(f"hole_{t.name}")
        if geom is None:
            geom = wp.body("workpiece").add_geom(wp.find_default("hole"), name=f"hole_{t.name}")
        geom.size = [t.radius_m, hole_depth, 0]
        geom.pos = [ox, oy, face + HOLE_LIFT - hole_depth]
        position = origin + rot @ np.array([ox, oy, face + HOLE_LIFT])
        if np.any(position < lo) or np.any(position > hi):
            raise ScenarioError(s.source, f"workpiece.targets[{i}]", position.round(3).tolist(),
                                f"a target inside the grid bounds {lo.tolist()} to {hi.tolist()}")
        targets.append(Target(t.name, t.role, f"workpiece/hole_{t.name}", position,
                              rot @ np.array([0.0, 0.0, 1.0]), t.radius_m, t.st_error_m))
    slot = origin + rot @ np.asarray(wp.site("slot").pos, float)
    if s.task.enabled and (np.any(slot < lo) or np.any(slot > hi)):  # the task's target
        raise ScenarioError(s.source, "workpiece.position", list(s.workpiece.position),
                            f"a work-piece whose slot (the task's primary target, at "
                            f"{slot.round(3).tolist()}) is inside the grid bounds "
                            f"{lo.tolist()} to {hi.tolist()}")
    frame = spec.worldbody.add_frame(pos=origin.tolist(), quat=yaw_quat(yaw))
    frame.attach_body(wp.body("workpiece"), "workpiece/", "")
    return tuple(targets)


def _panel(spec: mujoco.MjSpec, s: Scenario) -> None:
    panel = mujoco.MjSpec.from_file(str(PANEL_XML))
    frame = spec.worldbody.add_frame(pos=list(s.panel.position),
                                     quat=yaw_quat(math.radians(s.panel.yaw_deg)))
    frame.attach_body(panel.body("panel"), "panel/", "")


def _obstacles(spec: mujoco.MjSpec, s: Scenario) -> None:
    for i, o in enumerate(s.obstacles):
        prims = mujoco.MjSpec.from_file(str(OBSTACLES_XML))
        prims.geom(o.shape).size = [*o.size, *([0.0] * (3 - len(o.size)))]
        frame = spec.worldbody.add_frame(pos=list(o.position),
                                         quat=yaw_quat(math.radians(o.yaw_deg)))
        frame.attach_body(prims.body(o.shape), f"obstacle{i}/", "")


def _robots(spec: mujoco.MjSpec, s: Scenario) -> list[float]:
    """Attach the robots; returns the start configuration of each, concatenated."""
    robot, arm_home = camera_robot(s)  # built once; each base gets a copy
    half = s.camera.baseline_m / 2
    for side, sign in (("left", -1.0), ("right", 1.0)):
        cam, site = robot.camera(side), robot.site(f"{side}_optical")
        cam.fovy = s.camera.fovy_deg
        cam.resolution = [s.camera.width, s.camera.height]
        cam.pos = [sign * half, cam.pos[1], cam.pos[2]]
        site.pos = list(cam.pos)
    robot.delete(robot.key("home"))  # the scene has keyframes of its own
    for body in robot.bodies:  # the arm's controller carries its weight
        body.gravcomp = 1.0
    start: list[float] = []
    for i, base in enumerate(s.base_poses()):
        yaw = math.remainder(math.radians(base.yaw_deg), 2 * math.pi)  # within the joint's range
        start += [base.x, base.y, yaw, *arm_home]
        spec.worldbody.add_frame().attach_body(robot.copy().body("base"), f"r{i + 1}/", "")
    return start


def build_scene(s: Scenario) -> Scene:
    """Compile the scenario's world. Raises ScenarioError for geometry it cannot hold."""
    spec = mujoco.MjSpec()
    _world(spec, s)
    targets = _workpiece(spec, s)
    _panel(spec, s)
    _obstacles(spec, s)
    start = _robots(spec, s)
    textures = paint(spec)
    model = spec.compile()
    robots = []
    for i in range(s.robots.count):
        name = f"r{i + 1}"
        joints = [model.joint(f"{name}/{j}") for j in ROBOT_JOINTS]
        root = model.body(f"{name}/base").id
        bodies = frozenset(b for b in range(model.nbody) if _descends(model, b, root))
        robots.append(Robot(
            name,
            np.array([model.jnt_qposadr[j.id] for j in joints]),
            np.array([model.jnt_dofadr[j.id] for j in joints]),
            bodies,
        ))
    qpos = model.qpos0.copy()
    for robot, i in zip(robots, range(len(robots)), strict=True):
        qpos[robot.qpos_adr] = start[9 * i: 9 * i + 9]
    scene = Scene(s, spec, model, tuple(robots), targets, qpos, textures)
    check_robot_bases(scene)
    return scene


def _descends(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return False


def check_robot_bases(scene: Scene) -> None:
    """Raise ScenarioError if a robot, at its start configuration, overlaps anything but
    the floor (the work-piece, the panel, an obstacle, another robot), naming the base pose
    at fault and what it overlaps. Exact for every shape and height: MuJoCo's signed
    distance between collision geoms (touching, to a micrometre, is allowed)."""
    model, data, s = scene.model, scene.make_data(), scene.scenario
    robot_of = {int(b): i for i, r in enumerate(scene.robots) for b in r.body_ids}
    floor = model.geom("floor").id
    solid = [g for g in range(model.ngeom) if g != floor
             and (model.geom_contype[g] or model.geom_conaffinity[g])]
    nobody = len(scene.robots)  # the owner of what is not a robot's
    owner = {g: robot_of.get(int(model.geom_bodyid[g]), nobody) for g in solid}
    radius = np.where(model.geom_rbound > 0, model.geom_rbound, np.inf)
    fromto = np.zeros(6)

    def name(g: int, own: bool = False) -> str:
        text = model.geom(g).name or model.body(int(model.geom_bodyid[g])).name
        i = owner[g]
        if i < nobody:
            return f"{text} (robots.bases[{i}])" if s.robots.bases and not own else text
        if text.startswith("obstacle"):
            index, shape = text.removeprefix("obstacle").split("/")
            return f"obstacles[{index}] (a {shape})"
        return text

    for i in range(len(scene.robots)):
        own = [g for g in solid if owner[g] == i]
        others = [h for h in solid if owner[h] > i]  # each pair once
        for g in own:
            for h in others:
                if np.linalg.norm(data.geom_xpos[g] - data.geom_xpos[h]) > radius[g] + radius[h]:
                    continue  # bounding spheres apart
                depth = -mujoco.mj_geomDistance(model, data, g, h, 0.0, fromto)
                if depth <= 1e-6:
                    continue
                where = f"here {name(g, own=True)} overlaps {name(h)} by {1000 * depth:.0f} mm"
                if s.robots.bases:
                    b = s.robots.bases[i]
                    raise ScenarioError(s.source, f"robots.bases[{i}]",
                                        {"x": b.x, "y": b.y, "yaw_deg": b.yaw_deg},
                                        f"a start pose clear of everything but the floor; {where}")
                raise ScenarioError(s.source, "robots.start_radius_m", s.robots.start_radius_m,
                                    f"a radius at which every robot stands clear of everything "
                                    f"but the floor; {where}")
