"""A reduced Table 1 in CI: the paper's pattern asserted on two sweeps run through
``taskcam sweep``, both planning in the robots' map.

scenarios/regression.toml: 24 paired scenes at each of 5, 20 and 35 % density, every
method on the same scenes. Asserted: optimal placement beats biased random placement at
the 20 and 10 % tolerances (one-sided sign test over the paired scenes, the three
densities pooled, p < 0.05; not worse at any density, by at most one scene at 20 %,
where both are near the ceiling); success does not rise with density, nor with a
tighter tolerance; secondary targets do not hurt (at most two scenes of 72 worse); and
optimal placement places as many cameras that see their target as random at every
density.

scenarios/regression_hard.toml: the 1 % tolerance, which needs Table 1's images and step
bound and so has its own sweep with them: 48 paired scenes at 5 % density, where the
paper's gap is widest. Asserted: optimal placement meets it where biased random misses
it more often than the reverse (sign test, p < 0.05), and ends nearer the slot
(one-sided Wilcoxon signed-rank test on the final displacement, p < 0.05, as every
other claim here; at the effect measured, 48 pairs give it a power of 0.66 at p < 0.05
and 0.37 at p < 0.01).

Trials are seeded and every process runs the same code paths whatever its processor
(sim/determinism.py, docs/reproducibility.md), so the counts are the same on every run
and every machine. Each bound asks for a clear effect (a one-sided test, or a margin of
scenes), so that an algorithm change that breaks the pattern fails here and one that
leaves it intact does not; the sweeps' sizes are chosen for the tests' power, not for
the outcome. The counts and powers measured behind these choices are in
docs/notes/regression-history.md.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binomtest, wilcoxon

from sim.cli import main
from sim.config.scenario import SCENARIO_DIR
from sim.config.sweep import load_sweep
from sim.experiments.results import Results

pytestmark = pytest.mark.slow  # the regression sweep: about ten minutes on 2 cores
EASY, MEDIUM, HARD = 0.2, 0.1, 0.01
TRIALS = 24  # paired scenes per density (scenarios/regression.toml)


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    """The reduced table's results database."""
    db = tmp_path_factory.mktemp("regression") / "regression.sqlite"
    assert main(["sweep", str(SCENARIO_DIR / "regression.toml"), "--db", str(db),
                 "--workers", "2"]) == 0
    return db


@pytest.fixture(scope="module")
def outcomes(swept) -> dict[tuple[str, int, float], list[bool]]:
    """Success per (method, density index, tolerance), trial by trial."""
    out: dict[tuple[str, int, float], list[bool]] = defaultdict(list)
    with Results(swept) as r:
        for d, _trial, method, tol, ok in r.rows("successes"):
            out[(method, d, tol)].append(bool(ok))
    return out


def test_the_reduced_table_plans_in_the_robots_map():
    assert load_sweep(SCENARIO_DIR / "regression.toml").scenario.search.planner_world == "map"
    assert load_sweep(SCENARIO_DIR / "regression_hard.toml").scenario.search.planner_world == "map"


def test_optimal_placement_places_as_many_seeing_cameras_as_random_at_every_density(swept):
    """Planning in the robots' map, the rating function's views are no harder to get
    to than biased random's: optimal placement places at least as many cameras that see
    their target, at every density. A camera that sees nothing is not counted: biased
    random places its camera wherever it gets to within its bounds, seen or not, where
    the rating function refuses a view it rates zero (at 35 % biased random placed 40
    cameras of 48 and 27 of them saw a target; optimal placement 40, all seeing)."""
    seeing: dict[tuple[str, int], int] = defaultdict(int)
    with Results(swept) as r:
        for d, *_, record in r.rows("trials"):
            for m in json.loads(record)["methods"]:
                seeing[(m["method"], d)] += sum(bool(x["placed"] and x["seen"])
                                                for x in m["robots"])
    for d in range(3):
        assert seeing[("optimal", d)] >= seeing[("random", d)], dict(seeing)


