"""The pose corrections a sweep's trials record, and what they were where two
sweeps of the same scenes end differently.

Each method's outcome in a trial keeps, per robot, every move's correction: its status
(``corrected``, ``uncertain``, ``failed``) and the camera's error against the simulator's
truth after it. A move is within the bound when that error is within 3 mm and 0.2°
(the pose-correction benchmark's). Beside a paired comparison (sim/experiments/paired.py)
the tasks are grouped by which sweep met a tolerance: if the tasks only the second sweep
met are the ones whose corrections left the cameras beyond the bound, the corrections'
residual is what the first sweep's loop costs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taskcam.sim.experiments.results import Results

BOUND_M, BOUND_DEG = 0.003, 0.2  # a correction's error that counts as within the bound


@dataclass(frozen=True)
class TaskCorrections:
    """One method's task in one trial: its moves' corrections and how it ended."""

    errors: list[tuple[float, float] | None]  # each move's error after (m, deg); None: failed
    statuses: list[str]
    final_displacement_m: float | None

    @property
    def worst(self) -> tuple[float, float] | None:
        """The largest position and rotation error (m, deg) of any camera's last
        correction; None if a correction failed (the commanded pose stood) or none ran."""
        if not self.errors or any(e is None for e in self.errors):
            return None
        found = [e for e in self.errors if e is not None]
        return max(e[0] for e in found), max(e[1] for e in found)

    @property
    def within(self) -> bool:
        """Every camera's last correction within the bound."""
        worst = self.worst
        return worst is not None and worst[0] <= BOUND_M and worst[1] <= BOUND_DEG


def read(db: str | Path) -> dict[tuple[str, int, int], TaskCorrections]:
    """Every task's corrections by (method, density index, trial); empty if the sweep
    ran without correction."""
    out: dict[tuple[str, int, int], TaskCorrections] = {}
    with Results(db, readonly=True) as results:
        rows = results.db.execute("SELECT density_index, trial, record FROM trials").fetchall()
    for d, trial, text in rows:
        for outcome in json.loads(text)["methods"]:
            last = [r["corrections"][-1] for r in outcome["robots"] if r.get("corrections")]
            if not last:
                continue
            errors = [None if c["error_after"] is None else
                      (c["error_after"]["position_m"], c["error_after"]["orientation_deg"])
                      for c in last]
            out[(outcome["method"], int(d), int(trial))] = TaskCorrections(
                errors, [c["status"] for c in last], outcome.get("final_displacement_m"))
    return out


def _mm(values: list[float]) -> str:
    return f"{1e3 * np.median(values):.2f} / {1e3 * np.percentile(values, 90):.2f}" if values \
        else "-"


def markdown(first: str | Path, second: str | Path, tolerance: float) -> str:
    """The first sweep's corrections by method, and its tasks grouped by which sweep met
    ``tolerance``, as Markdown; empty if the first sweep ran without correction."""
    tasks = read(first)
    if not tasks:
        return ""
    lines = [f"Pose corrections in {Path(first).stem} (each camera's last correction in "
             f"each task; within: {1e3 * BOUND_M:g} mm and {BOUND_DEG:g}°).", "",
             "| method | tasks | cameras | corrected | uncertain | failed | all within "
             "| worst camera: median / 90th pct. mm |", "|---|---|---|---|---|---|---|---|"]
    for method in sorted({k[0] for k in tasks}):
        mine = [t for k, t in tasks.items() if k[0] == method]
        statuses = [s for t in mine for s in t.statuses]
        worst = [t.worst[0] for t in mine if t.worst is not None]
        lines.append(f"| {method} | {len(mine)} | {len(statuses)} | "
                     f"{statuses.count('corrected')} | {statuses.count('uncertain')} | "
                     f"{statuses.count('failed')} | {sum(t.within for t in mine)} | "
                     f"{_mm(worst)} |")
    with Results(first, readonly=True) as a, Results(second, readonly=True) as b:
        met_a, met_b = a.successes(), b.successes()
    groups: dict[tuple[bool, bool], list[TaskCorrections]] = {}
    for (method, d, tol), by_trial in met_a.items():
        if abs(tol - tolerance) > 1e-9:
            continue
        other = met_b.get((method, d, tol), {})
        for trial, ok in by_trial.items():
            if trial in other and (method, d, trial) in tasks:
                groups.setdefault((ok, other[trial]), []).append(tasks[(method, d, trial)])
    lines += ["", f"The same tasks by which sweep met the {100 * tolerance:g} % tolerance "
              f"(first: {Path(first).stem}, second: {Path(second).stem}).", "",
              "| met by | tasks | all cameras within | a correction failed "
              "| worst camera: median / 90th pct. mm | final displacement: median / 90th "
              "pct. mm |", "|---|---|---|---|---|---|"]
    names = {(True, True): "both", (True, False): "first only", (False, True): "second only",
             (False, False): "neither"}
    for key, name in names.items():
        group = groups.get(key, [])
        if not group:
            continue
        worst = [t.worst[0] for t in group if t.worst is not None]
        final = [t.final_displacement_m for t in group if t.final_displacement_m is not None]
        lines.append(f"| {name} | {len(group)} | {sum(t.within for t in group)} | "
                     f"{sum(t.worst is None for t in group)} | {_mm(worst)} | {_mm(final)} |")
    return "\n".join(lines) + "\n"
