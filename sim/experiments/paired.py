"""Two sweeps on the same scenes, compared cell by cell: the paired difference in success.

Two results databases whose sweeps share the seed and the densities hold the same
scenes trial for trial (a trial's scene is seeded from the sweep's seed, the density
and the trial alone), whatever else differs (e.g. positioning errors and their
correction on in one, off in the other). For every method, density and tolerance both
ran, over the trials both finished: the successes of each, the pairs where only one
succeeded, the difference in success rate with its 95 % interval for paired
proportions (Newcombe 1998, method 10: Wilson intervals of the two rates combined
through their correlation), and the exact McNemar test. With few scenes an interval
that holds zero does not show "no change": it shows which changes the data exclude,
given as the margin (the larger of the interval's two ends, in points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from taskcam.sim.experiments.orderings import mcnemar
from taskcam.sim.experiments.report import Z95, wilson
from taskcam.sim.experiments.results import Results, ResultsError


def paired_interval(both: int, first_only: int, second_only: int, neither: int,
                    z: float = Z95) -> tuple[float, float]:
    """95 % interval of the difference (first's success rate less the second's) from
    paired outcomes counted as: both succeeded, only the first, only the second,
    neither (Newcombe 1998, method 10, his continuity-corrected correlation)."""
    n = both + first_only + second_only + neither
    if n == 0:
        return -1.0, 1.0
    p1, p2 = (both + first_only) / n, (both + second_only) / n
    l1, u1 = wilson(both + first_only, n, z)
    l2, u2 = wilson(both + second_only, n, z)
    rows = (both + first_only) * (second_only + neither)
    cols = (both + second_only) * (first_only + neither)
    cross = both * neither - first_only * second_only
    if rows * cols == 0:
        phi = 0.0
    elif cross > 0:
        phi = max(cross - n / 2, 0.0) / math.sqrt(rows * cols)
    else:
        phi = cross / math.sqrt(rows * cols)
    d = p1 - p2
    low = math.sqrt(max((p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2, 0))
    high = math.sqrt(max((u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2, 0))
    return max(d - low, -1.0), min(d + high, 1.0)


@dataclass(frozen=True)
class PairedCell:
    """One method, density and tolerance in both sweeps, over the trials both finished."""

    method: str
    density: float
    tolerance: float
    both: int
    first_only: int
    second_only: int
    neither: int

    @property
    def n(self) -> int:
        return self.both + self.first_only + self.second_only + self.neither

    @property
    def difference(self) -> float:
        """First's success rate less the second's."""
        return (self.first_only - self.second_only) / self.n

    @property
    def interval(self) -> tuple[float, float]:
        return paired_interval(self.both, self.first_only, self.second_only, self.neither)

    @property
    def p(self) -> float:
        """Exact McNemar p-value (two-sided)."""
        return mcnemar(self.first_only, self.second_only)

    @property
    def excluded_margin(self) -> float:
        """The smallest change (either way, a fraction) the interval excludes."""
        low, high = self.interval
        return max(abs(low), abs(high))


def _successes(db: str | Path) -> tuple[dict[str, Any], dict[tuple[str, int, float],
                                                              dict[int, bool]]]:
    with Results(db, readonly=True) as results:
        description = results.description() or {}
        sweep = description.get("sweep")
        if not isinstance(sweep, dict) or "densities" not in sweep:
            raise ResultsError(Path(results.path), "a results database without a sweep's "
                               "description", "a database written by taskcam sweep")
        sweep = {**sweep, "scenes": description.get("scenes")}  # the scene generator
        return sweep, results.successes()


def compare(first: str | Path, second: str | Path) -> list[PairedCell]:
    """Every cell both databases hold, paired over the trials both finished.
    ResultsError if either is not a sweep's database, or their scenes differ (another
    seed or other densities)."""
    sweep_a, a = _successes(first)
    sweep_b, b = _successes(second)
    for name in ("seed", "densities", "scenes"):
        if sweep_a.get(name) != sweep_b.get(name):
            raise ResultsError(Path(second), f"a sweep whose {name} is {sweep_b.get(name)!r} "
                               f"where {first}'s is {sweep_a.get(name)!r}",
                               "two sweeps of the same scenes (the same seed, densities "
                               "and scene generator)")
    densities = [float(d) for d in sweep_a["densities"]]
    out = []
    for key in sorted(a.keys() & b.keys(), key=lambda k: (-k[2], k[0], k[1])):
        x, y = a[key], b[key]
        trials = x.keys() & y.keys()
        if not trials:
            continue
        count = {(i, j): sum(x[t] == i and y[t] == j for t in trials)
                 for i in (True, False) for j in (True, False)}
        out.append(PairedCell(key[0], densities[key[1]], key[2], count[True, True],
                              count[True, False], count[False, True], count[False, False]))
    return out


def pooled(cells: list[PairedCell]) -> list[PairedCell]:
    """Per tolerance, the cells' pairs summed over methods and densities (``method``
    "all", ``density`` NaN): a change too small for any one cell to show. The tasks of
    one scene share it, so the pooled pairs are not independent and the pooled test is
    a summary, not an exact test."""
    out = []
    for tolerance in sorted({c.tolerance for c in cells}, reverse=True):
        mine = [c for c in cells if c.tolerance == tolerance]
        out.append(PairedCell("all", math.nan, tolerance, sum(c.both for c in mine),
                              sum(c.first_only for c in mine),
                              sum(c.second_only for c in mine), sum(c.neither for c in mine)))
    return out


def markdown(cells: list[PairedCell], first: str, second: str) -> str:
    """The comparison as a Markdown table, a row per cell, then pooled per tolerance."""
    lines = [f"Success with {first} less success with {second}, on the same scenes "
             "(points; 95 % interval, Newcombe's method 10 for paired proportions; exact "
             "McNemar test; the margin is the smallest change the interval excludes).", "",
             "| tolerance | density | method | scenes | both | only first | only second "
             "| difference | 95 % interval | McNemar p | excludes changes beyond |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        low, high = c.interval
        lines.append(f"| {c.tolerance:g} | {c.density:g} | {c.method} | {c.n} | {c.both} | "
                     f"{c.first_only} | {c.second_only} | {100 * c.difference:+.0f} | "
                     f"{100 * low:+.0f} to {100 * high:+.0f} | {c.p:.3g} | "
                     f"{100 * c.excluded_margin:.0f} |")
    lines += ["", "Pooled over methods and densities (:func:`pooled`: the tasks of a scene "
              "share it, so the test is a summary, not exact).", "",
              "| tolerance | paired tasks | both | only first | only second | difference "
              "| McNemar p |", "|---|---|---|---|---|---|---|"]
    for c in pooled(cells):
        lines.append(f"| {c.tolerance:g} | {c.n} | {c.both} | {c.first_only} | "
                     f"{c.second_only} | {100 * c.difference:+.1f} | {c.p:.3g} |")
    return "\n".join(lines) + "\n"
