"""One outcome, told the same everywhere: the stage lines, the outcome table,
``summary.json``, ``scene.xml`` and what ``overview.png`` is drawn from agree on which
robots were placed (N of M), the re-placements during the task (step, reason, result),
each correction's status and why (in summary.json's words) and each robot's final base
pose; the screen's meters show only on a terminal and ``--quiet`` leaves the table
alone; the ``view:`` hint serves the web viewer where there is no display."""

from __future__ import annotations

import fcntl
import io
import json
import math
import os
import pty
import shlex
import struct
import subprocess
import sys
import termios
from pathlib import Path

import mujoco
import numpy as np
import pytest

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.run_screen import (
    correction_words,
    has_display,
    placed_line,
    placement_line,
    replacement_lines,
    run_screen,
    view_command,
)
from taskcam.sim.screen import Screen
from taskcam.sim.stages.overview import Overview, framed_points
from taskcam.sim.stages.overview_marks import (
    PLACED_RGBA,
    UNPLACED_RGBA,
    robot_marks,
    target_marks,
)
from taskcam.sim.world.scene import build_scene

TASKCAM = Path(sys.executable).parent / "taskcam"


def _placed(name: str, status: str, why: str | None = None) -> dict:
    correction = {"status": status, "frames": 25, "frames_located": 1 if status == "failed"
                  else 25,
                  "error_before": {"position_m": 0.0341, "orientation_deg": 0.87}}
    if status != "failed":
        correction["error_after"] = {"position_m": 0.0079, "orientation_deg": 0.37}
    if why:
        correction["failed"] = why
    return {"name": name, "placed": True,
            "target": {"name": "slot", "role": "primary", "position": [0.0, 0.3, 0.6]},
            "pose": {"position": [0.0, 0.0, 1.0], "quat_wxyz": [1, 0, 0, 0]},
            "base": {"x_m": -1.2, "y_m": 0.5, "yaw_rad": 2 * math.pi + 0.5},
            "rating": {"total": 63.3, "dof": 1.0, "resolution": 500.0, "tfv": 0.2,
                       "tav": 0.6, "free": 0.999},
            "correction": correction}


FAILED = "too few fiducials found again in the final frame"
UNCERTAIN = "the sqpnp estimate and the bundle adjustment are 11.5 mm 0.80 deg apart"
SUMMARY = {
    "robots": [
        _placed("r1", "failed", FAILED),
        {**_placed("r2", "uncertain", UNCERTAIN),
         "placements": [{"placed": True}, {"placed": False, "refused": "no view of the site"}]},
        _placed("r3", "corrected"),
        {"name": "r4", "placed": False, "refused": "no view found",
         "pose": {"position": [2.0, 0.0, 1.0], "quat_wxyz": [1, 0, 0, 0]},
         "base": {"x_m": 2.0, "y_m": 0.0, "yaw_rad": 0.0}}],
    "task": {"attempted": True, "object_size_m": 0.2, "steps": 9,
             "success": {"0.2": True, "0.1": True, "0.01": False},
             "final_displacement_m": 0.003, "stopped_by": "max_steps",
             "replacements": [
                 {"step": 4, "robot": "r2", "reason": "lost the panel 3 steps running",
                  "best_rating": 40.8, "placed": False, "placement": 1},
                 {"step": 2, "robot": "r3", "reason": "site rating 0 below 0.5 x 78.4",
                  "best_rating": 46.7, "site_rating": 0.0, "placed": False,
                  "worth_the_move": False}]},
    "timings_s": {"total": 20.0},
}


def test_each_correction_is_told_with_its_status_and_why():
    lines = [placement_line(r["name"], r) for r in SUMMARY["robots"]]
    assert f"correction failed ({FAILED}; 1 of 25 frames located)" in lines[0]
    assert "corrected" not in lines[0]
    assert lines[1].endswith(f"; uncertain 34.1 mm 0.87° -> 7.9 mm 0.37° ({UNCERTAIN})")
    assert lines[2].endswith("; corrected 34.1 mm 0.87° -> 7.9 mm 0.37°")
    assert lines[3] == "r4: not placed (no view found)"
    table = run_screen(SUMMARY).splitlines()
    rows = {line.split()[0]: line for line in table[1:5]}
    for name, status in (("r1", "failed"), ("r2", "uncertain"), ("r3", "corrected")):
        assert f" {status} " in rows[name]
    # the why of each correction not trusted, word for word as summary.json has it
    assert f"r1's correction failed: {FAILED}" in table
    assert f"r2's correction uncertain: {UNCERTAIN}" in table
    assert correction_words(SUMMARY["robots"][2]["correction"]) == "corrected"
    assert not any(line.startswith("r3's correction") for line in table)


