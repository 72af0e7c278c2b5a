"""Two sweeps of the same scenes compared cell by cell (issue 23, item 4): the paired
difference's interval against its defining properties and its coverage by simulation,
the comparison of two results databases against hand counts, and `taskcam compare`."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_taskcam

from sim.config.sweep import load_sweep
from sim.experiments.paired import compare, markdown, paired_interval
from sim.experiments.results import Results, ResultsError


def test_interval_holds_the_difference_and_mirrors_when_the_sweeps_swap():
    for counts in [(30, 12, 2, 6), (10, 0, 0, 40), (0, 5, 0, 45), (25, 3, 9, 13)]:
        both, first, second, neither = counts
        n = sum(counts)
        d = (first - second) / n
        low, high = paired_interval(*counts)
        assert -1 <= low <= d <= high <= 1
        swapped = paired_interval(both, second, first, neither)
        assert swapped == pytest.approx((-high, -low))
    low, high = paired_interval(20, 0, 0, 30)  # no discordant pair: around zero
    assert low < 0 < high and high < 0.1


def test_interval_covers_the_true_difference_95_percent_of_the_time():
    """Brute force: 4000 samples of 50 pairs from known cell probabilities; the share of
    intervals holding the true difference is near 95 % (Newcombe reports method 10's
    coverage at 0.94-0.96 for such n)."""
    rng = np.random.default_rng(7)
    for probs in [(0.6, 0.2, 0.05, 0.15), (0.8, 0.05, 0.05, 0.1), (0.3, 0.1, 0.3, 0.3)]:
        truth = probs[1] - probs[2]
        samples = rng.multinomial(50, probs, size=4000)
        held = [lo <= truth <= hi for lo, hi in (paired_interval(*map(int, s)) for s in samples)]
        assert 0.925 <= np.mean(held) <= 0.985, (probs, np.mean(held))


def _db(path, loop_wins: dict[tuple[int, int], bool], seed: int = 0) -> None:
    """A results database of one method at two densities, 'optimal' succeeding at the
    easy tolerance where ``loop_wins`` says."""
    with Results(path) as r:
        r.start({"sweep": {"seed": seed, "densities": [0.05, 0.2],
                           "methods": [{"name": "optimal"}]}, "scenes": "generator"},
                resume=False)
        for (d, trial), ok in loop_wins.items():
            r.add({"density_index": d, "trial": trial, "seed": trial, "density": 0.05,
                   "achieved_density": 0.0, "obstacles": 0, "timings_s": {"total": 1.0},
                   "methods": [{"method": "optimal", "placement": "rating", "secondary": True,
                                "final_displacement_m": None, "steps": 0, "stopped_by": "",
                                "success": {"0.2": ok}}]})


def test_compare_counts_the_pairs_by_hand(tmp_path):
    """At 5 %, 10 scenes: on in 8 (1-8), off in 6 (3-8 and 9): both 6, on only 2, off
    only 1, neither 1. At 20 % the off sweep finished only 4 of the on sweep's 6."""
    on = {(0, t): 1 <= t <= 8 for t in range(10)} | {(1, t): t < 3 for t in range(6)}
    off = {(0, t): 3 <= t <= 9 for t in range(10)} | {(1, t): t < 1 for t in range(4)}
    _db(tmp_path / "on.sqlite", on)
    _db(tmp_path / "off.sqlite", off)
    cells = compare(tmp_path / "on.sqlite", tmp_path / "off.sqlite")
    five, twenty = sorted(cells, key=lambda c: c.density)
    assert (five.both, five.first_only, five.second_only, five.neither) == (6, 2, 1, 1)
    assert five.difference == pytest.approx(0.1)
    assert (twenty.n, twenty.both, twenty.first_only) == (4, 1, 2)
    assert five.excluded_margin == pytest.approx(max(map(abs, five.interval)))
    text = markdown(cells, "on", "off")
    assert "| 0.2 | 0.05 | optimal | 10 | 6 | 2 | 1 | +10 |" in text


def test_compare_refuses_sweeps_of_other_scenes(tmp_path):
    _db(tmp_path / "a.sqlite", {(0, 0): True})
    _db(tmp_path / "b.sqlite", {(0, 0): True}, seed=1)
    with pytest.raises(ResultsError, match="seed"):
        compare(tmp_path / "a.sqlite", tmp_path / "b.sqlite")


def test_taskcam_compare_prints_the_table_and_refuses_a_missing_file(tmp_path):
    _db(tmp_path / "a.sqlite", {(0, 0): True, (0, 1): False})
    _db(tmp_path / "b.sqlite", {(0, 0): False, (0, 1): False})
    out = tmp_path / "cmp.md"
    done = run_taskcam("compare", str(tmp_path / "a.sqlite"), str(tmp_path / "b.sqlite"),
                       "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "| 0.2 | 0.05 | optimal | 2 | 0 | 1 | 0 | +50 |" in done.stdout
    assert out.read_text() == done.stdout
    bad = run_taskcam("compare", str(tmp_path / "a.sqlite"), str(tmp_path / "none.sqlite"))
    assert bad.returncode == 2 and "none.sqlite" in bad.stderr and "Traceback" not in bad.stderr


def test_the_whole_loop_sweep_extends_the_main_table_on_its_first_scenes():
    main, loop = load_sweep("scenarios/table1.toml"), load_sweep("scenarios/table1_loop.toml")
    assert loop.config.trials == 50 and main.config.trials == 300
    assert loop.config.methods == main.config.methods
    assert all(loop.trial_seed(i, k) == main.trial_seed(i, k)
               for i in range(len(main.config.densities)) for k in range(50))
    assert loop.scenario.correction.enabled and not main.scenario.correction.enabled
    assert loop.scenario.motion.joint_offset_deg > 0 == main.scenario.motion.joint_offset_deg
    assert loop.scenario.camera == main.scenario.camera  # everything else as the main table
    assert loop.scenario.search == main.scenario.search