def test_the_cameras_face_the_requested_density(swept):
    """The density is held from the depth of field's near limit to its far limit: every
    placed camera, of every method, faces the request within the generator's 2 points
    at every recorded radius, and the median within 5 points."""
    sweep = load_sweep(SCENARIO_DIR / "regression.toml")
    faced: dict[int, list[float]] = defaultdict(list)
    with Results(swept) as r:
        for d, *_, record in r.rows("trials"):
            trial = json.loads(record)
            request = sweep.config.densities[d]
            assert all(abs(share - request) <= 0.02 + 1e-9
                       for _, share in trial["density_by_radius"])
            faced[d] += [x["faced_density"] for m in trial["methods"] for x in m["robots"]
                         if x["placed"]]
    for d, request in enumerate(sweep.config.densities):
        assert abs(float(np.median(faced[d])) - request) <= 0.05, (request, faced[d])


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
    assert {len(v) for v in outcomes.values()} == {TRIALS}
    assert len(outcomes) == 3 * 3 * 3  # methods x densities x tolerances


def test_the_rating_function_beats_biased_random_placement(outcomes):
    for tol in (EASY, MEDIUM):
        paired = [[ok for d in range(3) for ok in outcomes[(m, d, tol)]]
                  for m in ("optimal", "random")]
        assert sign_test(*paired) < 0.05
        assert sum(paired[0]) > sum(paired[1])
        ceiling = 1 if tol == EASY else 0  # scenes optimal may lose where both near 24
        for d in range(3):
            assert (sum(outcomes[("optimal", d, tol)])
                    >= sum(outcomes[("random", d, tol)]) - ceiling)


def test_success_does_not_rise_with_density_or_difficulty(outcomes):
    for method in ("optimal", "optimal_primary", "random"):
        for d in range(3):  # harder tolerances succeed in a subset of the scenes
            for tighter, looser in ((MEDIUM, EASY), (HARD, MEDIUM)):
                assert all(not t or lo for t, lo in zip(outcomes[(method, d, tighter)],
                                                       outcomes[(method, d, looser)],
                                                       strict=True))
    for tol in (EASY, MEDIUM):
        for method in ("optimal", "random"):
            assert rate(outcomes, method, 0, tol) >= rate(outcomes, method, 2, tol)


def test_secondary_targets_do_not_hurt(outcomes):
    for tol in (EASY, MEDIUM):
        with_secondary = sum(sum(outcomes[("optimal", d, tol)]) for d in range(3))
        without = sum(sum(outcomes[("optimal_primary", d, tol)]) for d in range(3))
        assert with_secondary >= without - 2  # at most two scenes of 72 worse


@pytest.fixture(scope="module")
def hard(tmp_path_factory) -> dict[str, dict[int, tuple[bool, float]]]:
    """Per method, per trial: met the hard tolerance, and the final displacement (m)."""
    db = tmp_path_factory.mktemp("regression_hard") / "regression_hard.sqlite"
    assert main(["sweep", str(SCENARIO_DIR / "regression_hard.toml"), "--db", str(db),
                 "--workers", "2"]) == 0
    out: dict[str, dict[int, tuple[bool, float]]] = defaultdict(dict)
    with Results(Path(db)) as r:
        met = {(m, t): bool(ok) for _d, t, m, tol, ok in r.rows("successes") if tol == HARD}
        for _d, t, m, _placement, _secondary, final, _steps, _by in r.rows("outcomes"):
            out[m][t] = (met[(m, t)], math.inf if final is None else final)  # not tried
    return out


def test_the_hard_tolerance_orders_optimal_over_random(hard):
    """At 5 % density optimal placement meets the 1 % tolerance where biased random
    misses it more often than the reverse, and ends nearer the slot (paired tests)."""
    trials = sorted(hard["optimal"])
    assert trials == sorted(hard["random"]) and len(trials) == 48
    optimal = [hard["optimal"][t] for t in trials]
    random = [hard["random"][t] for t in trials]
    assert sign_test([o[0] for o in optimal], [r[0] for r in random]) < 0.05
    assert wilcoxon([o[1] for o in optimal], [r[1] for r in random],
                    alternative="less").pvalue < 0.05
