"""Every model and scenario compiles and steps with zero MuJoCo warnings."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from taskcam.sim.config.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from taskcam.sim.config.sweep import is_sweep_file, load_sweep
from taskcam.sim.world.scene import MODELS_DIR, ROBOT_JOINTS, build_scene


def _step_without_warnings(model: mujoco.MjModel, data: mujoco.MjData, steps: int = 500) -> None:
    for _ in range(steps):
        mujoco.mj_step(model, data)
    counts = {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning)}
    assert not any(counts.values()), counts
    assert np.all(np.isfinite(data.qpos))


@pytest.mark.parametrize("path", sorted(MODELS_DIR.glob("*.xml")), ids=lambda p: p.name)
def test_model_compiles_and_steps(path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    _step_without_warnings(model, data)


def test_robot_model_conventions():
    model = mujoco.MjModel.from_xml_path(str(MODELS_DIR / "camera_robot.xml"))
    assert [model.joint(i).name for i in range(model.njnt)] == list(ROBOT_JOINTS)
    assert model.nu == len(ROBOT_JOINTS)
    assert set(model.site_group) == {4}
    assert {model.camera(i).name for i in range(model.ncam)} == {"left", "right"}
    # UR5e reach: shoulder to wrist centre = a2 + a3 = 0.8172 m when stretched.
    data = mujoco.MjData(model)
    data.qpos[:] = 0
    mujoco.mj_forward(model, data)
    shoulder = data.body("shoulder_link").xpos
    wrist = data.body("wrist_1_link").xpos
    assert np.linalg.norm(wrist - shoulder) == pytest.approx(np.hypot(0.425 + 0.3922, 0.007),
                                                             abs=1e-4)


@pytest.mark.parametrize("path", sorted(SCENARIO_DIR.glob("*.toml")), ids=lambda p: p.name)
def test_scenario_builds_and_steps(path):
    """Every scenario file, and every sweep file's first trial (its base scenario with
    the overrides and generated obstacles), compiles and steps cleanly."""
    if is_sweep_file(path):
        from taskcam.sim.experiments.runner import trial_specs
        from taskcam.sim.experiments.trial import trial_scenario

        scenario, _ = trial_scenario(trial_specs(load_sweep(path))[0])
    else:
        scenario = load_scenario(path)
    scene = build_scene(scenario)
    _step_without_warnings(scene.model, scene.make_data())


@pytest.mark.parametrize("count", [1, 2, 3, 4])
def test_any_robot_count_builds(count):
    scene = build_scene(parse_scenario({"robots": {"count": count}}))
    assert [r.name for r in scene.robots] == [f"r{i + 1}" for i in range(count)]
    for robot in scene.robots:
        assert scene.model.camera(robot.camera).id >= 0
        assert scene.model.camera(robot.right_camera).id >= 0
    _step_without_warnings(scene.model, scene.make_data(), steps=200)


def test_camera_parameters_come_from_the_scenario():
    s = parse_scenario({"camera": {"fovy_deg": 45.0, "width": 320, "height": 240,
                                   "baseline_m": 0.08}})
    scene = build_scene(s)
    data = scene.make_data()
    left, right = scene.robots[0].camera, scene.robots[0].right_camera
    assert scene.model.cam_fovy[scene.model.camera(left).id] == pytest.approx(45.0)
    assert tuple(scene.model.cam_resolution[scene.model.camera(right).id]) == (320, 240)
    baseline = np.linalg.norm(data.camera(left).xpos - data.camera(right).xpos)
    assert baseline == pytest.approx(0.08, abs=1e-9)
