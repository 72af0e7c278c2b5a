"""The soak of unfamiliar scenes in small (bench/studies/soak.py runs 500): random valid
scenarios run as ``taskcam run`` runs them and their run directories audited; and the
auditor's checks shown to fail on run directories that do not tell the truth."""

from __future__ import annotations

import copy
import json
import math
import shutil
import tomllib
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from taskcam.sim.config.scenario import parse_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.experiments.soak.audit import audit_run
from taskcam.sim.experiments.soak.audit_findings import Audit
from taskcam.sim.experiments.soak.audit_robot import CORRECTION_TOL_M, POSE_TOL_DEG, POSE_TOL_M
from taskcam.sim.experiments.soak.draw_scenario import draw_scenario, is_heavy, to_toml
from taskcam.sim.experiments.soak.scenes import Job, discard_reason, run_file, run_scenes, tally
from taskcam.sim.world.scene import build_scene

# Scenes 0-23 of the soak's draws at 240 x 180 (the smallest size at which most random
# views still resolve the holes): 22 light, 2 (9 and 19) with correction and task on;
# and the scenes the soak found failing (tests/data/soak/, each file says what it
# found). About a minute and a half on 2 workers.
SCENES = 24
SIZES = ((240, 180),)
FOUND = sorted((Path(__file__).parent / "data" / "soak").glob("*.toml"))


