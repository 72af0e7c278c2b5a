"""What ``taskcam run`` prints: the stage lines and the outcome table, from a
summary whose numbers are known; and the pictures of a run: ``overview.png`` frames the
work-piece and the robots, ``--video`` films the episode."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import cv2
import imageio.v2 as imageio
import mujoco
import numpy as np
import pytest

from taskcam.mapping import opencv_pose
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.run_screen import distance_m, placement_line, run_screen, task_line, view_command
from taskcam.sim.stages.episode import Episode
from taskcam.sim.stages.overview import Overview, framed_points, frustum_segments
from taskcam.sim.stages.run_directory import write_run
from taskcam.sim.world.render import camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene


def _robot(name: str, position: list[float], target: list[float]) -> dict:
    return {"name": name, "placed": True,
            "target": {"name": "slot", "role": "primary", "position": target},
            "pose": {"position": position, "quat_wxyz": [1, 0, 0, 0]},
            "rating": {"total": 77.04, "dof": 1.0, "resolution": 552.6, "tfv": 0.2,
                       "tav": 0.697, "free": 0.999},
            "positioning_error": {"position_m": 0.0228, "orientation_deg": 1.49},
            "correction": {"status": "corrected",
                           "error_before": {"position_m": 0.0228, "orientation_deg": 1.49},
                           "error_after": {"position_m": 0.0013, "orientation_deg": 0.03}}}


SUMMARY = {
    "robots": [_robot("r1", [0.0, 0.0, 1.0], [0.0, 0.3, 0.6]),
               {"name": "r2", "placed": False, "refused": "no view of any target"}],
    "task": {"attempted": True, "object_size_m": 0.2, "steps": 17,
             "success": {"0.2": True, "0.1": True, "0.01": False},
             "final_displacement_m": 0.00273, "stopped_by": "max_steps"},
    "timings_s": {"mapping": 3.2, "placement": 2.3, "task": 15.0, "total": 20.5},
}


def test_the_outcome_table_says_what_the_summary_says():
    text = run_screen(SUMMARY, Path("runs/x/run.rrd"))
    assert distance_m(SUMMARY["robots"][0]) == pytest.approx(0.5)  # 0.3-0.4-0.5 by hand
    lines = text.splitlines()
    robots = lines[:3]
    assert len({len(line) for line in robots}) == 1  # aligned: right-justified columns
    assert robots[1].split()[:5] == ["r1", "slot", "(primary)", "77.0", "1"]
    assert "0.50 m" in robots[1] and "22.8 mm 1.49°" in robots[1] and "1.3 mm 0.03°" in robots[1]
    assert robots[2].split()[:3] == ["r2", "not", "placed"]
    assert lines[4] == "placed: 1 of 2 robots (r1); not placed: r2"
    start = next(k for k, line in enumerate(lines) if line.startswith("task "))
    task = lines[start:start + 2]
    assert task[0].split()[1:4] == ["20", "%", "of"]
    assert task[1].split() == ["met", "met", "missed", "2.73", "mm", "17"]
    assert "mapping 3.2 s" in text and "total 20.5 s" in text
    assert lines[-1] == "view: " + view_command(Path("runs/x/run.rrd"))
    assert shlex.split(lines[-1], comments=True)[-1] == "runs/x/run.rrd"


def test_stage_lines():
    assert placement_line("r1", SUMMARY["robots"][0]) == (
        "r1: placed for slot (primary), RF 77.0, 0.50 m away; corrected 22.8 mm 1.49° -> "
        "1.3 mm 0.03°")
    assert placement_line("r2", SUMMARY["robots"][1]) == "r2: not placed (no view of any target)"
    assert task_line(SUMMARY["task"]).startswith("task: 20 % met, 10 % met, 1 % missed; "
                                                 "final displacement 2.73 mm after 17 step(s)")


def _share(segmentation: np.ndarray, model: mujoco.MjModel, bodies: list[int]) -> int:
    geoms = np.flatnonzero(np.isin(model.geom_bodyid, bodies))
    return int(np.isin(segmentation, geoms).sum())


def test_the_overview_frames_the_workpiece_and_every_robot():
    scene = build_scene(load_scenario())
    model, data = scene.model, scene.make_data()
    workpiece = [b for b in range(model.nbody) if model.body(b).name.startswith("workpiece/")]
    robots = [sorted(r.body_ids) for r in scene.robots]
    framed = framed_points(model, data, [r.body_ids for r in scene.robots])
    with Overview(model, framed) as view:
        plain = view.render(data)
        pinhole = camera_pinhole(model, scene.robots[0].camera)
        frusta = [opencv_pose(camera_pose(data, r.camera)) for r in scene.robots]
        drawn = view.render(data, frusta, pinhole)
        seg = view.segmentation(data)
    assert plain.std() > 20  # not blank
    # the work-piece and each robot are in the picture, not cut by its edges
    for bodies in [workpiece, *robots]:
        assert _share(seg, model, bodies) > 500
        rows, cols = np.nonzero(np.isin(seg, np.flatnonzero(np.isin(model.geom_bodyid,
                                                                      bodies))))
        assert rows.min() > 0 and cols.min() > 0
        assert rows.max() < seg.shape[0] - 1 and cols.max() < seg.shape[1] - 1
    # the work-piece near the middle
    rows, cols = np.nonzero(np.isin(seg, np.flatnonzero(np.isin(model.geom_bodyid,
                                                                  workpiece))))
    assert abs(cols.mean() / seg.shape[1] - 0.5) < 0.2
    assert abs(rows.mean() / seg.shape[0] - 0.5) < 0.25
    # the frusta are drawn (green lines) and nowhere else is changed much
    changed = np.abs(drawn.astype(int) - plain.astype(int)).sum(axis=2) > 60
    assert 100 < changed.sum() < 0.05 * changed.size
    assert (drawn[changed][:, 1] > drawn[changed][:, 0]).mean() > 0.8
    assert len(frustum_segments(frusta[0], pinhole, 0.25)) == 8


@pytest.mark.slow
def test_a_filmed_run_writes_its_pictures(tmp_path):
    """A small episode with ``video``: the film has the overview's size, many frames, and
    shows the robot moving; ``overview.png`` is written too."""
    small = tmp_path / "small.toml"
    small.write_text("[robots]\ncount = 1\n[mapping]\nmax_views = 2\n[task]\nenabled = false\n"
                     "[correction]\nenabled = false\n")
    out = tmp_path / "run"
    write_run(Episode(load_scenario(small)), out, record=False, video=True)
    picture = cv2.imread(str(out / "overview.png"))
    assert picture is not None and picture.std() > 20
    reader = imageio.get_reader(str(out / "episode.mp4"))
    frames = [f for f in reader]
    assert frames[0].shape == picture.shape
    assert len(frames) > 20
    moved = np.abs(frames[-1].astype(int) - frames[0].astype(int)).sum(axis=2) > 60
    assert moved.mean() > 0.002  # the robot is elsewhere at the end than at the start
    assert math.isclose(reader.get_meta_data()["fps"], 15.0)


@pytest.mark.slow
def test_taskcam_run_prints_its_stages_and_outcome(default_run):
    out, summary = default_run
    printed = (out.parent / "stdout.txt").read_text()
    assert printed == run_screen(summary, out / "run.rrd")  # the table, from the summary
    command = shlex.split(printed.splitlines()[-1].removeprefix("view: "), comments=True)
    assert Path(command[-1]) == out / "run.rrd" and Path(command[0]).name == "rerun"
    stages = (out.parent / "stderr.txt").read_text()
    for robot in summary["robots"]:
        assert f"taskcam: {robot['name']}: placed for {robot['target']['name']} (" in stages
    assert task_line(summary["task"]) in stages
    assert "taskcam: mapping: " in stages
    picture = cv2.imread(str(out / "overview.png"))
    assert picture is not None and picture.std() > 20
