"""Bring your own robot: an arm from MuJoCo Menagerie or the user's MJCF is
mounted on taskcam's base with the stereo head on its flange, and IK drives it; an arm
that breaks the contract is refused naming the key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest

from taskcam.sim.config.scenario import Scenario, load_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.robot_model import ARM_JOINTS
from taskcam.sim.world.scene import build_scene, save_scene

UR5E = "menagerie:universal_robots_ur5e"

# a six-joint arm of capsules, its own actuators, a keyframe and a mount site
ARM = """
<mujoco>
  <default><geom type="capsule" size="0.04"/></default>
  <worldbody>
    <body name="root">
      <body name="l1" pos="0 0 0.1"><joint name="j1" axis="0 0 1" range="-3 3"/>
        <geom fromto="0 0 0 0 0 0.1"/>
        <body name="l2" pos="0 0 0.1"><joint name="j2" axis="0 1 0" range="-3 3"/>
          <geom fromto="0 0 0 0.4 0 0"/>
          <body name="l3" pos="0.4 0 0"><joint name="j3" axis="0 1 0" range="-3 3"/>
            <geom fromto="0 0 0 0.35 0 0"/>
            <body name="l4" pos="0.35 0 0"><joint name="j4" axis="0 1 0"/>
              <geom fromto="0 0 0 0.05 0 0" size="0.035"/>
              <body name="l5" pos="0.05 0 0"><joint name="j5" axis="0 0 1"/>
                <geom fromto="0 0 0 0.05 0 0" size="0.035"/>
                <body name="l6" pos="0.05 0 0"><joint name="j6" axis="1 0 0"/>
                  <geom fromto="0 0 0 0.03 0 0" size="0.03"/>
                  <site name="tool" pos="0.04 0 0" zaxis="1 0 0"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="j1"/></actuator>
  <keyframe><key name="home" qpos="0 -1 1.5 0 0 0"/></keyframe>
