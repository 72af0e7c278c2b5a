"""The scenes of the placement generality benchmark (sim/experiments/reach_scenes.py,
bench/studies/placement_reach.py) and the compact arm they carry (models/arms/compact_arm.xml)."""

from __future__ import annotations

import math
import tomllib
from collections import Counter
from pathlib import Path

import mujoco
import numpy as np
import pytest

from taskcam.sim.config.scenario import load_scenario, parse_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.experiments.reach_scenes import (
    COMPACT_ARM,
    FAR_LIMIT_M,
    ORACLE,
    UR5E,
    ReachScene,
    crosses,
    draw_reach_scene,
    obstacle_solid,
    oracle_table,
)
from taskcam.sim.experiments.soak.draw_obstacles import TABLE_HALF
from taskcam.sim.experiments.soak.draw_scenario import to_toml
from taskcam.sim.world.robot_model import ARM_JOINTS
from taskcam.sim.world.scene import build_scene

DRAWS = 300
# bench/studies/placement_reach.py's minimum over 200 scenes: 30 robots with each of these
MINIMUM_PER_200 = 30


def _draw(i: int, attempt: int = 0) -> ReachScene:
    return draw_reach_scene(np.random.default_rng([0, i, attempt]), f"reach{i}")


@pytest.fixture(scope="module")
def draws() -> list[ReachScene]:
    return [_draw(i) for i in range(DRAWS)]


def test_a_draw_is_the_same_for_the_same_seed() -> None:
    for i in range(5):
        a, b = _draw(i), _draw(i)
        assert a == b
        assert to_toml(a.table) == to_toml(b.table)
    assert _draw(0).table != _draw(0, attempt=1).table


def test_a_draw_leaves_placement_at_its_defaults_and_correction_and_task_off(
        draws: list[ReachScene]) -> None:
    defaults = parse_scenario({})
    for d in draws:
        assert "search" not in d.table and "rating" not in d.table
        scenario = parse_scenario(tomllib.loads(to_toml(d.table)))
        assert scenario == parse_scenario(d.table)  # the TOML says what was drawn
        assert scenario.search == defaults.search and scenario.rating == defaults.rating
        assert not scenario.correction.enabled and not scenario.task.enabled
        assert scenario.robots.move_base
        assert 1 <= scenario.robots.count <= 4
        assert f"robots{scenario.robots.count}" in d.features
        assert len(d.robot_features) == len(d.start_distances_m) == scenario.robots.count
        assert scenario.mapping.depth_source in d.features


def test_the_oracle_changes_only_the_placement_settings_it_names() -> None:
    d = _draw(3)
    table = oracle_table(d.table)
    assert table["search"] == ORACLE and "search" not in d.table  # the draw is not changed
    oracle, default = parse_scenario(table), parse_scenario(d.table)
    assert (oracle.search.planner_world, oracle.search.check_sight,
            oracle.search.ik_candidates) == ("model", True, 1000)
    assert oracle == parse_scenario({**d.table, "search": ORACLE})
    assert oracle.robots == default.robots and oracle.obstacles == default.obstacles


def test_a_written_draw_loads_as_a_scenario_file(tmp_path: Path) -> None:
    kinds = set()
    for i in range(30):
        d = _draw(i)
        path = tmp_path / f"reach{i}.toml"
        path.write_text(to_toml(d.table))
        scenario = load_scenario(path)
        assert scenario.name == f"reach{i}" and scenario.robots == parse_scenario(d.table).robots
        kinds.add(scenario.robots.model)
    assert kinds == {"taskcam", UR5E, str(COMPACT_ARM)}


def test_every_feature_the_benchmark_needs_is_drawn_often_enough(
        draws: list[ReachScene]) -> None:
    counts: Counter[str] = Counter()
    for d in draws:
        for robot in range(len(d.robot_features)):
            counts.update(set(d.features_of(robot)))
    need = math.ceil(MINIMUM_PER_200 * DRAWS / 200)
    for feature in ("stereo", "far_start", "ur5e", "compact_arm"):
        assert counts[feature] >= need, (feature, counts[feature])
    for feature in ("render", "taskcam", "wall", "enclosure", "enclosure_roof",
                    "robots1", "robots2", "robots3", "robots4"):
        assert counts[feature] > 0, feature


def test_a_far_start_is_beyond_the_limit_and_the_others_within(draws: list[ReachScene]
                                                                ) -> None:
    far = 0
    for d in draws:
        wx, wy = d.table["workpiece"]["position"]
        for base, own, drawn in zip(d.table["robots"]["bases"], d.robot_features,
                                    d.start_distances_m, strict=True):
            distance = math.hypot(base["x"] - wx, base["y"] - wy)
            assert distance == pytest.approx(drawn, abs=1e-3)
            assert ("far_start" in own) == (distance > FAR_LIMIT_M)
            far += distance > FAR_LIMIT_M
            assert distance < 3.01
    assert far > 0


