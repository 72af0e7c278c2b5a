"""The soak's scenes: draw a random valid scenario (sim/experiments/soak/draw_scenario.py),
write it as a TOML file, run it as a user would (as ``taskcam run FILE --out DIR`` runs
it, in a worker process) and audit the run directory (sim/experiments/soak/audit.py).

A draw the command rejects as invalid input (exit 2: the scenario parser or the scene
builder) is discarded, its reason (the key named) counted, and the next draw of the
scene tried. A run that fails (exit 1) is a ``traceback`` finding with the traceback.
Each scene gives one JSON-able record; :func:`run_scenes` runs many on worker
processes (a scene that kills its worker is a ``crash``, one that overruns a
``timeout``), and :func:`tally` adds records up.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import re
import shutil
import time
import traceback
from collections import Counter
from collections.abc import Iterator
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

import numpy as np

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.experiments.runner import init_worker, one_thread_each
from taskcam.sim.experiments.soak.audit import audit_run
from taskcam.sim.experiments.soak.audit_findings import Finding
from taskcam.sim.experiments.soak.draw_scenario import SIZES, draw_scenario, is_heavy, to_toml
from taskcam.sim.stages.episode import Episode
from taskcam.sim.stages.run_directory import write_run

MAX_DRAWS = 25  # draws tried for one scene before it counts as having none valid
_KEY = re.compile(r"key '([^']*)'")


def run_file(path: Path, out: Path) -> tuple[int, str]:
    """The scenario file run as ``taskcam run PATH --out OUT --no-record`` runs it, in this
    process (taskcam.sim.stages.run_directory.write_run): its exit code (0, 2 for invalid input,
    1 for a failure) and what it said."""
    try:
        episode = Episode(load_scenario(path))  # checks the file, then the scene
    except ScenarioError as exc:
        return 2, f"taskcam: error: {exc}\n"
    except Exception:  # a failure the checks let through: the soak goes on
        return 1, traceback.format_exc()
    try:
        write_run(episode, out, record=False)
    except Exception:
        return 1, traceback.format_exc()
    return 0, ""


def discard_reason(stderr: str) -> str:
    """The key an invalid-input message names (``robots.bases[1]`` -> ``robots.bases``)."""
    found = _KEY.search(stderr)
    return re.sub(r"\[\d+\]", "", found.group(1)) if found else "unknown"


def _run(path: Path, out: Path, record: dict[str, Any], keep: bool) -> bool:
    """Run and audit the scenario file ``path`` into ``out``, adding to ``record``;
    False if the CLI rejected it as invalid input (its reason added to the discards)."""
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    code, stderr = run_file(path, out)
    if code == 2:
        record["discards"].append({"reason": discard_reason(stderr),
                                   "message": stderr.strip().splitlines()[-1][:300]})
        return False
    record.update({"scenario": path.read_text(), "exit": code,
                   "run_s": round(time.perf_counter() - start, 3)})
    if code != 0:
        record["findings"].append(Finding("traceback", None, stderr[-4000:]).as_dict())
    else:
        record.update(audit_run(out, load_scenario(path)).summary())
        summary = json.loads((out / "summary.json").read_text())
        record["timings_s"] = summary.get("timings_s", {})
    if record["findings"] or keep:
        record["run_dir"] = str(out)
    else:
        shutil.rmtree(out, ignore_errors=True)
    return True


def run_scene(index: int, workdir: Path, master_seed: int = 0, heavy: bool | None = None,
              sizes: tuple[tuple[int, int], ...] = SIZES, keep: bool = False) -> dict[str, Any]:
    """Draw, run and audit scene ``index`` of a soak (seeded by ``master_seed`` and the
    index alone) in ``workdir``; the scenario file and run directory are kept if
    ``keep`` or if it has findings. Returns the scene's record."""
    heavy = is_heavy(index) if heavy is None else heavy
    workdir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"index": index, "master_seed": master_seed, "heavy": heavy,
                              "discards": [], "findings": []}
    start = time.perf_counter()
    record["exit"] = None  # stays None if every draw is discarded
    for attempt in range(MAX_DRAWS):
        draw = draw_scenario(np.random.default_rng([master_seed, index, attempt]),
                             f"soak{index:04d}", heavy, sizes)
        path = workdir / f"soak{index:04d}.toml"
        path.write_text(to_toml(draw.table))
        if _run(path, workdir / f"soak{index:04d}", record, keep):
            record.update(attempt=attempt, features=list(draw.features))
            break
    if "run_dir" not in record:
        path.unlink()
    record["seconds"] = round(time.perf_counter() - start, 3)
    return record


def run_path(path: Path, workdir: Path, keep: bool = False) -> dict[str, Any]:
    """Run and audit a scenario file as the soak does a drawn one (its record has the
    file's ``name``, no index)."""
    workdir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"index": None, "file": path.name, "heavy": None, "discards": [],
                              "findings": [], "exit": None}
    start = time.perf_counter()
    _run(path, workdir / path.stem, record, keep)
    record["seconds"] = round(time.perf_counter() - start, 3)
    return record


Job = tuple[int, bool | None] | Path  # a scene index (heavy None: by the index), or a file


def _worker(conn: Connection, workdir: Path, master_seed: int,
            sizes: tuple[tuple[int, int], ...], keep: bool) -> None:
    """A worker process: runs the scene indices it is sent until it is sent None."""
    init_worker()
    while True:
        job = conn.recv()
        if job is None:
            return
        if isinstance(job, Path):
            conn.send(run_path(job, workdir, keep))
        else:
            conn.send(run_scene(job[0], workdir, master_seed, job[1], sizes, keep))


