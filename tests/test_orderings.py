"""The paper's orderings: which pairs of its Table 1 it claims, and
their tests on a results database, against hand counts."""

from __future__ import annotations

import math

import pytest

from taskcam.sim.experiments.orderings import Ordering, claims, markdown, mcnemar, orderings_in
from taskcam.sim.experiments.report_files import write_report
from taskcam.sim.experiments.results import Results


def test_the_paper_makes_48_claims_of_more_than_10_points():
    """14 placement, 6 secondary-target and 28 density claims; by hand: optimal 100 over
    random 45 at 5 %, easy, without secondary targets (gap 55); nothing where its cells
    tie (optimal at 5 %, easy, with or without: 100 and 100) or differ by 10 or less
    (random at 5 %, medium: 30 with, 23 without); and 5 % above 35 % for optimal, hard."""
    made = claims()
    assert [sum(c[0] == f for c in made) for f in ("placement", "secondary targets",
                                                  "density")] == [14, 6, 28]
    assert ("placement", ("rating", False, 0.05, 0.2), ("biased_random", False, 0.05, 0.2),
            55.0) in made
    pairs = {(c[1], c[2]) for c in made} | {(c[2], c[1]) for c in made}
    assert (("rating", True, 0.05, 0.2), ("rating", False, 0.05, 0.2)) not in pairs
    assert (("biased_random", True, 0.05, 0.1), ("biased_random", False, 0.05, 0.1)) not in pairs
    assert ("density", ("rating", False, 0.05, 0.01), ("rating", False, 0.35, 0.01),
            94.0) in made
    assert all(gap > 10 for *_, gap in made)


def test_mcnemar_by_hand():
    # 8 discordant one way, 1 the other: 2 (C(9,0) + C(9,1)) / 2^9 = 20 / 512
    assert mcnemar(8, 1) == pytest.approx(20 / 512)
    assert mcnemar(1, 8) == pytest.approx(20 / 512)
    assert mcnemar(0, 0) == 1.0


def _trial(density_index: int, trial: int, wins: dict[str, bool]) -> dict:
    methods = [{"method": name, "placement": placement, "secondary": secondary,
                "final_displacement_m": None, "steps": 0, "stopped_by": "",
                "success": {"0.2": wins[name]}}
               for name, placement, secondary in (("optimal", "rating", True),
                                                  ("random", "biased_random", True))]
    return {"density_index": density_index, "trial": trial, "seed": trial,
            "density": (0.05, 0.2)[density_index], "achieved_density": 0.0, "obstacles": 0,
            "timings_s": {"total": 1.0}, "methods": methods}


@pytest.fixture
def small_db(tmp_path):
    """Two densities of 20 paired scenes, methods with secondary targets only, easy
    tolerance: at 5 % optimal succeeds in 18, random in 6 (14 scenes optimal alone, 2
    random alone); at 20 % optimal in 9, random in 5 (6 optimal alone, 2 random alone)."""
    db = tmp_path / "small.sqlite"
    with Results(db) as r:
        r.start({"sweep": {"densities": [0.05, 0.2],
                           "methods": [{"name": "optimal"}, {"name": "random"}]}},
                resume=False)
        for d, (both, optimal_only, random_only) in enumerate(((4, 14, 2), (3, 6, 2))):
            plan = ([(True, True)] * both + [(True, False)] * optimal_only
                    + [(False, True)] * random_only)
            plan += [(False, False)] * (20 - len(plan))
            for i, (o, rnd) in enumerate(plan):
                r.add(_trial(d, i, {"optimal": o, "random": rnd}))
    return db


def test_orderings_on_a_database_against_hand_counts(small_db, tmp_path):
    """Only the claims this sweep ran (optimal over random, with secondary targets, easy,
    at 5 and 20 %; random's density step 5 -> 20 %: optimal's, 100 to 95 in the paper,
    is none): counts, Wilson intervals apart or not, McNemar on the discordant pairs and
    Fisher's test by hand."""
    tested = {(o.family, o.higher, o.lower): o for o in orderings_in(small_db)}
    assert set(tested) == {
        ("placement", ("rating", True, 0.05, 0.2), ("biased_random", True, 0.05, 0.2)),
        ("placement", ("rating", True, 0.2, 0.2), ("biased_random", True, 0.2, 0.2)),
        ("density", ("biased_random", True, 0.05, 0.2), ("biased_random", True, 0.2, 0.2))}
    five = tested[("placement", ("rating", True, 0.05, 0.2), ("biased_random", True, 0.05, 0.2))]
    assert five.counts == ((18, 20), (6, 20)) and five.test == "McNemar"
    assert five.p_value == pytest.approx(mcnemar(14, 2))
    assert five.reproduces  # 90 % [70-97] against 30 % [15-52]
    twenty = tested[("placement", ("rating", True, 0.2, 0.2), ("biased_random", True, 0.2, 0.2))]
    assert twenty.counts == ((9, 20), (5, 20)) and not twenty.reproduces  # overlapping
    step = tested[("density", ("biased_random", True, 0.05, 0.2),
                   ("biased_random", True, 0.2, 0.2))]
    assert step.counts == ((6, 20), (5, 20)) and step.test == "Fisher"
    # Fisher two-sided by hand: the tables with 11 successes over 40 no likelier than this
    def table(k: int) -> float:  # k successes of the 11 in the first group of 20
        return math.comb(20, k) * math.comb(20, 11 - k) / math.comb(40, 11)
    observed = table(6)
    p = sum(table(k) for k in range(12) if table(k) <= observed * (1 + 1e-9))
    assert step.p_value == pytest.approx(p) and p > 0.5
    out = write_report(small_db, tmp_path / "out")
    assert out["orderings"] == markdown(orderings_in(small_db))
    assert (tmp_path / "out" / "small-orderings.md").read_text() == out["orderings"]
    assert "- placement: 1 of 2 (not: 1 too close)" in out["orderings"]
    assert "- all: 1 of 3 (not: 2 too close)" in out["orderings"]
    assert five.verdict == "reproduced" and twenty.verdict == step.verdict == "too close"
    lines = (tmp_path / "out" / "small-orderings.csv").read_text().splitlines()
    assert len(lines) == 1 + 3


@pytest.mark.parametrize("counts, verdict", [
    (((19, 20), (2, 20)), "reproduced"),  # 95 % [76-99] over 10 % [3-30]
    (((2, 20), (19, 20)), "reversed"),
    (((20, 20), (18, 20)), "both at the ceiling"),  # 100 and 90 %: no room for 10 points
    (((2, 20), (0, 20)), "both at the floor"),  # 10 and 0 %
    (((12, 20), (8, 20)), "too close"),  # 60 % [39-78] against 40 % [22-61]
    (((19, 20), (17, 20)), "too close"),  # 95 and 85 %: the lower one below 90 %
])
def test_an_ordering_that_does_not_reproduce_says_how(counts, verdict):
    o = Ordering("placement", ("rating", True, 0.05, 0.2), ("biased_random", True, 0.05, 0.2),
                 55.0, counts, "McNemar", 1.0)
    assert o.verdict == verdict