def test_a_walled_robot_has_a_wall_across_its_way_and_room_round_it(
        draws: list[ReachScene]) -> None:
    walled = 0
    for d in draws:
        wx, wy = d.table["workpiece"]["position"]
        solids = [obstacle_solid(o) for o in d.table.get("obstacles", [])]
        # beyond the enclosure's walls, if there is one
        apart = TABLE_HALF[0] + d.layout.get("enclosure", {}).get("margin_m", 0.0) + 0.2
        for base, own in zip(d.table["robots"]["bases"], d.robot_features, strict=True):
            if "wall" not in own:
                continue
            walled += 1
            # a thin tall wall, apart from the table and short enough to go round
            across = [s for s in solids if crosses(s, (base["x"], base["y"]), (wx, wy))
                      and s.top - s.bottom >= 1.0 and min(s.half) <= 0.05
                      and max(s.half) <= 0.7 and math.hypot(s.x - wx, s.y - wy) > apart]
            assert across, base
    assert walled > 0


def test_an_enclosure_is_closed_on_three_sides_and_open_on_the_fourth(
        draws: list[ReachScene]) -> None:
    enclosed = 0
    for d in draws:
        if "enclosure" not in d.features:
            continue
        enclosed += 1
        layout = d.layout["enclosure"]
        wx, wy = d.table["workpiece"]["position"]
        yaw = math.radians(d.table["workpiece"]["yaw_deg"])
        solids = [obstacle_solid(o) for o in d.table.get("obstacles", [])]
        walls = [s for s in solids if s.bottom < 0.05]  # standing on the floor
        for side, local in (("+x", (1, 0)), ("-x", (-1, 0)), ("+y", (0, 1)), ("-y", (0, -1))):
            out = abs(local[0]) * TABLE_HALF[0] + abs(local[1]) * TABLE_HALF[1]
            out += layout["margin_m"] + 0.05  # just past the walls
            end = (wx + out * (math.cos(yaw) * local[0] - math.sin(yaw) * local[1]),
                   wy + out * (math.sin(yaw) * local[0] + math.cos(yaw) * local[1]))
            closed = any(crosses(s, (wx, wy), end) for s in walls)
            assert closed == (side != layout["open_side"]), (side, layout)
        assert ("enclosure_roof" in d.features) == layout["roof"]
    assert enclosed > 0


def test_the_compact_arm_compiles_and_steps_without_warnings() -> None:
    model = mujoco.MjModel.from_xml_path(str(COMPACT_ARM))
    data = mujoco.MjData(model)
    hinges = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    assert model.njnt == len(hinges) == 6 and model.jnt_limited.all()
    assert [model.joint(j).name for j in hinges] == list(ARM_JOINTS)
    assert (model.body_mass[1:] > 0).all()
    assert ((model.geom_contype > 0) & (model.geom_group == 3)).sum() >= 6
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert not any(int(w.number) for w in data.warning)
    assert np.allclose(data.qpos, model.key("home").qpos, atol=0.05)  # its servos hold it
    # stretched, the flange is 0.6-0.7 m from the shoulder, its +z pointing out of it
    data.qpos[:] = 0
    mujoco.mj_forward(model, data)
    shoulder, flange = data.body("shoulder_link").xpos, data.site("attachment_site")
    assert 0.6 <= np.linalg.norm(flange.xpos - shoulder) <= 0.7
    out = flange.xpos - data.body("wrist_3_link").xpos
    assert flange.xmat.reshape(3, 3)[:, 2] @ out / np.linalg.norm(out) > 0.99


@pytest.mark.slow
def test_a_scene_of_each_arm_builds_and_steps() -> None:
    """The scene builder accepts a draw with each arm (the first such draw it does
    not refuse), with the arm mounted on every robot."""
    built: dict[str, int] = {}
    for i in range(60):
        d = _draw(i)
        arm = next(a for a in ("taskcam", "ur5e", "compact_arm") if a in d.features)
        if arm in built:
            continue
        try:
            scene = build_scene(parse_scenario(d.table))
        except ScenarioError:
            continue
        built[arm] = i
        model, data = scene.model, scene.make_data()
        for robot in scene.robots:
            names = [model.joint(int(j)).name for j in model.dof_jntid[robot.dof_adr]]
            assert names[3:] == [f"{robot.name}/{j}" for j in ARM_JOINTS]
            if arm != "taskcam":
                assert model.site(f"{robot.name}/arm/attachment_site").id >= 0
        for _ in range(200):
            mujoco.mj_step(model, data)
        assert not any(int(w.number) for w in data.warning), arm
        if len(built) == 3:
            break
    assert set(built) == {"taskcam", "ur5e", "compact_arm"}, built
