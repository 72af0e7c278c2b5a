"""A reduced Table 1 in CI: what the table shows under the paper's conditions (clutter
that the cameras face, the paper's biased random, a secondary target off the plate, no
oracle), asserted on two sweeps run through ``taskcam sweep``.

scenarios/regression.toml: 24 paired scenes at each of 5, 20 and 35 % density, every
method on the same scenes. Asserted: every placed camera faces the requested density;
optimal placement places as many cameras that see their target as biased random at
every density; at the 1 % tolerance it meets the tolerance where biased random misses
it more often than the reverse (one-sided sign test over the paired scenes, the three
densities pooled, p < 0.05; power 0.82 at the effect measured), and at the 20 and 10 %
tolerances, where both are near the ceiling, it is not worse; a tighter tolerance
succeeds in a subset of the scenes, and at 1 % no method succeeds more often at 35 %
than at 5 %; secondary targets cost at most two scenes of 72 at 20 %.

scenarios/regression_hard.toml: the 1 % tolerance with Table 1's images and step bound:
48 paired scenes at 5 % density. Asserted: optimal placement meets it where biased
random misses it more often than the reverse (sign test, p < 0.05), and ends nearer the
slot (one-sided Wilcoxon signed-rank test on the final displacement, p < 0.05).

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

from taskcam.sim.cli import main
from taskcam.sim.config.scenario import SCENARIO_DIR
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments.results import Results

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
    the rating function refuses a view it rates zero (at 35 % biased random placed 48
    cameras of 48 and 32 of them saw a target; optimal placement 48, all seeing)."""
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
    """Where the tolerance asks for a good measurement (1 %), optimal placement meets it
    where the paper's biased random misses it more often than the reverse (one-sided
    sign test over the 72 paired scenes, p < 0.05); at the easy and medium tolerances,
    where both are near the ceiling, it is not worse."""
    paired = [[ok for d in range(3) for ok in outcomes[(m, d, HARD)]]
              for m in ("optimal", "random")]
    assert sign_test(*paired) < 0.05
    for tol in (EASY, MEDIUM):
        assert (sum(ok for d in range(3) for ok in outcomes[("optimal", d, tol)])
                >= sum(ok for d in range(3) for ok in outcomes[("random", d, tol)]))


def test_success_does_not_rise_with_density_or_difficulty(outcomes):
    """A tighter tolerance succeeds in a subset of the scenes the looser one does; at the
    tolerance that is off the ceiling (1 %), each method succeeds no more often at 35 %
    than at 5 %."""
    for method in ("optimal", "optimal_primary", "random"):
        for d in range(3):
            for tighter, looser in ((MEDIUM, EASY), (HARD, MEDIUM)):
                assert all(not t or lo for t, lo in zip(outcomes[(method, d, tighter)],
                                                       outcomes[(method, d, looser)],
                                                       strict=True))
        assert rate(outcomes, method, 0, HARD) >= rate(outcomes, method, 2, HARD)


def test_secondary_targets_do_not_hurt_at_the_easy_tolerance(outcomes):
    """At 20 % the secondary targets cost at most two scenes of 72. (At 1 % they cost:
    docs/notes/regression-history.md gives the counts, not asserted here.)"""
    with_secondary = sum(sum(outcomes[("optimal", d, EASY)]) for d in range(3))
    without = sum(sum(outcomes[("optimal_primary", d, EASY)]) for d in range(3))
    assert with_secondary >= without - 2


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