class _Worker:
    def __init__(self, context: Any, args: tuple[Any, ...]) -> None:
        self.conn, child = context.Pipe()
        self.process = context.Process(target=_worker, args=(child, *args), daemon=True)
        self.process.start()
        child.close()
        self.job: Job | None = None
        self.started = 0.0
        self.done = 0

    def send(self, job: Job) -> None:
        self.job, self.started = job, time.monotonic()
        self.conn.send(job)

    def finished(self) -> None:
        """Its scene's record is in: free for the next."""
        self.job = None
        self.done += 1

    def stop(self, kill: bool = False) -> None:
        if kill:
            self.process.kill()
        else:
            with contextlib.suppress(OSError):
                self.conn.send(None)
        self.process.join(10)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


def _lost(job: Job, kind: str, message: str, seconds: float) -> dict[str, Any]:
    """The record of a scene whose worker died or overran."""
    if isinstance(job, Path):
        where: dict[str, Any] = {"index": None, "file": job.name, "heavy": None}
    else:
        where = {"index": job[0], "heavy": is_heavy(job[0]) if job[1] is None else job[1]}
    return {**where, "discards": [], "exit": None,
            "findings": [Finding(kind, None, message).as_dict()], "seconds": round(seconds, 3)}


def run_scenes(jobs: list[Job], workdir: Path, workers: int = 2,
               master_seed: int = 0, sizes: tuple[tuple[int, int], ...] = SIZES,
               keep: bool = False, timeout_s: float = 1800.0, recycle: int = 40
               ) -> Iterator[dict[str, Any]]:
    """Run scenes ``(index, heavy)`` (heavy None: by the index) or scenario files on
    ``workers`` worker processes, each library kept to one thread, yielding each record
    as it finishes. A worker that dies or runs a scene longer than ``timeout_s`` is
    replaced (its scene recorded as a ``crash`` or ``timeout``); each is replaced after
    ``recycle`` scenes."""
    context = multiprocessing.get_context("spawn")  # no GL context or renderer inherited
    args = (workdir, master_seed, sizes, keep)
    queue = list(reversed(jobs))
    pool: list[_Worker] = []
    try:
        with one_thread_each():
            pool = [_Worker(context, args) for _ in range(min(workers, len(jobs)))]
        for w in pool:
            if queue:
                w.send(queue.pop())
        while any(w.job is not None for w in pool):
            busy = [w for w in pool if w.job is not None]
            deadline = min(w.started for w in busy) + timeout_s
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy],
                         timeout=max(0.0, deadline - time.monotonic()))
            for w in busy:
                assert w.job is not None
                record: dict[str, Any] | None = None
                replace = False
                if w.conn in ready or w.conn.poll():
                    try:
                        record = w.conn.recv()
                    except (EOFError, OSError):
                        record = None
                if record is None and not w.process.is_alive():
                    record = _lost(w.job, "crash", f"the worker died (exit code "
                                   f"{w.process.exitcode}) running this scene",
                                   time.monotonic() - w.started)
                    replace = True
                elif record is None and time.monotonic() - w.started > timeout_s:
                    w.stop(kill=True)
                    record = _lost(w.job, "timeout", f"the scene ran longer than {timeout_s} s",
                                   time.monotonic() - w.started)
                    replace = True
                if record is None:
                    continue
                yield record
                w.finished()
                if replace or w.done >= recycle:
                    w.stop(kill=replace)
                    with one_thread_each():
                        pool[pool.index(w)] = w = _Worker(context, args)
                if queue:
                    w.send(queue.pop())
    finally:
        for w in pool:
            w.stop(kill=w.job is not None)


def tally(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The counts of each outcome over scene records (as :func:`run_scene` gives them)."""
    counts: Counter[str] = Counter()
    discards: Counter[str] = Counter()
    refused: Counter[str] = Counter()
    refused_robots: Counter[str] = Counter()
    failures: Counter[str] = Counter()
    findings: Counter[str] = Counter()
    worst: dict[str, float] = {}
    seconds: dict[str, list[float]] = {"light": [], "heavy": []}  # a worker's, per run
    for r in records:
        counts["scenes"] += 1
        counts["heavy_scenes"] += bool(r.get("heavy"))
        discards.update(d["reason"] for d in r.get("discards", []))
        if r.get("exit") is None and not r.get("findings"):
            counts["scenes_without_valid_draw"] += 1
        counts["tracebacks"] += sum(f["kind"] == "traceback" for f in r.get("findings", []))
        counts.update(r.get("counts", {}))
        refused.update(r.get("refused", {}))
        refused_robots.update(r.get("refused_robots", {}))
        failures.update(r.get("correction_failures", {}))
        findings.update(f["kind"] for f in r.get("findings", []))
        counts["scenes_with_findings"] += bool(r.get("findings"))
        for k, v in r.get("worst", {}).items():
            worst[k] = max(worst.get(k, 0.0), v)
        if r.get("exit") == 0:
            seconds["heavy" if r.get("heavy") else "light"].append(r["run_s"])
    per_scene = {k: {"scenes": len(v), "median_s": round(float(np.median(v)), 2),
                     "max_s": round(max(v), 2), "total_s": round(sum(v), 1)}
                 for k, v in seconds.items() if v}
    return {"counts": dict(sorted(counts.items())), "discarded_draws": dict(discards),
            "refused_robots": dict(refused_robots), "refused_placements": dict(refused),
            "correction_failures": dict(failures),
            "findings": dict(findings), "worst": worst, "run_seconds": per_scene}
