"""Tables from a results database: success rates with Wilson 95 % intervals, in the
layout of the paper's Table 1 (tolerance by placement, density by secondary targets),
next to the paper's numbers; as Markdown, CSV and a PNG chart (report_chart.py)."""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from taskcam.placement import method_label
from taskcam.sim.experiments.results import Results, ResultsError

Z95 = 1.959963984540054

# The paper's Table 1 (%): (placement, secondary, density, tolerance) -> success; "<<1"
# where it prints that.
PAPER: dict[tuple[str, bool, float, float], str] = {}
_TABLE1: dict[float, dict[str, tuple[tuple[int | str, int | str], ...]]] = {
    0.2: {"rating": ((100, 100), (76, 95), (13, 25)),
          "biased_random": ((45, 58), (16, 28), (5, 9))},
    0.1: {"rating": ((99, 100), (63, 86), (10, 18)),
          "biased_random": ((23, 30), (8, 15), (3, 4))},
    0.01: {"rating": ((97, 99), (30, 52), (3, 7)),
           "biased_random": ((1, 1), ("<<1", "<<1"), ("<<1", "<<1"))},
}
for _tol, _rows in _TABLE1.items():
    for _placement, _cells in _rows.items():
        for _density, (_without, _with) in zip((0.05, 0.2, 0.35), _cells, strict=True):
            PAPER[(_placement, False, _density, _tol)] = str(_without)
            PAPER[(_placement, True, _density, _tol)] = str(_with)

DIFFICULTY = {0.2: "easy", 0.1: "medium", 0.01: "hard"}


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (fractions)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half))  # rounding


@dataclass(frozen=True)
class Cell:
    """One method at one density and tolerance."""

    method: str
    placement: str
    secondary: bool
    density: float  # requested
    achieved_density: float  # mean over the trials
    tolerance: float
    trials: int
    successes: int

    @property
    def rate(self) -> float:
        return self.successes / self.trials if self.trials else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        return wilson(self.successes, self.trials)

    @property
    def paper(self) -> str | None:
        return PAPER.get((self.placement, self.secondary, round(self.density, 4),
                          self.tolerance))


def cells(db: str | Path) -> list[Cell]:
    """Success counts per method, density and tolerance, from the database (opened
    read-only). ResultsError if it is not a results database or holds no trial yet."""
    wanted = "a database written by taskcam sweep, with at least one trial"
    with Results(db, readonly=True) as results:
        description = results.description() or {}
        try:
            sweep = description["sweep"]
            densities = sweep["densities"]
            order = {m["name"]: i for i, m in enumerate(sweep["methods"])}
        except (KeyError, TypeError, IndexError):
            raise ResultsError(results.path, "a results database without a sweep's "
                               "description", wanted) from None
        achieved = dict(results.db.execute(
            "SELECT density_index, AVG(achieved_density) FROM trials GROUP BY density_index"))
        rows = results.db.execute(
            "SELECT o.method, o.placement, o.secondary, s.density_index, s.tolerance, "
            "COUNT(*), SUM(s.success) FROM successes s JOIN outcomes o USING "
            "(density_index, trial, method) GROUP BY o.method, s.density_index, s.tolerance")
        try:
            out = [Cell(method, placement, bool(secondary), densities[d], achieved[d], tol, n, ok)
                   for method, placement, secondary, d, tol, n, ok in rows]
        except (KeyError, IndexError):
            raise ResultsError(results.path, "a results database whose trials do not match "
                               "its sweep's densities", wanted) from None
    if not out:
        raise ResultsError(results.path, "a results database without a finished trial", wanted)
    return sorted(out, key=lambda c: (-c.tolerance, order.get(c.method, 99), c.density))


def trial_records(db: str | Path) -> list[tuple[float, dict[str, Any]]]:
    """Every trial's requested density and its record, in the sweep's order (the
    database opened read-only)."""
    with Results(db, readonly=True) as results:
        return [(density, json.loads(record)) for density, record in results.db.execute(
            "SELECT density, record FROM trials ORDER BY density_index, trial")]