@pytest.fixture(scope="module")
def soak(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    work = tmp_path_factory.mktemp("soak")
    jobs: list[Job] = [*FOUND, *((i, None) for i in range(SCENES))]  # the slow ones first
    return list(run_scenes(jobs, work, workers=2, sizes=SIZES))


def _findings(records: list[dict[str, Any]]) -> list[str]:
    return [f"{r.get('file') or 'scene ' + str(r['index'])} ({r.get('run_dir', 'no run dir')}): "
            f"{f['kind']} {f['robot']}: {f['message'][:400]}" for r in records
            for f in r["findings"]]


@pytest.mark.slow
def test_soak_scenes_tell_the_truth(soak: list[dict[str, Any]]) -> None:
    findings = _findings([r for r in soak if r["index"] is not None])
    assert not findings, "\n".join(findings)


@pytest.mark.parametrize("name", [p.name for p in FOUND])
@pytest.mark.slow
def test_scenes_the_soak_found_failing_tell_the_truth(soak: list[dict[str, Any]],
                                                      name: str) -> None:
    (record,) = [r for r in soak if r.get("file") == name]
    assert record["exit"] == 0
    findings = _findings([record])
    assert not findings, "\n".join(findings)


@pytest.mark.slow
def test_soak_checks_every_part(soak: list[dict[str, Any]]) -> None:
    """The soak ran what it claims and its checks had something to check (the found
    scenes included). Re-placements during the task are audited on a run that forces
    one (tests/test_task.py): since cameras are placed for the slot past the hanging
    panel, the found scenes that re-placed cameras no longer do."""
    c = tally(soak)["counts"]
    assert c["scenes"] == SCENES + len(FOUND) and c["heavy_scenes"] == 2
    assert c["poses_checked"] == c["robots"] > SCENES
    assert c.get("robots_placed", 0) >= 10 and c.get("robots_refused", 0) >= 1
    assert c.get("sightings_checked", 0) >= 10 and c.get("seen_checked", 0) >= 5
    assert sum(c.get(f"corrections_{s}", 0) for s in ("corrected", "uncertain", "failed")) >= 2


# ---------------------------------------------------------------- the generator


def test_draws_are_valid_scenarios_over_the_whole_schema() -> None:
    features: Counter[str] = Counter()
    shapes: Counter[str] = Counter()
    keys: Counter[str] = Counter()
    for i in range(300):
        draw = draw_scenario(np.random.default_rng([0, i, 0]), f"d{i}", is_heavy(i))
        scenario = parse_scenario(tomllib.loads(to_toml(draw.table)))
        assert scenario == parse_scenario(draw.table)  # the TOML says what was drawn
        assert scenario.correction.enabled == scenario.task.enabled == is_heavy(i)
        if is_heavy(i):
            assert scenario.motion.base_offset_m > 0 and scenario.task.replace
        features.update(draw.features)
        shapes.update(o.shape for o in scenario.obstacles)
        keys.update([scenario.mapping.depth_source, scenario.mapping.strategy,
                     scenario.mapping.gain, scenario.search.method, scenario.search.strategy])
    assert set(shapes) == {"box", "cylinder", "sphere"}
    for feature in ("roof", "shelf", "walls1", "walls3", "floating_sphere", "clutter",
                    "tight_base", "misplaced", "targets3", "robots1", "robots4", "heavy",
                    "planner_map", "planner_map_seen", "planner_model"):
        assert features[feature] > 0, feature
    for key in ("render", "stereo", "cooperative", "single", "random", "entropy",
                "unobserved", "rear_side", "rating", "biased_random", "information_gain",
                "exhaustive", "coarse", "bounded"):
        assert keys[key] > 0, key
    assert features["heavy"] == 30  # one scene in ten


def test_draws_keep_clear_of_geometry_unless_drawn_tight() -> None:
    """The scene builder accepts every draw but those with a base drawn too close."""
    tight = 0
    for i in range(60):
        draw = draw_scenario(np.random.default_rng([0, i, 0]), f"d{i}", is_heavy(i))
        try:
            build_scene(parse_scenario(draw.table))
        except ScenarioError as exc:
            assert "tight_base" in draw.features, str(exc)
            assert exc.key == "robots.bases[0]"
        tight += "tight_base" in draw.features
    assert tight >= 1


def test_invalid_input_is_a_discard_named_by_its_key(tmp_path: Path) -> None:
    path = tmp_path / "inside.toml"
    path.write_text(to_toml({"name": "inside", "robots": {
        "count": 2, "bases": [{"x": -1.8, "y": 0.0, "yaw_deg": 0.0},
                              {"x": 0.3, "y": 0.0, "yaw_deg": 0.0}]}}))
    code, stderr = run_file(path, tmp_path / "run")
    assert code == 2
    assert discard_reason(stderr) == "robots.bases"
    assert not (tmp_path / "run").exists()


def test_a_run_that_raises_gives_its_traceback(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a directory")
    path = tmp_path / "s.toml"
    path.write_text(to_toml({"name": "s", "camera": {"width": 160, "height": 120}}))
    code, stderr = run_file(path, tmp_path / "file" / "run")
    assert code == 1
    assert "Traceback (most recent call last)" in stderr


# ---------------------------------------------------------------- the auditor can fail

AUDITED = {"name": "audited", "seed": 1,
           "camera": {"width": 320, "height": 240, "samples": 0},
           "robots": {"count": 2, "bases": [{"x": -1.6, "y": -0.4, "yaw_deg": 15.0},
                                            {"x": 1.6, "y": 0.5, "yaw_deg": 195.0}]},
           "obstacles": [{"shape": "box", "position": [0.0, -0.9, 0.3],
                          "size": [0.15, 0.1, 0.3]}],
           # four views: the arms' way to their views mapped (never observed is blocked)
           "mapping": {"max_views": 4},
           "rating": {"tfv_directions": 4096},
           "search": {"strategy": "coarse", "ik_candidates": 10},
           "motion": {"settle_s": 0.3}}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run of a small fixed scene whose two robots are placed and see their targets."""
    work = tmp_path_factory.mktemp("audited")
    path = work / "audited.toml"
    path.write_text(to_toml(AUDITED))
    code, stderr = run_file(path, work / "run")
    assert code == 0, stderr
    summary = json.loads((work / "run" / "summary.json").read_text())
    assert all(r["placed"] and r["seen"] and r["sightings"] for r in summary["robots"])
    return work / "run"


def edited(run_dir: Path, tmp_path: Path, summary_edit: Any = None, xml_edit: Any = None
           ) -> tuple[set[tuple[str, str | None, str]], dict[str, Any]]:
    """The findings an edited copy of the run directory has that the original has not,
    and the edited summary."""
    copy_dir = tmp_path / "copy"
    shutil.copytree(run_dir, copy_dir)
    summary = json.loads((copy_dir / "summary.json").read_text())
    if summary_edit is not None:
        summary_edit(summary)
        (copy_dir / "summary.json").write_text(json.dumps(summary))
    if xml_edit is not None:
        for name in ("scene.xml", "look.xml"):
            xml = (copy_dir / name).read_text()
            (copy_dir / name).write_text(xml_edit(xml, summary))

    def keyed(a: Audit) -> set[tuple[str, str | None, str]]:
        return {(f.kind, f.robot, f.message) for f in a.findings}

    return keyed(audit_run(copy_dir)) - keyed(audit_run(run_dir)), summary


def kinds(found: set[tuple[str, str | None, str]]) -> set[str]:
    return {k for k, _, _ in found}


def test_the_run_it_edits_passes(run_dir: Path) -> None:
    audit = audit_run(run_dir)
    assert not audit.findings
    # every sighting and every robot's look was checked
    robots = json.loads((run_dir / "summary.json").read_text())["robots"]
    assert audit.counts["sightings_checked"] == sum(len(r["sightings"]) for r in robots) >= 2
    assert audit.counts["seen_checked"] == 2


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_reported_pose_off_the_scene_is_found(run_dir: Path, tmp_path: Path,
                                                axis: int) -> None:
    def move(s: dict[str, Any]) -> None:
        s["robots"][1]["pose"]["position"][axis] += 3 * POSE_TOL_M

    found, _ = edited(run_dir, tmp_path, move)
    assert {(k, r) for k, r, _ in found} == {("pose_mismatch", "r2")}


def test_a_look_from_elsewhere_than_the_scene_says_is_found(run_dir: Path,
                                                          tmp_path: Path) -> None:
    def elsewhere(s: dict[str, Any]) -> None:
        robot = s["robots"][0]
        robot["placements"][robot["seen_from_placement"]]["pose"]["position"][2] += 0.01

    found, _ = edited(run_dir, tmp_path, elsewhere)
    assert {(k, r) for k, r, _ in found} == {("look_mismatch", "r1")}


def test_a_reported_orientation_off_the_scene_is_found(run_dir: Path, tmp_path: Path) -> None:
    def turn(s: dict[str, Any]) -> None:
        half = math.radians(3 * POSE_TOL_DEG) / 2  # about the camera's x axis
        w, x, y, z = s["robots"][0]["pose"]["quat_wxyz"]
        c, si = math.cos(half), math.sin(half)
        s["robots"][0]["pose"]["quat_wxyz"] = [c * w - si * x, c * x + si * w,
                                               c * y + si * z, c * z - si * y]

    found, _ = edited(run_dir, tmp_path, turn)
    assert {(k, r) for k, r, _ in found} == {("pose_mismatch", "r1")}


def test_a_sighting_outside_the_image_is_found(run_dir: Path, tmp_path: Path) -> None:
    def outside(s: dict[str, Any]) -> None:
        s["robots"][0]["sightings"][0]["pixel"] = [330.0, 100.0]  # the image is 320 wide

    found, _ = edited(run_dir, tmp_path, outside)
    assert "sighting_outside_image" in kinds(found)
    assert all(r == "r1" for _, r, _ in found)


def test_a_detection_off_its_target_is_found(run_dir: Path, tmp_path: Path) -> None:
    def off(s: dict[str, Any]) -> None:
        u, v = s["robots"][1]["pixel"]
        s["robots"][1]["pixel"] = [u + 25.0 if u < 160 else u - 25.0, v]

    found, _ = edited(run_dir, tmp_path, off)
    assert {(k, r) for k, r, _ in found} == {("sighting_off_target", "r2")}


def _block(xml: str, summary: dict[str, Any]) -> str:
    """scene.xml with a 4 cm cube halfway between r1's camera and its target."""
    robot = summary["robots"][0]
    camera = np.array(robot["placements"][robot["seen_from_placement"]]["pose"]["position"])
    target = np.array(robot["target"]["position"])  # within millimetres of the true place
    x, y, z = (camera + target) / 2
    cube = f'<geom name="blocker" type="box" size="0.02 0.02 0.02" pos="{x} {y} {z}"/>'
    return xml.replace("<worldbody>", "<worldbody>\n    " + cube, 1)


def test_a_sighting_of_a_target_behind_an_obstacle_is_found(run_dir: Path,
                                                            tmp_path: Path) -> None:
    found, _ = edited(run_dir, tmp_path, xml_edit=_block)
    assert {(k, r) for k, r, _ in found} == {("sighting_obstructed", "r1")}
    assert any("'blocker'" in m and "the detection ('seen')" in m for _, _, m in found)
    assert any("'blocker'" in m and "sightings[" in m for _, _, m in found)


def _corrected(s: dict[str, Any], error_m: float, status: str = "corrected",
               estimated_m: float | None = None) -> None:
    """Give r1's placement (and its top-level mirror) a correction ``error_m`` off."""
    robot = s["robots"][0]
    placement = robot["placements"][robot["placement"]]
    estimated = copy.deepcopy(placement["pose"])
    estimated["position"][0] += error_m if estimated_m is None else estimated_m
    correction = {"status": status, "error_before": {"position_m": 0.02, "orientation_deg": 1.0},
                  "error_after": {"position_m": error_m, "orientation_deg": 0.0}}
    for record in (placement, robot):
        record["correction"] = copy.deepcopy(correction)
        record["estimated_pose"] = copy.deepcopy(estimated)


def test_a_correction_within_tolerance_passes(run_dir: Path, tmp_path: Path) -> None:
    found, _ = edited(run_dir, tmp_path, lambda s: _corrected(s, CORRECTION_TOL_M / 2))
    assert not found


def test_an_unflagged_bad_correction_is_found(run_dir: Path, tmp_path: Path) -> None:
    found, _ = edited(run_dir, tmp_path, lambda s: _corrected(s, 3 * CORRECTION_TOL_M))
    assert {(k, r) for k, r, _ in found} == {("correction_out_of_tolerance", "r1")}


def test_a_bad_correction_reported_as_failed_passes(run_dir: Path, tmp_path: Path) -> None:
    def failed(s: dict[str, Any]) -> None:
        _corrected(s, 3 * CORRECTION_TOL_M, "failed")
        for record in (s["robots"][0], s["robots"][0]["placements"][0]):
            record["correction"]["failed"] = "too few fiducials found again in the final frame"

    found, _ = edited(run_dir, tmp_path, failed)
    assert not found


def test_a_failure_without_a_reason_is_found(run_dir: Path, tmp_path: Path) -> None:
    found, _ = edited(run_dir, tmp_path,
                      lambda s: _corrected(s, 3 * CORRECTION_TOL_M, "failed"))
    assert {(k, r) for k, r, _ in found} == {("correction_misreported", "r1")}


def test_a_misreported_correction_error_is_found(run_dir: Path, tmp_path: Path) -> None:
    """error_after says 1 mm; the estimated pose is 5 mm off the true one."""
    found, _ = edited(run_dir, tmp_path,
                      lambda s: _corrected(s, CORRECTION_TOL_M / 3, estimated_m=0.005))
    assert {(k, r) for k, r, _ in found} == {("correction_misreported", "r1")}


def test_a_robot_neither_placed_nor_refused_is_found(run_dir: Path, tmp_path: Path) -> None:
    def unplaced(s: dict[str, Any]) -> None:
        robot = s["robots"][1]
        robot["placements"][0] = {k: robot["placements"][0][k]
                                  for k in ("index", "step", "reason")} | {"placed": False}
        robot.update(placed=False, placement=None, seen=False, pixel=None, sightings=[])
        for key in ("commanded_pose", "candidate_position", "target", "estimated_pose"):
            robot.pop(key, None)

    found, _ = edited(run_dir, tmp_path, unplaced)
    assert kinds(found) == {"unaccounted_robot"}

    def refused(s: dict[str, Any]) -> None:
        unplaced(s)
        s["robots"][1]["placements"][0]["refused"] = "every candidate tried was rejected"

    found, _ = edited(run_dir, tmp_path / "refused", refused)
    assert not found


def test_a_robot_missing_from_the_summary_is_found(run_dir: Path, tmp_path: Path) -> None:
    found, _ = edited(run_dir, tmp_path, lambda s: s["robots"].pop(1))
    assert found == {("unaccounted_robot", "r2", "in scene.xml but not in the summary")}


def test_top_level_fields_that_are_not_the_placements_are_found(run_dir: Path,
                                                                tmp_path: Path) -> None:
    def stale(s: dict[str, Any]) -> None:
        s["robots"][0]["commanded_pose"]["position"][2] += 0.05

    found, _ = edited(run_dir, tmp_path, stale)
    assert {(k, r) for k, r, _ in found} == {("mirror_mismatch", "r1")}

