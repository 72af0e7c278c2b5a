"""Two sweeps of the same scenes compared cell by cell: the paired
difference's interval against its defining properties and its coverage by simulation,
the comparison of two results databases against hand counts, and `taskcam compare`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import run_taskcam

from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments import corrections
from taskcam.sim.experiments.paired import compare, markdown, paired_interval, pooled
from taskcam.sim.experiments.results import Results, ResultsError


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


def _robots(error: tuple[float, float] | str | None) -> list[dict]:
    """Two robots' records: r1's move corrected to ``error`` (m, deg; None: failed), r2's
    to 0.5 mm and 0.01 deg; none if ``error`` is "off" (a sweep without correction)."""
    if error == "off":
        return [{"name": "r1", "corrections": []}, {"name": "r2", "corrections": []}]

    def move(e):
        status = ("failed" if e is None else
                  "corrected" if e[0] <= 0.003 and e[1] <= 0.2 else "uncertain")
        after = None if e is None else {"position_m": e[0], "orientation_deg": e[1]}
        return {"status": status, "error_after": after}
    return [{"name": "r1", "corrections": [move((0.02, 1.0)), move(error)]},
            {"name": "r2", "corrections": [move((0.0005, 0.01))]}]


def _db(path, loop_wins: dict[tuple[int, int], bool], seed: int = 0,
        errors: dict[tuple[int, int], tuple[float, float] | None] | None = None) -> None:
    """A results database of one method at two densities, 'optimal' succeeding at the
    easy tolerance where ``loop_wins`` says; its cameras corrected to ``errors`` (by
    trial; 1 mm and 0.05 deg where not given), or not corrected without it."""
    with Results(path) as r:
        r.start({"sweep": {"seed": seed, "densities": [0.05, 0.2],
                           "methods": [{"name": "optimal"}]}, "scenes": "generator"},
                resume=False)
        for (d, trial), ok in loop_wins.items():
            r.add({"density_index": d, "trial": trial, "seed": trial, "density": 0.05,
                   "achieved_density": 0.0, "obstacles": 0, "timings_s": {"total": 1.0},
                   "methods": [{"method": "optimal", "placement": "rating", "secondary": True,
                                "final_displacement_m": None, "steps": 0, "stopped_by": "",
                                "success": {"0.2": ok},
                                "robots": _robots("off" if errors is None else
                                                  errors.get((d, trial), (0.001, 0.05)))}]})


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
    # pooled: 14 pairs; both 6 + 1, on only 2 + 2, off only 1 + 0, neither 1 + 1
    (pool,) = pooled(cells)
    assert (pool.n, pool.both, pool.first_only, pool.second_only, pool.neither) == (14, 7, 4, 1, 2)
    assert pool.p == pytest.approx(0.375)  # exact McNemar: 2 * P(X <= 1), X ~ Bin(5, 1/2)
    assert "| 0.2 | 14 | 7 | 4 | 1 | +21.4 | 0.375 |" in text


def test_the_corrections_where_the_sweeps_end_differently_by_hand(tmp_path):
    """The scenes of the test above; the 'on' sweep's cameras corrected to 1 mm and 0.05
    deg but at 5 %: trial 9 (only 'off' met it) to 5 mm, trial 0 (neither) failed.
    Each task's last correction per camera counts (r1's first move, 20 mm off, not)."""
    on = {(0, t): 1 <= t <= 8 for t in range(10)} | {(1, t): t < 3 for t in range(6)}
    off = {(0, t): 3 <= t <= 9 for t in range(10)} | {(1, t): t < 1 for t in range(4)}
    _db(tmp_path / "on.sqlite", on, errors={(0, 9): (0.005, 0.1), (0, 0): None})
    _db(tmp_path / "off.sqlite", off)
    tasks = corrections.read(tmp_path / "on.sqlite")
    assert len(tasks) == 16 and tasks[("optimal", 0, 9)].worst == (0.005, 0.1)
    assert tasks[("optimal", 0, 0)].worst is None and not tasks[("optimal", 0, 0)].within
    assert corrections.read(tmp_path / "off.sqlite") == {}
    assert corrections.markdown(tmp_path / "off.sqlite", tmp_path / "on.sqlite", 0.2) == ""
    text = corrections.markdown(tmp_path / "on.sqlite", tmp_path / "off.sqlite", 0.2)
    # 32 cameras: 30 corrected, 1 uncertain, 1 failed; 14 of 16 tasks within
    assert "| optimal | 16 | 32 | 30 | 1 | 1 | 14 | 1.00 / 1.00 |" in text
    # both: 6 + 1; first only: 2 + 2; second only: trial 9; neither: trial 0 and 3 at 20 %
    assert "| both | 7 | 7 | 0 | 1.00 / 1.00 |" in text
    assert "| first only | 4 | 4 | 0 |" in text
    assert "| second only | 1 | 0 | 0 | 5.00 / 5.00 |" in text
    assert "| neither | 2 | 1 | 1 | 1.00 / 1.00 |" in text
    done = run_taskcam("compare", str(tmp_path / "on.sqlite"), str(tmp_path / "off.sqlite"))
    assert done.returncode == 0 and text in done.stdout


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


def test_the_fixed_views_ablation_differs_from_the_main_table_only_in_re_placing_cameras():
    main = load_sweep("scenarios/table1.toml")
    fixed = load_sweep("scenarios/table1_fixed_views.toml")
    assert fixed.config.trials == 50
    assert fixed.config.methods == tuple(m for m in main.config.methods  # the paper's four
                                         if m.name not in ("nbv", "informed_random"))
    assert all(fixed.trial_seed(i, k) == main.trial_seed(i, k)
               for i in range(len(main.config.densities)) for k in range(50))
    assert main.scenario.task.replace and not fixed.scenario.task.replace
    assert dataclasses.replace(fixed.scenario, task=main.scenario.task, source="") \
        == dataclasses.replace(main.scenario, source="")