def test_placed_and_replaced_robots_are_counted_and_told_alike():
    table = run_screen(SUMMARY).splitlines()
    assert placed_line(SUMMARY["robots"]) == "placed: 3 of 4 robots (r1, r2, r3); not placed: r4"
    assert placed_line(SUMMARY["robots"]) in table
    again = replacement_lines(SUMMARY)
    assert again == [
        "r2 at task step 4 (lost the panel 3 steps running): not placed again "
        "(no view of the site)",
        "r3 at task step 2 (site rating 0 below 0.5 x 78.4): stays; the best view of the "
        "site (RF 46.7) is not worth the move"]
    assert all(line in table for line in again)
    # the final base pose: x, y and the yaw wound back into one turn
    assert "-1.20, 0.50 m, 28.6°" in table[1] and "2.00, 0.00 m, 0.0°" in table[4]


def test_the_overview_marks_come_from_the_summary():
    robots = robot_marks(SUMMARY)
    assert [(r.name, r.placed) for r in robots] == [("r1", True), ("r2", True), ("r3", True),
                                                     ("r4", False)]
    assert robots[3].rgba == UNPLACED_RGBA and robots[0].rgba == PLACED_RGBA
    assert robots[3].label == "r4 (not placed)"
    # the camera in OpenCV's convention: MuJoCo's -z forward is its +z
    assert np.allclose(robots[3].T_world_cam[:3, 2], [0, 0, -1])
    assert [t.label for t in target_marks(SUMMARY)] == ["slot (primary)"]


def test_the_overviews_labels_point_at_what_they_name():
    """A robot's base, projected as the labels are, falls on that robot in the picture."""
    scene = build_scene(load_scenario())
    model, data = scene.model, scene.make_data()
    with Overview(model, framed_points(model, data, [r.body_ids for r in scene.robots])) as view:
        view.render(data)
        seg = view.segmentation(data)
        for robot in scene.robots:
            head = data.xpos[model.body(robot.head_body).id]
            u, v = view.pixels(head[None])[0]
            patch = seg[int(v) - 3:int(v) + 4, int(u) - 3:int(u) + 4].ravel()
            bodies = {int(model.geom_bodyid[g]) for g in patch if g >= 0}
            assert bodies & set(robot.body_ids), robot.name


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_meters_show_on_a_terminal_only_and_never_when_quiet():
    for stream, quiet, shown in ((_Terminal(), False, True), (io.StringIO(), False, False),
                                 (_Terminal(), True, False)):
        screen = Screen(stream, quiet=quiet)
        with screen.meter("task", "step", 40) as advance:
            for k in range(1, 6):
                advance(k)
        screen.line("done")
        text = stream.getvalue()
        assert ("taskcam: task" in text and "step" in text) == shown
        assert ("taskcam: done" in text) == (not quiet)
        if not shown:
            assert "\r" not in text


def test_the_view_hint_serves_the_web_viewer_without_a_display():
    recording = Path("runs/x/run.rrd")
    here = shlex.split(view_command(recording, display=True))
    assert here[1:] == ["runs/x/run.rrd"] and Path(here[0]).name == "rerun"
    headless = view_command(recording, display=False)
    command = shlex.split(headless, comments=True)
    assert command[1:] == ["--web-viewer", "runs/x/run.rrd"]
    assert "http://localhost:9090" in headless
    assert not has_display({}) or sys.platform in ("darwin", "win32")
    assert has_display({"DISPLAY": ":0"}) and has_display({"WAYLAND_DISPLAY": "wayland-0"})


# ------------------------------------------------------------------ a whole run

THREE = """\
name = "three"
[robots]
count = 3
bases = [
  { x = -1.9, y = -0.5, yaw_deg = 15.0 },
  { x = 1.9, y = 0.5, yaw_deg = 195.0 },
  { x = 0.0, y = -3.3, yaw_deg = 90.0 },  # too far to drive within reach of a view
]
[search]
drive_path_m = 0.3
[correction]
enabled = true
[task]
enabled = true
"""


SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "not_placed", "of"), [
    pytest.param(THREE, ["r3"], 3, id="three robots, one out of reach"),
    pytest.param(SCENARIOS / "menagerie_ur5e.toml", [], 2, id="menagerie ur5e"),
])
def test_a_run_tells_one_outcome(tmp_path, scenario, not_placed, of):
    """The screen's lines and the data overview.png is drawn from, held to summary.json
    and scene.xml: in a scene with a robot that cannot be placed, and in the shipped
    scenario whose arms are Menagerie's UR5e."""
    if isinstance(scenario, str):
        (tmp_path / "three.toml").write_text(scenario)
        scenario = tmp_path / "three.toml"
    out = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run([str(TASKCAM), "run", str(scenario), "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    robots = summary["robots"]
    placed = [r["name"] for r in robots if r["placed"]]
    assert summary["placed"] == {"count": len(placed), "of": of, "robots": placed,
                                 "not_placed": [r["name"] for r in robots if not r["placed"]]}
    assert summary["placed"]["not_placed"] == not_placed
    # the screen: the table is the summary's, the stage lines say the same
    assert done.stdout == run_screen(summary, out / "run.rrd")
    stages = done.stderr
    assert f"taskcam: {placed_line(robots)}\n" in stages and placed_line(robots) in done.stdout
    assert f"placed: {of - len(not_placed)} of {of} robots" in stages
    for robot in robots:
        first = robot["placements"][0]
        assert f"taskcam: {placement_line(robot['name'], first)}\n" in stages
        if robot["placed"] and robot.get("correction"):
            status = robot["correction"]["status"]
            assert status in done.stdout.splitlines()[robots.index(robot) + 1]
    for line in replacement_lines(summary):
        assert f"taskcam: {line}\n" in stages and line in done.stdout
    assert "--web-viewer" in done.stdout.splitlines()[-1]  # no display here
    # scene.xml's keyframe "final" holds the bases where summary.json says
    model = mujoco.MjModel.from_xml_path(str(out / "scene.xml"))
    final = model.key("final").qpos
    for robot in robots:
        for key, joint in (("x_m", "base_x"), ("y_m", "base_y"), ("yaw_rad", "base_yaw")):
            address = model.jnt_qposadr[model.joint(f"{robot['name']}/{joint}").id]
            assert robot["base"][key] == pytest.approx(final[address], abs=1e-5)  # as written
    # overview.png's marks: every robot, red where not placed, at the pose it ended
    marks = robot_marks(summary)
    assert [(m.name, m.placed) for m in marks] == [(r["name"], r["placed"]) for r in robots]
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("final").id)
    mujoco.mj_forward(model, data)
    for mark in marks:
        camera = data.cam(f"{mark.name}/left")
        assert np.allclose(mark.T_world_cam[:3, 3], camera.xpos, atol=1e-4)
        assert mark.rgba == (PLACED_RGBA if mark.placed else UNPLACED_RGBA)
        assert mark.base == pytest.approx(tuple(
            final[model.jnt_qposadr[model.joint(f"{mark.name}/{joint}").id]]
            for joint in ("base_x", "base_y", "base_yaw")), abs=1e-5)
    # the targets it labels: those the placed robots ended viewing, in summary.json's roles
    assert [t.label for t in target_marks(summary)] == list(dict.fromkeys(
        f"{r['target']['name']} ({r['target']['role']})" for r in robots if r["placed"]))


@pytest.mark.slow
def test_quiet_prints_the_table_alone_and_a_terminal_sees_the_meters(tmp_path):
    small = tmp_path / "small.toml"
    small.write_text("[robots]\ncount = 1\n[mapping]\nmax_views = 2\n"
                     "[correction]\nenabled = true\n[task]\nenabled = false\n")
    quiet = subprocess.run([str(TASKCAM), "run", str(small), "--out", str(tmp_path / "q"),
                            "--quiet", "--no-record"], capture_output=True, text=True,
                           timeout=900)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr
    summary = json.loads((tmp_path / "q" / "summary.json").read_text())
    assert quiet.stdout == run_screen(summary)
    # on a terminal (a pseudo-terminal for stderr): the move's meter counts frames
    leader, follower = pty.openpty()  # a terminal 100 columns wide
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
    with subprocess.Popen([str(TASKCAM), "run", str(small), "--out", str(tmp_path / "t"),
                           "--no-record"], stdout=subprocess.DEVNULL, stderr=follower) as run:
        os.close(follower)
        seen = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:
                break
            if not chunk:
                break
            seen += chunk
        assert run.wait(timeout=900) == 0
    os.close(leader)
    text = seen.decode(errors="replace")
    assert "r1 moving, correcting its pose" in text and "frame" in text and "\r" in text
