"""What ``taskcam run`` tells its user on one screen: a line per stage as it ends, and at
the end an aligned table of the outcome (per robot its target, rating, distance and
correction; the task per tolerance; the stages' times; how to open the recording).

Everything here reads ``summary.json``'s records (docs/run-directory.md): a run's
outcome can be printed again from its directory.
"""

from __future__ import annotations

import math
import os
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

RATING_TERMS = ("dof", "resolution", "tfv", "tav", "free")  # eq. 1's factors
WEB_VIEWER_PORT = 9090  # rerun --web-viewer serves here unless told another port


def distance_m(placement: dict[str, Any]) -> float | None:
    """How far the camera (its final pose) is from the point of its target (m)."""
    target, pose = placement.get("target"), placement.get("pose")
    if not target or not pose:
        return None
    return math.dist(pose["position"], target["position"])


def _error(e: dict[str, float] | None) -> str:
    return "-" if not e else f"{1000 * e['position_m']:.1f} mm {e['orientation_deg']:.2f}°"


def correction_words(correction: dict[str, Any] | None) -> str | None:
    """A correction's status and why, in ``summary.json``'s words: ``corrected``,
    ``uncertain: <why>`` or ``failed: <why>`` (None: no correction was made)."""
    if not correction or "status" not in correction:
        return None
    why = correction.get("failed")
    return correction["status"] if not why else f"{correction['status']}: {why}"


def _correction_clause(correction: dict[str, Any] | None) -> str:
    """The correction in a placement's line: its status, the pose error before and after
    (off the truth) and, unless corrected, why."""
    if not correction or "status" not in correction:
        return ""
    status, why = correction["status"], correction.get("failed")
    if status == "failed":
        return (f"; correction failed ({why}; {correction.get('frames_located', 0)} of "
                f"{correction.get('frames', 0)} frames located): the commanded pose stands")
    clause = (f"; {status} {_error(correction.get('error_before'))} -> "
              f"{_error(correction.get('error_after'))}")
    return clause + (f" ({why})" if why else "")


def placement_words(placement: dict[str, Any], again: bool = False) -> str:
    """A placement in words: its target, rating, distance and correction, or why it
    was not placed (``again``: a re-placement during the task)."""
    if not placement.get("placed"):
        return (f"not placed{' again' if again else ''} "
                f"({placement.get('refused', 'no view found')})")
    target, rating = placement["target"], placement["rating"]
    return (f"placed{' again' if again else ''} for {target['name']} ({target['role']}), "
            f"RF {rating['total']:.1f}, {distance_m(placement):.2f} m away"
            + _correction_clause(placement.get("correction")))


def placement_line(name: str, placement: dict[str, Any]) -> str:
    """One robot's placement, in a line: its target, rating, distance and correction."""
    return f"{name}: {placement_words(placement)}"


def placed_line(robots: Sequence[dict[str, Any]]) -> str:
    """How many robots were placed of how many, and which were not."""
    placed = [r["name"] for r in robots if r.get("placed")]
    missing = [r["name"] for r in robots if not r.get("placed")]
    line = f"placed: {len(placed)} of {len(robots)} robots"
    line += f" ({', '.join(placed)})" if placed else ""
    return line + (f"; not placed: {', '.join(missing)}" if missing else "")


def replacement_line(record: dict[str, Any], robot: dict[str, Any] | None) -> str:
    """A re-placement during the task (``task.replacements``' ``record``), in a line:
    the robot, the task step, why, and what came of it (``robot``: the robot's record,
    whose ``placements`` hold the new placement)."""
    head = f"{record['robot']} at task step {record['step']} ({record['reason']}): "
    if "placement" in record and robot is not None:
        return head + placement_words(robot["placements"][record["placement"]], again=True)
    if record.get("worth_the_move") is False:
        return (head + f"stays; the best view of the site (RF {record['best_rating']:.1f}) "
                "is not worth the move")
    return head + "stays; no view of the site rates"


def replacement_lines(summary: dict[str, Any]) -> list[str]:
    """Every re-placement of the task in ``summary``, a line each, in order."""
    task = summary.get("task") or {}
    robots = {r["name"]: r for r in summary["robots"]}
    return [replacement_line(rec, robots.get(rec["robot"]))
            for rec in task.get("replacements", [])]


def base_words(base: dict[str, float] | None) -> str:
    """A base pose on the floor: x, y (m) and yaw (deg)."""
    if not base:
        return "-"
    yaw = math.degrees(math.remainder(base["yaw_rad"], 2 * math.pi))  # the joint may wind
    return f"{base['x_m']:.2f}, {base['y_m']:.2f} m, {yaw:.1f}°"


def _percent(tolerance: str) -> str:
    return f"{100 * float(tolerance):g} %"


def task_line(task: dict[str, Any] | None) -> str:
    """The task's outcome in a line: per tolerance, the final displacement and steps."""
    if not task or not task.get("attempted"):
        return "task: not run"
    met = ", ".join(f"{_percent(t)} {'met' if ok else 'missed'}"
                    for t, ok in task["success"].items())
    final = task.get("final_displacement_m")
    where = "" if final is None else f"; final displacement {1000 * final:.2f} mm"
    return f"task: {met}{where} after {task['steps']} step(s) ({task['stopped_by']})"


