"""A reduced Table 1 in CI: scenarios/regression.toml (a dozen paired scenes per
density) through ``taskcam sweep``, and the paper's pattern asserted on it.

Trials are seeded and every process runs the same code paths whatever its processor
(sim/determinism.py, docs/reproducibility.md), so the counts are the same on every run
and every machine; the bounds are what makes this a regression test: each asks for a
clear effect (a one-sided sign test on the paired scenes, or a margin of scenes), so
that an algorithm change that breaks the pattern fails here, and one that leaves it
intact does not. Measured with the pinned code paths at c1b1fc7 (successes of 12 at
5 / 20 / 35 %): at 20 % tolerance optimal 12 / 8 / 8, without secondary targets
10 / 8 / 5, biased random 9 / 8 / 1; at 10 %: 7 / 8 / 6, 7 / 4 / 4, 5 / 1 / 0 (sign
test at 5 and 20 %, 10 % tolerance: 12 wins, 3 losses, p = 0.018). These miss three
bounds: the sign test, optimal over random at 20 % density and tolerance (8 = 8), and
the fall from 5 to 35 % at 10 % tolerance (7 against 6 + 2). Pinned at 8a2651b they
held (11 / 9 / 5, 10 / 7 / 5, 8 / 6 / 2; 7 / 8 / 3, 5 / 3 / 4, 5 / 0 / 0; 12 wins,
2 losses, p = 0.0065); unpinned, this machine (AVX-512) gave at c1b1fc7 11 / 8 / 8,
10 / 7 / 5, 9 / 9 / 1; 8 / 6 / 6, 9 / 4 / 3, 5 / 2 / 0 (8 wins, 1 loss). The outcomes
are sensitive: with four steps, the panel reaches the slot only if it is measured
within 5 mm of it early, so an algorithm change that leaves the measurement as
accurate still moves a few scenes either way.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pytest
from scipy.stats import binomtest

from sim.cli import main
from sim.results import Results
from sim.scenario import SCENARIO_DIR

EASY, MEDIUM, HARD = 0.2, 0.1, 0.01


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory) -> dict[tuple[str, int, float], list[bool]]:
    """Success per (method, density index, tolerance), trial by trial."""
    db = tmp_path_factory.mktemp("regression") / "regression.sqlite"
    assert main(["sweep", str(SCENARIO_DIR / "regression.toml"), "--db", str(db),
                 "--workers", "2"]) == 0
    out: dict[tuple[str, int, float], list[bool]] = defaultdict(list)
    with Results(Path(db)) as r:
        for d, _trial, method, tol, ok in r.rows("successes"):
            out[(method, d, tol)].append(bool(ok))
    return out


def rate(outcomes, method: str, density: int, tol: float) -> float:
    hits = outcomes[(method, density, tol)]
    return sum(hits) / len(hits)


def sign_test(a: list[bool], b: list[bool]) -> float:
    """One-sided p of ``a`` succeeding where ``b`` fails more often than the reverse,
    over paired scenes."""
    wins = sum(x and not y for x, y in zip(a, b, strict=True))
    losses = sum(y and not x for x, y in zip(a, b, strict=True))
    if wins + losses == 0:
        return 1.0
    return float(binomtest(wins, wins + losses, 0.5, alternative="greater").pvalue)


def test_every_scene_ran_every_method(outcomes):
    assert {len(v) for v in outcomes.values()} == {12}
    assert len(outcomes) == 3 * 3 * 3  # methods x densities x tolerances


def test_the_rating_function_beats_biased_random_placement_at_5_and_20_percent(outcomes):
    medium = [outcomes[(m, d, MEDIUM)] for m in ("optimal", "random") for d in (0, 1)]
    assert sign_test(medium[0] + medium[1], medium[2] + medium[3]) < 0.01
    for tol in (EASY, MEDIUM):
        for d in (0, 1):
            assert rate(outcomes, "optimal", d, tol) > rate(outcomes, "random", d, tol)


def test_success_falls_as_density_and_difficulty_rise(outcomes):
    for method in ("optimal", "optimal_primary", "random"):
        for d in range(3):  # harder tolerances succeed in a subset of the scenes
            for tighter, looser in ((MEDIUM, EASY), (HARD, MEDIUM)):
                assert all(not t or lo for t, lo in zip(outcomes[(method, d, tighter)],
                                                       outcomes[(method, d, looser)],
                                                       strict=True))
    for tol in (EASY, MEDIUM):
        dense = rate(outcomes, "optimal", 2, tol)
        assert rate(outcomes, "optimal", 0, tol) >= dense + 2 / 12
        assert rate(outcomes, "random", 0, tol) >= rate(outcomes, "random", 2, tol)


def test_secondary_targets_do_not_hurt(outcomes):
    for tol in (EASY, MEDIUM):
        with_secondary = sum(sum(outcomes[("optimal", d, tol)]) for d in range(3))
        without = sum(sum(outcomes[("optimal_primary", d, tol)]) for d in range(3))
        assert with_secondary >= without - 1  # at most one scene of 36 worse