def elevation_bands(db: str | Path) -> dict[float, list[float]]:
    """Each requested density's mean blocked share per 10 deg elevation band (10-20 deg
    first), over the trials that recorded it (older sweeps did not)."""
    by_density: dict[float, list[list[float]]] = defaultdict(list)
    for density, record in trial_records(db):
        shares = record.get("blocked_by_elevation")
        if shares:
            by_density[density].append(shares)
    return {d: [sum(col) / len(col) for col in zip(*rows, strict=True)]
            for d, rows in sorted(by_density.items())}


def radius_shares(db: str | Path) -> dict[float, list[list[float]]]:
    """Each requested density's mean [radius (m), blocked share within it of the slot],
    over the trials that recorded them (older sweeps did not)."""
    by_density: dict[float, list[list[list[float]]]] = defaultdict(list)
    for density, record in trial_records(db):
        if record.get("density_by_radius"):
            by_density[density].append(record["density_by_radius"])
    return {d: [[rows[0][k][0], sum(r[k][1] for r in rows) / len(rows)]
                for k in range(len(rows[0]))] for d, rows in sorted(by_density.items())}


def radius_markdown(shares: dict[float, list[list[float]]]) -> str:
    """The blocked share within each radius of the slot, a row per requested density."""
    if not shares:
        return ""
    radii = [r for r, _ in next(iter(shares.values()))]
    head = ["Density"] + [f"{r:g} m" for r in radii]
    lines = ["Blocked share (%) within each radius of the slot (the depth of field's near "
             "limit first, its far limit last), mean over the trials", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join([f"{100 * d:g} %"] + [f"{100 * v:.1f}" for _, v in rows]) + " |"
              for d, rows in shares.items()]
    return "\n".join(lines) + "\n"


def step_limit(db: str | Path) -> dict[tuple[str, float], tuple[int, int]]:
    """Per method and requested density: how many attempted tasks ended at the sweep's
    step limit (``max_steps``), of how many attempted."""
    with Results(db, readonly=True) as results:
        rows = results.db.execute(
            "SELECT o.method, t.density, SUM(o.stopped_by = 'max_steps'), COUNT(*) "
            "FROM outcomes o JOIN trials t USING (density_index, trial) "
            "WHERE o.steps > 0 GROUP BY o.method, t.density ORDER BY o.method, t.density")
        return {(m, d): (int(at), int(n)) for m, d, at, n in rows}


def step_limit_markdown(limits: dict[tuple[str, float], tuple[int, int]]) -> str:
    """The tasks that ended at the step limit, per method and density (the step budget
    must not be what limits success)."""
    if not limits:
        return ""
    by_method: dict[str, list[str]] = defaultdict(list)
    for (method, density), (at, n) in limits.items():
        by_method[method].append(f"{at} of {n} at {100 * density:g} %")
    return ("Tasks that ended at the step limit (`task.max_steps`), of those attempted: "
            + "; ".join(f"{m} {', '.join(v)}" for m, v in by_method.items()) + "\n")


def failed_trials(db: str | Path) -> list[tuple[int, int, int, float, int, str]]:
    """The trials stored as failed (their worker died every time): density index, trial,
    seed, requested density, attempts, reason."""
    with Results(db, readonly=True) as results:
        return results.failures()


def failed_markdown(failed: list[tuple[int, int, int, float, int, str]]) -> str:
    """The failed trials, each with why (they count in no table above)."""
    if not failed:
        return ""
    return (f"Failed trials, in no table above: {len(failed)}\n\n"
            + "".join(f"- trial {trial} at {100 * density:g} % (density index {d}, seed "
                      f"{seed}): {reason}\n" for d, trial, seed, density, _, reason in failed))


