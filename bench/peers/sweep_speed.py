"""Table 1's speed against a baseline commit, side by side, and the whole loop's cost.

Run from the repository root::

    python -m bench.peers.sweep_speed --baseline c383897 --scenes 10

- *Table 1 scene*: the same scenes (the first ``--scenes`` of each density: the scenes
  are drawn from the sweep's seed, the density and the trial's index, alike at both
  commits) run by this checkout and by the baseline, alternating scene by scene. Each
  commit runs its own ``scenarios/table1.toml``: what a researcher gets who runs the
  table again (the baseline's file uses keys this commit retired, ``search.drive_m``).
  The baseline runs from its own ``git worktree`` (``--worktree``, made if missing)
  with its own virtual environment (its ``scripts/setup``), in a subprocess, so that
  it imports its own code.
- *Whole loop over correction off*: at this commit, the same scenes with
  ``scenarios/table1_loop.toml`` (the positioning errors and the pose correction on)
  against ``table1.toml``, alternating.

Each side is one long-lived worker process started pinned (``python -m taskcam.sim.pinned``),
so imports and compiled code's caches are paid once, as in a sweep's worker. Prints one
table and writes bench/results/sweep_speed.json: rows ``table1 scene`` (ours: seconds a
scene now, peer: the baseline's, ratio ours / peer), one per density, and ``whole loop
over correction off`` (ours: the loop's seconds a scene, peer: correction off's).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
from pathlib import Path
from typing import Any

from bench.common import ROOT, SCENARIOS, print_table, write_results
from taskcam.sim.config.sweep import load_sweep

# Run in a checkout's own environment: reads "SWEEP DENSITY_INDEX TRIAL" lines, runs that
# trial and answers with its seconds and what it placed. Only names both commits have
# (PREFIX: "taskcam.", or nothing at a commit that installed its packages at the top).
WORKER = """
import json, sys, time
from PREFIXsim.config.sweep import load_sweep
from PREFIXsim.experiments.runner import trial_specs
from PREFIXsim.experiments.trial import run_trial
specs = {}
for line in sys.stdin:
    path, d, t = line.split()
    if path not in specs:
        specs[path] = {(s.density_index, s.trial): s for s in trial_specs(load_sweep(path))}
    start = time.perf_counter()
    record = run_trial(specs[path][int(d), int(t)])
    seconds = time.perf_counter() - start
    placed = {m["method"]: sum(bool(r.get("placed")) for r in m.get("robots", []))
              for m in record["methods"]}
    print(json.dumps({"seconds": seconds, "placed": placed}), flush=True)
"""


class Worker:
    """A checkout's trial runner: one pinned process in its own virtual environment."""

    def __init__(self, checkout: Path) -> None:
        python = checkout / ".venv" / "bin" / "python"
        prefix = "taskcam." if (checkout / "taskcam" / "__init__.py").exists() else ""
        worker = WORKER.replace("PREFIX", prefix)
        self.process = subprocess.Popen(
            [str(python), "-m", f"{prefix}sim.pinned", str(python), "-c", worker], cwd=checkout,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def run(self, sweep: str, density_index: int, trial: int) -> dict[str, Any]:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(f"{sweep} {density_index} {trial}\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"the worker for {sweep} died (exit status "
                               f"{self.process.wait()})")
        return dict(json.loads(line))

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.close()
        self.process.wait()


def baseline_checkout(commit: str, worktree: Path) -> Path:
    """The baseline's worktree with its own virtual environment, made if missing."""
    if not (worktree / ".git").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(worktree),
                        commit], check=True)
    if not (worktree / ".venv" / "bin" / "python").exists():
        subprocess.run([str(worktree / "scripts" / "setup")], cwd=worktree, check=True)
    return worktree


def side_by_side(a: Worker, a_sweep: str, b: Worker, b_sweep: str, scenes: int,
                 densities: int, label: str) -> dict[int, list[tuple[float, float]]]:
    """Seconds of each scene by ``a`` and by ``b``, per density index, alternating which
    goes first from scene to scene (a slow spell of the machine falls on both), after
    one scene each not counted (the first density's next scene): a fresh environment
    compiles and caches its numba code, and a worker loads its libraries, in the first
    trial it runs."""
    a.run(a_sweep, 0, scenes)
    b.run(b_sweep, 0, scenes)
    out: dict[int, list[tuple[float, float]]] = {}
    for trial in range(scenes):
        for d in range(densities):
            first, second = ((a, a_sweep), (b, b_sweep)) if trial % 2 == 0 else (
                (b, b_sweep), (a, a_sweep))
            times = {id(first[0]): first[0].run(first[1], d, trial)["seconds"]}
            times[id(second[0])] = second[0].run(second[1], d, trial)["seconds"]
            out.setdefault(d, []).append((times[id(a)], times[id(b)]))
            print(f"{label}: density {d}, scene {trial}: {times[id(a)]:.1f} s against "
                  f"{times[id(b)]:.1f} s", flush=True)
    return out


def rows_of(case: str, timed: dict[int, list[tuple[float, float]]],
            densities: list[float]) -> list[dict[str, Any]]:
    """The mean seconds a scene, over all and per density: ours, peer and the ratio."""
    def row(name: str, pairs: list[tuple[float, float]]) -> dict[str, Any]:
        ours = statistics.fmean(p[0] for p in pairs)
        peer = statistics.fmean(p[1] for p in pairs)
        return {"case": name, "ours": round(ours, 2), "peer": round(peer, 2),
                "ratio": round(ours / peer, 3), "unit": "s a scene", "scenes": len(pairs)}
    every = [p for pairs in timed.values() for p in pairs]
    return [row(case, every), *(row(f"{case}, density {densities[d]:g}", pairs)
                                for d, pairs in sorted(timed.items()))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="c383897", help="the commit to compare with")
    parser.add_argument("--scenes", type=int, default=10, help="scenes a density")
    parser.add_argument("--worktree", type=Path, default=ROOT / "runs" / "baseline",
                        help="the baseline's checkout (made if missing)")
    parser.add_argument("--parts", default="table1,loop",
                        help="which comparisons: table1 (against the baseline), loop")
    args = parser.parse_args()
    parts = set(args.parts.split(","))
    densities = list(load_sweep(SCENARIOS / "table1.toml").config.densities)
    ours = Worker(ROOT)
    rows: list[dict[str, Any]] = []
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True, check=True).stdout.strip()
    try:
        if "table1" in parts:
            peer = Worker(baseline_checkout(args.baseline, args.worktree))
            try:
                rows += rows_of("table1 scene", side_by_side(
                    ours, "scenarios/table1.toml", peer, "scenarios/table1.toml",
                    args.scenes, len(densities), "table1"), densities)
            finally:
                peer.close()
        if "loop" in parts:
            off = Worker(ROOT)
            try:
                rows += rows_of("whole loop over correction off", side_by_side(
                    ours, "scenarios/table1_loop.toml", off, "scenarios/table1.toml",
                    args.scenes, len(densities), "loop"), densities)
            finally:
                off.close()
    finally:
        ours.close()
    print_table(rows)
    print(f"written to {write_results('sweep_speed', rows, commit=commit, baseline=args.baseline)}")


if __name__ == "__main__":
    main()
