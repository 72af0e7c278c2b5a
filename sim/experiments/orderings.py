"""The paper's Table 1 as claims, each tested on a results database.

Every pair of cells the paper's table compares, kept where the paper's two cells differ
by more than GAP_POINTS: optimal against biased random placement in the same column,
with against without secondary targets for the same method, tolerance and density, and
each density step (5 to 20, 20 to 35, 5 to 35 %) for the same method, tolerance and
secondary setting. An ordering **reproduces** when taskcam's two Wilson 95 % intervals
are apart in the paper's direction. Each also gets a two-sided significance test: the
exact McNemar test where both cells ran on the same scenes (their discordant pairs), and
Fisher's exact test where they did not (density steps compare different scenes). One
that does not reproduce says how: reversed (the intervals apart the other way), both at
the ceiling or the floor (both rates within ROOM of 100 % or 0 %: no room for the
paper's gap of more than GAP_POINTS), or too close (the intervals overlap).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from scipy.stats import binomtest, fisher_exact

from taskcam.placement import method_label
from taskcam.sim.experiments.report import DIFFICULTY, PAPER, percent, wilson, write_rows
from taskcam.sim.experiments.results import Results, ResultsError

GAP_POINTS = 10.0  # the paper's cells must differ by more than this to make a claim
ROOM = GAP_POINTS / 100  # both rates this near 100 % (or 0 %) leave no room for such a gap
DENSITIES = (0.05, 0.2, 0.35)
TOLERANCES = (0.2, 0.1, 0.01)
PLACEMENTS = tuple(dict.fromkeys(key[0] for key in PAPER))  # the paper's: its table's rows
STEPS = ((0.05, 0.2), (0.2, 0.35), (0.05, 0.35))

Key = tuple[str, bool, float, float]  # placement, secondary, density, tolerance


def _paper(key: Key) -> float:
    """The paper's success at a cell (%); its "<<1" counts as 0."""
    text = PAPER[key]
    return 0.0 if text == "<<1" else float(text)


def claims() -> list[tuple[str, Key, Key, float]]:
    """The paper's orderings: (family, the cell it puts higher, the lower one, the gap in
    points), for every compared pair whose gap exceeds GAP_POINTS."""
    pairs: list[tuple[str, Key, Key]] = []
    for secondary in (False, True):
        for d in DENSITIES:
            for t in TOLERANCES:
                pairs.append(("placement", ("rating", secondary, d, t),
                              ("biased_random", secondary, d, t)))
    for p in PLACEMENTS:
        for d in DENSITIES:
            for t in TOLERANCES:
                pairs.append(("secondary targets", (p, True, d, t), (p, False, d, t)))
    for p in PLACEMENTS:
        for secondary in (False, True):
            for t in TOLERANCES:
                for low, high in STEPS:
                    pairs.append(("density", (p, secondary, low, t), (p, secondary, high, t)))
    out = []
    for family, a, b in pairs:
        gap = _paper(a) - _paper(b)
        if abs(gap) > GAP_POINTS:
            out.append((family, a, b, gap) if gap > 0 else (family, b, a, -gap))
    return out


@dataclass(frozen=True)
class Ordering:
    """One of the paper's orderings tested: its cells' success counts in the database,
    whether taskcam reproduces it, and the test's p-value (two-sided)."""

    family: str
    higher: Key
    lower: Key
    paper_gap: float  # points
    counts: tuple[tuple[int, int], tuple[int, int]]  # (successes, trials) higher, lower
    test: str  # "McNemar" (same scenes) or "Fisher"
    p_value: float

    @property
    def reproduces(self) -> bool:
        """Wilson 95 % intervals apart, the paper's higher cell above."""
        (s1, n1), (s2, n2) = self.counts
        return wilson(s1, n1)[0] > wilson(s2, n2)[1]

    @property
    def verdict(self) -> str:
        """"reproduced", or why not: "reversed" (the intervals apart the other way),
        "both at the ceiling" / "both at the floor" (both rates at least 1 - ROOM / at
        most ROOM), or "too close" (the intervals overlap)."""
        (s1, n1), (s2, n2) = self.counts
        if self.reproduces:
            return "reproduced"
        if wilson(s2, n2)[0] > wilson(s1, n1)[1]:
            return "reversed"
        rates = (s1 / n1, s2 / n2)
        if min(rates) >= 1 - ROOM:
            return "both at the ceiling"
        if max(rates) <= ROOM:
            return "both at the floor"
        return "too close"


def mcnemar(only_first: int, only_second: int) -> float:
    """Exact two-sided McNemar p-value from the discordant pairs' counts."""
    n = only_first + only_second
    return 1.0 if n == 0 else float(binomtest(only_first, n, 0.5).pvalue)


