"""Sweeps: where a trial's time goes, how trials scale over workers, and whether a
worker's memory stays flat.

Run from the repository root: ``python -m bench.peers.sweep``. Three parts, on the same
sweep file (default ``scenarios/table1.toml``):

1. *Stages*: ``--stage-trials`` trials of the sweep's first method with the pose
   correction switched on, timed per stage (median over the trials; rendering is also
   counted inside the stages that render).
2. *Throughput*: the same ``--trials`` trials (the sweep's first two methods) on one
   local worker, on two, and on a two-worker Dask LocalCluster; trials per second,
   and each against one worker (the peer).
3. *Memory*: ``--memory-trials`` trials on one worker process in a row; its peak
   resident memory after trial 20 and after the last (the renderer and the other
   native resources are released after each trial, so it should stay flat).

Prints one table and writes bench/results/sweep.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from bench.common import print_table, write_results
from taskcam.sim.config.sweep import Sweep, load_sweep
from taskcam.sim.experiments.runner import init_worker, one_thread_each, run_sweep, trial_specs
from taskcam.sim.experiments.trial import TrialSpec, run_trial

STAGES = ("build", "mapping", "placement", "ik", "motion", "correction", "task", "rendering",
          "total")


def stages(sweep: Sweep, n: int) -> list[dict[str, Any]]:
    s = sweep.scenario
    corrected = dataclasses.replace(s, correction=dataclasses.replace(s.correction,
                                                                      enabled=True))
    specs = [dataclasses.replace(t, scenario=corrected, methods=sweep.config.methods[:1])
             for t in trial_specs(sweep)[:n]]
    timings = [run_trial(spec)["timings_s"] for spec in specs]
    return [{"case": f"stage: {k} (median of {n} trials, 1 method)", "ours":
             statistics.median(t.get(k, 0.0) for t in timings), "peer": None, "ratio": None,
             "unit": "s per trial"} for k in STAGES]


def throughput(sweep: Sweep, n: int) -> list[dict[str, Any]]:
    from distributed import LocalCluster

    small = dataclasses.replace(sweep, config=dataclasses.replace(
        sweep.config, trials=max(1, -(-n // len(sweep.config.densities))),
        methods=sweep.config.methods[:2]))
    rates = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, workers in (("1 local worker", 1), ("2 local workers", 2)):
            done = run_sweep(small, Path(tmp) / f"{workers}.sqlite", workers, progress=False)
            rates[label] = done.ran / done.seconds
        with one_thread_each(), LocalCluster(n_workers=2, threads_per_worker=1,
                                             processes=True, dashboard_address=None) as cluster:
            start = time.perf_counter()
            done = run_sweep(small, Path(tmp) / "dask.sqlite", scheduler=cluster.scheduler_address,
                             progress=False)
            rates["2-worker Dask LocalCluster"] = done.ran / (time.perf_counter() - start)
    one = rates["1 local worker"]
    return [{"case": f"throughput: {label} ({done.total} trials, 2 methods)", "ours": rate,
             "peer": one, "ratio": rate / one, "unit": "trials/s (peer: 1 worker)"}
            for label, rate in rates.items()]


def _memory_run(specs: list[TrialSpec]) -> list[float]:
    return [run_trial(spec)["worker"]["max_rss_mib"] for spec in specs]


def memory(sweep: Sweep, n: int) -> list[dict[str, Any]]:
    specs = [dataclasses.replace(t, methods=sweep.config.methods[:2])
             for t in trial_specs(dataclasses.replace(sweep, config=dataclasses.replace(
                 sweep.config, trials=max(10, n))))][:n]
    with ProcessPoolExecutor(1, mp_context=get_context("spawn"), initializer=init_worker) as p:
        rss = p.submit(_memory_run, specs).result()
    early = rss[min(19, len(rss) - 1)]  # once the caches a sweep keeps are filled
    return [{"case": f"worker peak memory: trial 20 -> trial {len(rss)}", "ours": rss[-1],
             "peer": early, "ratio": rss[-1] / early, "unit": "MiB (peer: after trial 20)"}]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=Path, default=Path("scenarios/table1.toml"))
    parser.add_argument("--stage-trials", type=int, default=3)
    parser.add_argument("--trials", type=int, default=6)
    parser.add_argument("--memory-trials", type=int, default=300)
    parser.add_argument("--memory-sweep", type=Path, default=Path("scenarios/smoke.toml"),
                        help="a cheaper sweep for the long memory run")
    parser.add_argument("--parts", default="stages,throughput,memory",
                        help="comma-separated: stages, throughput, memory")
    args = parser.parse_args()
    parts = args.parts.split(",")
    unknown = set(parts) - {"stages", "throughput", "memory"}
    if unknown:
        parser.error(f"unknown parts {sorted(unknown)}; parts: stages, throughput, memory")
    sweep = load_sweep(args.sweep)
    rows = []
    if "stages" in parts:
        rows += stages(sweep, args.stage_trials)
    if "throughput" in parts:
        rows += throughput(sweep, args.trials)
    if "memory" in parts:
        rows += memory(load_sweep(args.memory_sweep), args.memory_trials)
    print_table(rows)
    name = "sweep" if len(parts) == 3 else "sweep_" + "_".join(parts)
    write_results(name, rows, sweep=str(args.sweep), memory_sweep=str(args.memory_sweep))

if __name__ == "__main__":
    main()