def bands_markdown(bands: dict[float, list[float]]) -> str:
    """The blocked share per elevation band, a row per requested density."""
    if not bands:
        return ""
    count = len(next(iter(bands.values())))
    head = ["Density"] + [f"{10 + 10 * k}-{20 + 10 * k} deg" for k in range(count)]
    lines = ["Blocked share (%) of each elevation band above the target the density is "
             "counted about, mean over the trials", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    lines += ["| " + " | ".join([f"{100 * d:g} %"] + [f"{100 * v:.1f}" for v in shares]) + " |"
              for d, shares in bands.items()]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class Views:
    """What one method's cameras did at one requested density, over its trials: the
    evidence behind a cell (why a rate is what it is)."""

    method: str
    density: float
    trials: int
    placed: float  # cameras placed, mean a trial
    saw: float  # cameras that saw the target they were placed for, mean a trial
    blind: int  # trials in which no camera saw its target
    replacements: float  # cameras placed again during the task, mean a trial
    final_mm: tuple[float, float] | None  # attempted tasks' final displacement (mm):
    # median and 90th percentile (numpy's linear interpolation)
    steps: tuple[float, float] | None  # attempted tasks' steps: median, 90th percentile
    faced: float | None = None  # the density placed cameras faced (within their distance
    # of the slot), median; None where the records have none
    nearer: int = 0  # placed cameras nearer the slot than the radius the density is held from


def camera_views(db: str | Path) -> list[Views]:
    """Per method and requested density, from the trials' records: how many cameras were
    placed and saw their target, how often none did, the re-placements, and where the
    attempted tasks ended and after how many steps."""
    import numpy as np

    rows: dict[tuple[str, float], list[dict[str, Any]]] = defaultdict(list)
    held_from: dict[tuple[str, float], list[float]] = defaultdict(list)
    for density, record in trial_records(db):
        for method in record["methods"]:
            if "robots" in method:  # a record that kept its robots (taskcam sweep's)
                rows[(method["method"], density)].append(method)
                held = record.get("density_by_radius")  # 0: none recorded, none counted
                held_from[(method["method"], density)].append(held[0][0] if held else 0.0)
    out = []
    for (name, density), runs in sorted(rows.items()):
        robots = [m["robots"] for m in runs]
        ended = [m for m in runs
                 if m.get("attempted") and m.get("final_displacement_m") is not None]
        finals = [1e3 * m["final_displacement_m"] for m in ended]
        steps = [m["steps"] for m in ended]
        faced = [r["faced_density"] for rs in robots for r in rs if "faced_density" in r]
        near = held_from[(name, density)]
        nearer = sum(r["slot_distance_m"] < radius for rs, radius in zip(robots, near, strict=True)
                     for r in rs if "slot_distance_m" in r)
        out.append(Views(
            name, density, len(runs),
            sum(sum(bool(r["placed"]) for r in rs) for rs in robots) / len(runs),
            sum(sum(bool(r["placed"] and r["seen"]) for r in rs) for rs in robots) / len(runs),
            sum(not any(r["placed"] and r["seen"] for r in rs) for rs in robots),
            sum(int(m.get("replacements") or 0) for m in runs) / len(runs),
            (float(np.median(finals)), float(np.percentile(finals, 90))) if finals else None,
            (float(np.median(steps)), float(np.percentile(steps, 90))) if steps else None,
            float(np.median(faced)) if faced else None, nearer))
    return out


def views_markdown(views: list[Views]) -> str:
    """The cameras' record per method and density, as a table."""
    if not views:
        return ""
    lines = ["What each method's cameras did (the trials' records): cameras placed and "
             "cameras that saw their target, mean a trial (of the robots); trials where "
             "none saw one; re-placements during the task, mean a trial; the attempted "
             "tasks' final displacement and steps, median / 90th percentile; the density "
             "the placed cameras faced (blocked within their distance of the slot), "
             "median, and how many stood nearer than the density is held from", "",
             "| method | density | trials | placed | saw target | none saw | "
             "re-placements | final mm | steps | faced % | nearer |",
             "|---|---|---:|---:|---:|---:|---:|---|---|---:|---:|"]
    for v in views:
        final = "-" if v.final_mm is None else f"{v.final_mm[0]:.2f} / {v.final_mm[1]:.2f}"
        steps = "-" if v.steps is None else f"{v.steps[0]:g} / {v.steps[1]:g}"
        faced = "-" if v.faced is None else f"{100 * v.faced:.1f}"
        lines.append(f"| {v.method} | {100 * v.density:g} % | {v.trials} | {v.placed:.2f} | "
                     f"{v.saw:.2f} | {percent_of(v.blind, v.trials)} | "
                     f"{v.replacements:.2f} | {final} | {steps} | {faced} | {v.nearer} |")
    return "\n".join(lines) + "\n"


def percent_of(count: int, total: int) -> str:
    """``count`` of ``total`` in whole percent."""
    return f"{round(100 * count / total)} %" if total else "-"


def percent(successes: int, trials: int) -> str:
    """A success rate as ``rate [Wilson 95 % interval]``, in whole percent."""
    lo, hi = wilson(successes, trials)
    return f"{100 * successes / trials:.0f} [{100 * lo:.0f}-{100 * hi:.0f}]"


def _percent(c: Cell) -> str:
    return percent(c.successes, c.trials)


def markdown(table: list[Cell]) -> str:
    """Table 1's layout: a block per tolerance, a row per placement, a column per density
    and secondary targets; each cell ours % [Wilson 95 %] (paper %)."""
    densities = sorted({c.density for c in table})
    by_key: dict[tuple[float, str, float, bool], Cell] = {}
    extra = []
    for c in table:
        key = (c.tolerance, c.placement, c.density, c.secondary)
        if key in by_key:
            extra.append(c)  # a second method with the same placement: listed below
        else:
            by_key[key] = c
    placements = list(dict.fromkeys(c.placement for c in table))
    n = sorted({c.trials for c in table})
    scenes = f"{n[0]}" if len(n) == 1 else f"{n[0]}-{n[-1]}"
    head = ["Tolerance", "Placement"] + [f"{100 * d:g} % {'with' if w else 'without'} sec."
                                         for d in densities for w in (False, True)]
    lines = [f"Success % [Wilson 95 % interval] (paper's %), {scenes} paired scenes per density",
             "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for tol in sorted({c.tolerance for c in table}, reverse=True):
        for placement in placements:
            row = [f"{100 * tol:g} % ({DIFFICULTY.get(tol, '')})", method_label(placement)]
            for d in densities:
                for with_secondary in (False, True):
                    cell = by_key.get((tol, placement, d, with_secondary))
                    if cell is None:
                        row.append("-")
                    else:
                        paper = f" ({cell.paper})" if cell.paper is not None else ""
                        row.append(_percent(cell) + paper)
            lines.append("| " + " | ".join(row) + " |")
    achieved = {c.density: c.achieved_density for c in table}
    lines += ["", "Occlusion density achieved (mean): " + ", ".join(
        f"{100 * d:g} % -> {100 * achieved[d]:.1f} %" for d in densities)]
    if extra:
        lines += ["", "Further methods: " + "; ".join(
            f"{c.method} at {100 * c.density:g} %, {100 * c.tolerance:g} %: {_percent(c)}"
            for c in extra)]
    return "\n".join(lines) + "\n"


def write_rows(path: Path, header: list[str], rows: Iterable[list[Any]]) -> None:
    """A CSV file: ``header``, then ``rows``."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def write_csv(table: list[Cell], path: Path) -> None:
    write_rows(path, ["method", "placement", "secondary", "density", "achieved_density",
                      "tolerance", "trials", "successes", "success_pct", "wilson_low_pct",
                      "wilson_high_pct", "paper_pct"],
               ([c.method, c.placement, int(c.secondary), c.density,
                 round(c.achieved_density, 5), c.tolerance, c.trials, c.successes,
                 round(100 * c.rate, 2), round(100 * c.interval[0], 2),
                 round(100 * c.interval[1], 2), c.paper or ""] for c in table))
