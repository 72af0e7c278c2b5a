"""What ``taskcam run`` tells its user on one screen: a line per stage as it ends, and at
the end an aligned table of the outcome (per robot its target, rating, distance and
correction; the task per tolerance; the stages' times; how to open the recording).

Everything here reads ``summary.json``'s records (docs/run-directory.md): a run's
outcome can be printed again from its directory.
"""

from __future__ import annotations

import math
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

RATING_TERMS = ("dof", "resolution", "tfv", "tav", "free")  # eq. 1's factors


def distance_m(placement: dict[str, Any]) -> float | None:
    """How far the camera (its final pose) is from the point of its target (m)."""
    target, pose = placement.get("target"), placement.get("pose")
    if not target or not pose:
        return None
    return math.dist(pose["position"], target["position"])


def _error(e: dict[str, float] | None) -> str:
    return "-" if not e else f"{1000 * e['position_m']:.1f} mm {e['orientation_deg']:.2f}°"


def placement_line(name: str, placement: dict[str, Any]) -> str:
    """One robot's placement, in a line: its target, rating, distance and correction."""
    if not placement.get("placed"):
        return f"{name}: not placed ({placement.get('refused', 'no view found')})"
    target, rating = placement["target"], placement["rating"]
    line = (f"{name}: placed for {target['name']} ({target['role']}), RF "
            f"{rating['total']:.1f}, {distance_m(placement):.2f} m away")
    correction = placement.get("correction")
    if correction and correction.get("error_after"):
        line += (f"; corrected {_error(correction['error_before'])} -> "
                 f"{_error(correction['error_after'])}")
    return line


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


def view_command(recording: Path) -> str:
    """The command that opens ``recording`` in the rerun viewer: the viewer installed
    beside this Python (the project's environment; relative to here where it lies
    below), else the one on the PATH."""
    beside = Path(sys.executable).parent / "rerun"
    viewer = "rerun"
    if beside.exists():
        viewer = str(beside)
        if beside.is_relative_to(Path.cwd()):
            viewer = str(beside.relative_to(Path.cwd()))
    return f"{shlex.quote(viewer)} {shlex.quote(str(recording))}"


def outcome(summary: dict[str, Any], recording: Path | None = None) -> str:
    """The outcome table of a run's ``summary``; with its ``recording``, how to open it."""
    # the pose the robot believes its camera has, off the truth: as commanded (before
    # correction), and as corrected
    head = ["robot", "target", "RF", *RATING_TERMS, "distance", "pose error",
            "corrected"]
    rows = [head]
    for r in summary["robots"]:
        if not r.get("placed"):
            rows.append([r["name"], "not placed", *["-"] * (len(head) - 2)])
            continue
        rating, correction = r["rating"], r.get("correction") or {}
        rows.append([r["name"], f"{r['target']['name']} ({r['target']['role']})",
                     f"{rating['total']:.1f}", *(f"{rating[k]:.3g}" for k in RATING_TERMS),
                     f"{distance_m(r):.2f} m",
                     _error(correction.get("error_before", r.get("positioning_error"))),
                     _error(correction.get("error_after"))])
    lines = _table(rows)
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