def look_line(rows: dict[str, dict[str, Any]], frame: dict[str, Any]) -> str:
    """What each placed camera sighted, in a line, and which targets the frame rests on."""
    seen = "; ".join(f"{name} sighted " + (", ".join(s["target"] for s in row["sightings"])
                                          or "nothing")
                     for name, row in rows.items() if "sightings" in row)
    located = ", ".join(frame.get("targets", {})) or "none (the nominal place)"
    return f"look: {seen or 'no camera placed'}; the target frame from {located}"


def mapping_line(mapping: dict[str, Any]) -> str:
    entropy = mapping["region_entropy_bits"]
    return (f"mapping: {mapping['views_total']} views, the region's entropy "
            f"{entropy['before']:.2f} -> {entropy['after']:.2f} bits a voxel "
            f"(stopped by {mapping['stopped_by']})")


def _table(rows: Sequence[Sequence[str]]) -> list[str]:
    """Rows aligned in columns (the first left, the rest right), two spaces apart."""
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    return ["  ".join(cell.ljust(w) if c == 0 else cell.rjust(w)
                      for c, (cell, w) in enumerate(zip(row, widths, strict=True))).rstrip()
            for row in rows]


def has_display(environ: Mapping[str, str] | None = None) -> bool:
    """Whether a desktop viewer can open here: always on macOS and Windows, elsewhere
    with an X11 or Wayland display (``DISPLAY``, ``WAYLAND_DISPLAY``)."""
    env = os.environ if environ is None else environ
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def view_command(recording: Path, display: bool | None = None) -> str:
    """The command that opens ``recording`` in the rerun viewer: the viewer installed
    beside this Python (the project's environment; relative to here where it lies
    below), else the one on the PATH. Without a display (``display`` None: this
    machine's, :func:`has_display`) it serves rerun's web viewer to a browser instead,
    on its default port."""
    beside = Path(sys.executable).parent / "rerun"
    viewer = "rerun"
    if beside.exists():
        viewer = str(beside)
        if beside.is_relative_to(Path.cwd()):
            viewer = str(beside.relative_to(Path.cwd()))
    if has_display() if display is None else display:
        return f"{shlex.quote(viewer)} {shlex.quote(str(recording))}"
    return (f"{shlex.quote(viewer)} --web-viewer {shlex.quote(str(recording))}"
            f"  # no display here: open http://localhost:{WEB_VIEWER_PORT} in a browser")


def run_screen(summary: dict[str, Any], recording: Path | None = None) -> str:
    """The outcome table of a run's ``summary``; with its ``recording``, how to open it."""
    # the pose the robot believes its camera has, off the truth: as commanded (before
    # correction), and as corrected
    head = ["robot", "target", "RF", *RATING_TERMS, "distance", "pose error",
            "corrected", "correction", "base (x, y, yaw)"]
    rows = [head]
    for r in summary["robots"]:
        if not r.get("placed"):
            rows.append([r["name"], "not placed", *["-"] * (len(head) - 3),
                         base_words(r.get("base"))])
            continue
        rating, correction = r["rating"], r.get("correction") or {}
        rows.append([r["name"], f"{r['target']['name']} ({r['target']['role']})",
                     f"{rating['total']:.1f}", *(f"{rating[k]:.3g}" for k in RATING_TERMS),
                     f"{distance_m(r):.2f} m",
                     _error(correction.get("error_before", r.get("positioning_error"))),
                     _error(correction.get("error_after")),
                     correction.get("status", "-"), base_words(r.get("base"))])
    lines = _table(rows) + ["", placed_line(summary["robots"])]
    for r in summary["robots"]:  # why a correction is not trusted, as summary.json says
        correction = r.get("correction") if r.get("placed") else None
        if correction and correction.get("status") not in (None, "corrected"):
            lines.append(f"{r['name']}'s correction {correction_words(correction)}")
    lines += replacement_lines(summary)
    task = summary.get("task")
    if task and task.get("attempted"):
        tolerances = list(task["success"])
        final = task.get("final_displacement_m")
        lines += [""] + _table([
            ["task", *(f"{_percent(t)} of {1000 * task['object_size_m']:g} mm"
                       for t in tolerances), "final displacement", "steps"],
            ["", *("met" if task["success"][t] else "missed" for t in tolerances),
             "-" if final is None else f"{1000 * final:.2f} mm", str(task["steps"])]])
        lines.append(f"stopped: {task['stopped_by']}")
    else:
        lines += ["", "task: not run"]
    times = {k: v for k, v in summary["timings_s"].items() if v >= 0.05 and k != "total"}
    lines += ["", "time: " + ", ".join(f"{k} {v:.1f} s" for k, v in times.items())
              + f"; total {summary['timings_s'].get('total', sum(times.values())):.1f} s"]
    if recording is not None:
        lines.append(f"view: {view_command(recording)}")
    return "\n".join(lines) + "\n"