</mujoco>
"""


MASSIVE = '<geom fromto="0 0 0 0.05 0 0" size="0.035"/>'  # l4 and l5's mass


def _with(s: Scenario, **robots: object) -> Scenario:
    return dataclasses.replace(s, robots=dataclasses.replace(s.robots, **robots))


def _head_on_mount(scene, site: str) -> None:
    """The head's frame is the mount site's: the stereo head sits on the flange."""
    data = scene.make_data()
    for r in scene.robots:
        head, mount = data.body(f"{r.name}/head"), data.site(f"{r.name}/arm/{site}")
        assert np.allclose(head.xpos, mount.xpos, atol=1e-9)
        assert np.allclose(head.xmat, mount.xmat, atol=1e-9)


def test_menagerie_ur5e_is_mounted_with_the_head_on_its_flange():
    scene = build_scene(_with(load_scenario(), model=UR5E))
    model = scene.model
    for r in scene.robots:
        names = [model.joint(int(j)).name for j in model.dof_jntid[r.dof_adr]]
        assert names[3:] == [f"{r.name}/{j}" for j in ARM_JOINTS]
        assert {model.body(b).name for b in r.body_ids} >= {f"{r.name}/arm/wrist_3_link",
                                                            f"{r.name}/head"}
        # taskcam's servos, one per joint, and none of Menagerie's own
        actuated = {model.joint(int(model.actuator_trnid[a, 0])).name for a in range(model.nu)}
        assert actuated >= {f"{r.name}/{j}" for j in ARM_JOINTS}
        assert model.nu == 9 * len(scene.robots)
        # its start is Menagerie's own home keyframe
        assert scene.start_qpos[r.qpos_adr[3:]] == pytest.approx(
            [-1.5708, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
        # its meshes are drawn; its collision capsules collide
        geoms = np.isin(model.geom_bodyid, list(r.body_ids))
        assert (geoms & (model.geom_type == mujoco.mjtGeom.mjGEOM_MESH)).sum() >= 15
        assert (geoms & (model.geom_contype > 0) & (model.geom_group == 3)).sum() >= 8
    _head_on_mount(scene, "attachment_site")


def test_ik_brings_the_menagerie_camera_to_a_view():
    scene = build_scene(_with(load_scenario(), model=UR5E))
    robot = scene.robots[0]
    target = scene.primary.position
    ik = solve_camera_pose(scene.model, scene.start_qpos, robot, target,
                           target + [-0.5, -0.1, 0.45])
    assert ik.position_error_m < 1e-3 and ik.orientation_error_deg < 0.5


def test_a_users_arm_file_is_mounted(tmp_path):
    (tmp_path / "arm.xml").write_text(ARM)
    scenario = tmp_path / "mine.toml"
    scenario.write_text('[robots]\nmodel = "arm.xml"\nmount = "tool"\n')
    scene = build_scene(load_scenario(scenario))
    _head_on_mount(scene, "tool")
    assert scene.start_qpos[scene.robots[0].qpos_adr[3:]] == pytest.approx([0, -1, 1.5, 0, 0, 0])


@pytest.mark.parametrize(("robots", "arm", "key", "said"), [
    ('model = "nowhere.xml"', None, "robots.model", "no such file"),
    ('model = "menagerie:no_such_robot"', None, "robots.model", "no robot 'no_such_robot'"),
    ('model = "arm.xml"\nmount = "flange"', ARM, "robots.mount", "no site 'flange'"),
    ('model = "arm.xml"\nmount = "tool"', ARM.replace('<joint name="j6" axis="1 0 0"/>', ""),
     "robots.model", "5 hinge joints"),
    ('model = "arm.urdf"', None, "robots.model", "bad value"),
    ('model = "arm.xml"\nmount = "tool"', ARM.replace(MASSIVE, ""), "robots.model",
     "does not compile"),
])
def test_an_arm_that_breaks_the_contract_is_refused(tmp_path, robots, arm, key, said):
    if arm is not None:
        (tmp_path / "arm.xml").write_text(arm)
    scenario = tmp_path / "bad.toml"
    scenario.write_text(f"[robots]\n{robots}\n")
    with pytest.raises(ScenarioError) as refused:
        build_scene(load_scenario(scenario))
    message = str(refused.value)
    assert message.startswith(f"{scenario}: key '{key}': ") and said in message
    assert "\n" not in message


def test_the_menagerie_scenario_is_shipped():
    s = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "menagerie_ur5e.toml")
    assert s.robots.model == UR5E and s.robots.count == 2


def test_a_saved_scene_with_menagerie_meshes_loads_elsewhere(tmp_path):
    """``scene.xml`` copies the arm's mesh files beside it: the run directory loads on
    its own, wherever it is moved."""
    scene = build_scene(_with(load_scenario(), model=UR5E))
    xml, files = scene.to_xml({})
    saved = save_scene(tmp_path / "run", xml, files)
    moved = tmp_path / "moved"
    saved.parent.rename(moved)
    model = mujoco.MjModel.from_xml_path(str(moved / "scene.xml"))
    assert model.nmesh == scene.model.nmesh > 0
    assert np.allclose(model.mesh_vert, scene.model.mesh_vert)


@pytest.mark.slow
def test_a_menagerie_camera_is_placed_moved_and_corrected(tmp_path):
    """The whole way to a view on Menagerie's UR5e, unchanged code: mapping, placement,
    the move in physics with its positioning errors, and the correction from fiducials
    to within the bench's bounds (3 mm, 0.2 deg)."""
    scenario = tmp_path / "one.toml"
    default = Path(__file__).resolve().parents[1] / "scenarios" / "default.toml"
    scenario.write_text(f'extends = "{default}"\n[robots]\ncount = 1\nmodel = "{UR5E}"\n'
                        'bases = [{ x = -1.9, y = -0.5, yaw_deg = 15.0 }]\n'
                        # one robot maps only its own side: its base's way is planned
                        # in the scene as it is (as examples/ and table1.toml do)
                        '[search]\nplanner_world = "model"\n'
                        "[task]\nenabled = false\n")
    from taskcam.sim.stages.episode import Episode

    summary, _ = Episode(load_scenario(scenario)).run()
    robot = summary["robots"][0]
    assert robot["placed"] and robot["seen"], robot.get("refused")
    assert robot["motion"]["contact_steps"] == 0
    error = robot["correction"]["error_after"]
    assert error["position_m"] <= 0.003 and error["orientation_deg"] <= 0.2, error


def test_a_scenario_extends_another(tmp_path):
    """``extends``: the file's tables over the base's, key by key; lists replaced; the
    name its own; a cycle or a missing base refused naming the key."""
    (tmp_path / "base.toml").write_text(
        'name = "base"\nseed = 3\n[camera]\nwidth = 320\nheight = 240\n'
        '[[obstacles]]\nshape = "box"\nposition = [0.9, 0.9, 0.1]\nsize = [0.1, 0.1, 0.1]\n')
    (tmp_path / "child.toml").write_text('extends = "base.toml"\nobstacles = []\n'
                                         "[camera]\nwidth = 400\n")
    s = load_scenario(tmp_path / "child.toml")
    assert (s.name, s.seed, s.camera.width, s.camera.height) == ("child", 3, 400, 240)
    assert s.obstacles == ()
    shipped = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" /
                            "menagerie_ur5e.toml")
    default = load_scenario()
    assert dataclasses.replace(shipped, robots=default.robots, name=default.name,
                               source=default.source) == default
    (tmp_path / "a.toml").write_text('extends = "b.toml"\n')
    (tmp_path / "b.toml").write_text('extends = "a.toml"\n')
    (tmp_path / "c.toml").write_text('extends = "nowhere.toml"\n')
    for name, said in (("a.toml", "a cycle"), ("c.toml", "no such file")):
        with pytest.raises(ScenarioError, match=f"key 'extends': {said}"):
            load_scenario(tmp_path / name)
