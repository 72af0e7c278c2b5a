"""A reduced Table 1 in CI: scenarios/regression.toml (two dozen paired scenes per
density) through ``taskcam sweep``, and the paper's pattern asserted on it.

Trials are seeded and every process runs the same code paths whatever its processor
(sim/determinism.py, docs/reproducibility.md), so the counts are the same on every run
and every machine; the bounds are what makes this a regression test: each asks for a
clear effect (a one-sided test, or a margin of scenes), so that an algorithm change that
breaks the pattern fails here, and one that leaves it intact does not.

The size is chosen for the tests' power, not for the outcome. With a dozen scenes the
sign test of optimal against biased random placement (10 % tolerance, 5 and 20 %
density) had, at the effect measured then (about 60 % of pairs discordant, 78 % of
those won), a power of 0.31 at p < 0.01 and 0.63 at p < 0.05; it passed at 8a2651b
(12 wins, 2 losses) and failed after issue 17's changes to placement, sightings and
the task (12 wins, 3 losses, p = 0.018). Two dozen scenes at p < 0.05 give a
power of 0.91; the fall with density is tested where it is large (20 % tolerance,
Fisher's exact test) and only as "not rising" at 10 %, where the four-step task's
measurement leaves optimal placement's fall small. Measured when this size was set
(fd876bb; successes of 24 at 5 / 20 / 35 %): at 20 % tolerance optimal 21 / 15 / 12,
without secondary targets 17 / 15 / 8, biased random 17 / 11 / 4; at 10 %: 14 / 13 / 9,
12 / 7 / 5, 8 / 3 / 0; at 1 % none (sign test 21 wins, 5 losses, p = 0.0012). After
sightings were held to their pose's uncertainty and made unambiguous: at 20 % 21 / 15 /
12, 14 / 13 / 6, 17 / 9 / 3; at 10 % 14 / 13 / 9, 7 / 6 / 4, 8 / 3 / 0; at 1 % none
(sign test 20 wins, 4 losses, p = 0.0008; the fall at 20 %: p = 0.0057 optimal,
0.00004 random). With four steps the panel reaches the slot
only if it is measured within 5 mm of it early, so an algorithm change that leaves the
measurement as accurate still moves a few scenes either way.

The sign test pools the three densities (it tested 5 and 20 % alone until issue 19's
second round): the paper orders optimal over biased random placement, with secondary
targets, in every column at the 10 % tolerance (100 / 30, 86 / 15, 18 / 4). Since the
measurement became relative and precise from most views (e8604da), biased random
placement succeeds at 5 and 20 % nearly as often as optimal in this reduced sweep
(successes of 24 at 5 / 20 / 35 %, 10 % tolerance: optimal 24 / 19 / 15, random
19 / 19 / 8; 20 %: 24 / 22 / 18 and 22 / 19 / 8), so those two densities alone had 9
wins and 4 losses (p = 0.13), all three 17 and 5 (p = 0.008; at 20 % tolerance 17 and
2). That random placement does as well at 20 % density is the scene generator's doing:
its floor-standing clutter leaves the views above 40 degrees open (issue 21, item 2).
Per density optimal is asserted not worse, and better over all three.

Since the generator blocks every elevation band in proportion (issue 21, item 2) and
the target frame rests on every target located, the same sweep gives, of 24 at 5 / 20 /
35 %: at 20 % tolerance optimal 23 / 24 / 21, without secondary targets 23 / 20 / 20,
biased random 23 / 18 / 15; at 10 % 23 / 24 / 18, 20 / 18 / 17, 21 / 16 / 13. Optimal
over random, pooled: 13 wins and 1 loss at 20 % (p = 0.0009), 17 and 2 at 10 %
(p = 0.0004). Random placement now falls with density at both tolerances (Fisher
p = 0.005 and 0.012); optimal placement, which finds the directions left open, falls at
10 % (p = 0.049) and hardly at 20 % (23 to 21, p = 0.30). So the fall is asserted where
the clutter makes it (random placement, both tolerances) and optimal placement is
asserted not to rise; per density optimal is not worse at 10 %, and at 20 %, where both
are at the ceiling at 5 % density (23 of 24 each; 23 and 24 with the new clutter and the
earlier frame), not worse by more than one scene.

With the slot as the task's primary target and the holes as its secondary ones (issue
21, item 1), found by its rails (a projected half-width of 22 mm for the detector's
limits), the same sweep gives, of 24 at 5 / 20 / 35 %: at 20 % tolerance optimal 24 /
23 / 23, without secondary targets 24 / 23 / 21, biased random 23 / 17 / 20; at 10 %
24 / 23 / 22, 24 / 23 / 21, 23 / 17 / 20; at 1 % 9 / 9 / 5, 9 / 6 / 10, 1 / 4 / 4.
Optimal over random, pooled: 12 wins and 2 losses at 20 % (p = 0.006), 11 and 2 at
10 % (p = 0.011), and 22 and 8 even at 1 % with four steps (p = 0.008). Neither method
falls significantly with density here (random 23 to 20 of 24, p = 0.17; it is lowest
at 20 %): with the rails detectable from most views at 320 x 240 the clutter leaves
both enough; so success is asserted "not rising" with density, as for optimal before.
Secondary targets no longer change much (with them over without, pooled: 3 wins and 1
loss at 20 %, 3 and 2 at 10 %): while the slot counted as 7 mm wide for the detector
(its gap alone), it was under a pixel from most views at this image size, and slot-only
placement failed in 10 and 14 of 24 scenes at 20 and 35 % density, an artefact of the
rule, not the secondary targets' effect. They are asserted not to hurt.

The hard tolerance (issue 21, item 5) is what Table 1's images and step bound are for
(at 320 x 240 the measurement is half as precise, and four steps end many tasks short
of it), so it has its own sweep with them, at the density where the paper's gap is
widest (97 % against 1 %): scenarios/regression_hard.toml, 48
pairs at 5 % density, about five minutes on 2 cores. Both sweeps plan in the robots'
map; there, with the task's noise a stream of its own, the reduced table met 10 % with
optimal placement in 24 / 24 / 20 scenes and with biased random in 23 / 21 / 15 (11
wins, 2 losses), placing 48 / 47 / 40 robots against 47 / 47 / 40, and the hard sweep
gave optimal 47 of 48 at 1 %, random 38 (10 wins, 1 loss), Wilcoxon p = 0.004. Measured
before, with the planner in the scene as it is: at 1 % optimal 48 of 48, biased random
42 (6 pairs won, none lost: sign test p = 0.016); the final
displacement is smaller with optimal placement in 35 pairs of 48 (median 0.83 mm
against 1.19; Wilcoxon signed-rank p = 1e-5, and p < 0.004 in either half of the pairs
alone), and optimal placement stops confident in 31 scenes, random in 5. The
paper's gap there (97 % against 1 %) does not reproduce: the relative measurement is
precise from most views biased random placement chooses at 5 % density.
Power: the success test rests on the discordant pairs, 6 of 48 here; were they all
won again, the chance of at least the 5 the test needs is 0.73 (binomial, 48 pairs at
6 in 48), so a change that keeps the effect fails it about one time in four. The
displacement test at p < 0.01 has a power of 0.996 at the measured effect (2000
bootstrap resamples of the 48 pairs). Both are asserted.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

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


def test_optimal_placement_places_as_many_robots_as_random_at_every_density(swept):
    """Planning in the robots' map, the rating function's views are no harder to get
    to than biased random's: it ranks only views the arm reaches from the floor its
    base gets to."""
    placed: dict[tuple[str, int], int] = defaultdict(int)
    with Results(swept) as r:
        for d, *_, record in r.rows("trials"):
            for m in json.loads(record)["methods"]:
                placed[(m["method"], d)] += sum(bool(x["placed"]) for x in m["robots"])
    for d in range(3):
        assert placed[("optimal", d)] >= placed[("random", d)], dict(placed)


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
                    alternative="less").pvalue < 0.01