def orderings_in(db: str | Path) -> list[Ordering]:
    """Every claim tested on the results database ``db`` (read-only); claims whose cells
    the sweep did not run (a method, density or tolerance it lacks) are left out.
    ResultsError if it is not a results database."""
    with Results(db, readonly=True) as results:
        description = results.description() or {}
        try:
            densities = [round(float(d), 4) for d in description["sweep"]["densities"]]
        except (KeyError, TypeError):
            raise ResultsError(results.path, "a results database without a sweep's "
                               "description", "a database written by taskcam sweep") from None
        method_of: dict[tuple[str, bool], str] = {}
        for method, placement, secondary in results.db.execute(
                "SELECT DISTINCT method, placement, secondary FROM outcomes ORDER BY method"):
            method_of.setdefault((placement, bool(secondary)), method)
        success = results.successes()

    def trials(key: Key) -> dict[int, bool] | None:
        placement, secondary, density, tol = key
        method = method_of.get((placement, secondary))
        if method is None or round(density, 4) not in densities:
            return None
        return success.get((method, densities.index(round(density, 4)), round(tol, 6)))

    out = []
    for family, higher, lower, gap in claims():
        a, b = trials(higher), trials(lower)
        if not a or not b:
            continue
        counts = ((sum(a.values()), len(a)), (sum(b.values()), len(b)))
        if family == "density":
            table = [[counts[0][0], counts[0][1] - counts[0][0]],
                     [counts[1][0], counts[1][1] - counts[1][0]]]
            test, p = "Fisher", float(fisher_exact(table).pvalue)
        else:
            both = a.keys() & b.keys()
            test = "McNemar"
            p = mcnemar(sum(a[t] and not b[t] for t in both),
                        sum(b[t] and not a[t] for t in both))
        out.append(Ordering(family, higher, lower, gap, counts, test, p))
    return out


def _cell(key: Key) -> str:
    placement, secondary, density, tol = key
    name = method_label(placement).split(" (")[0]
    return (f"{name}, {'with' if secondary else 'without'} sec., {density:.0%}, "
            f"{DIFFICULTY.get(tol, f'{tol:g}')}")


def markdown(orderings: list[Ordering]) -> str:
    """The orderings as a Markdown table, with how many of each family reproduce."""
    lines = ["The paper's orderings (its cells more than "
             f"{GAP_POINTS:g} points apart) on this database: success % [Wilson 95 %] of "
             "the cell the paper puts higher and of the lower one; reproduced when the "
             "intervals are apart in the paper's direction; p two-sided (McNemar on the "
             "same scenes, Fisher across densities).", ""]
    for family in ("placement", "secondary targets", "density"):
        mine = [o for o in orderings if o.family == family]
        lines.append(f"- {family}: {sum(o.reproduces for o in mine)} of {len(mine)}"
                     + _why_not(mine))
    lines.append(f"- all: {sum(o.reproduces for o in orderings)} of {len(orderings)}"
                 + _why_not(orderings))
    lines += ["", "| family | higher (paper %) | lower (paper %) | ours: higher | ours: lower "
              "| reproduced | test | p |", "|---|---|---|---:|---:|:-:|---|---:|"]
    for o in orderings:
        ours = [percent(s, n) for s, n in o.counts]
        lines.append(f"| {o.family} | {_cell(o.higher)} ({PAPER[o.higher]}) | "
                     f"{_cell(o.lower)} ({PAPER[o.lower]}) | {ours[0]} | {ours[1]} | "
                     f"{'yes' if o.reproduces else 'no: ' + o.verdict} | {o.test} | "
                     f"{o.p_value:.2g} |")
    return "\n".join(lines) + "\n"


def _why_not(orderings: list[Ordering]) -> str:
    """How many of those that do not reproduce fail each way, as ``(not: 3 too close,
    ...)``; empty if all reproduce."""
    verdicts = [o.verdict for o in orderings if not o.reproduces]
    kinds = sorted(set(verdicts), key=lambda v: (-verdicts.count(v), v))
    return f" (not: {', '.join(f'{verdicts.count(v)} {v}' for v in kinds)})" if kinds else ""


def write_csv(orderings: list[Ordering], path: Path) -> None:
    write_rows(path, ["family", "higher", "lower", "paper_gap_points", "higher_successes",
                      "higher_trials", "lower_successes", "lower_trials", "reproduces",
                      "verdict", "test", "p_value"],
               ([o.family, _cell(o.higher), _cell(o.lower), o.paper_gap, *o.counts[0],
                 *o.counts[1], int(o.reproduces), o.verdict, o.test, f"{o.p_value:.6g}"]
                for o in orderings))
