"""Running a sweep's trials: in this process, on a local process pool, or on a Dask
distributed cluster; each finished trial is stored at once (one transaction), so an
interrupted sweep resumes where it stopped, without losing or repeating a trial.

Trials are independent and seeded by their own indices (sim/config/sweep.py), so the stored
rows are the same whichever worker ran which trial, and in whatever order they ended;
and, their processes pinned to the same code paths (sim/determinism.py), on whichever
machine. Trials run in worker processes started with the pinned environment, one worker
included, so that a native crash (a segmentation fault in a library, say) ends a worker,
never the sweep: the trials in flight when a worker died run again, each alone in a
process of its own, and one whose process dies every time (``TRIAL_ATTEMPTS``) is
stored as failed, with the reason, and the sweep goes on.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from tqdm import tqdm

from taskcam.sim.config.sweep import Sweep
from taskcam.sim.determinism import PINS, late_imports, pin, started_pinned
from taskcam.sim.experiments.results import Results
from taskcam.sim.experiments.trial import TrialSpec, run_trial
from taskcam.sim.world.gl import resolve_gl_backend

PR_SET_PDEATHSIG = 1  # prctl option: the signal a process gets when its parent dies


@dataclass(frozen=True)
class SweepRun:
    """What a call to :func:`run_sweep` did."""

    total: int  # trials in the sweep
    already: int  # stored before this call
    ran: int  # finished and stored by this call
    failed: int  # stored as failed by this call (their worker died every time)
    seconds: float


@dataclass(frozen=True)
class TrialFailure:
    """A trial that could not be run: its worker process died every time."""

    spec: TrialSpec
    attempts: int
    reason: str  # e.g. "worker died with SIGSEGV, 3 times"


def trial_specs(sweep: Sweep) -> list[TrialSpec]:
    """Every trial of the sweep, the densities interleaved (a partial sweep covers all)."""
    c = sweep.config
    return [TrialSpec(sweep.scenario, c.methods, i, density, k, sweep.trial_seed(i, k))
            for k in range(c.trials) for i, density in enumerate(c.densities)]


def init_worker() -> None:
    """A local worker: dies with the sweep that started it (on Linux), even killed -9,
    rather than finish a trial nobody will store."""
    with suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    pin()  # inherited already; in case a worker is started otherwise
    resolve_gl_backend()  # inherited already (MUJOCO_GL); else chosen before mujoco loads


# A trial already uses more than one core now and then (OpenCV, numba, BLAS, Mesa's
# rasteriser); workers side by side each keep to one thread rather than fight over the cores.
SINGLE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                 "NUMBA_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1", "LP_NUM_THREADS": "1"}


@contextmanager
def one_thread_each() -> Iterator[None]:
    """Worker processes started within inherit single-threaded library settings."""
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD}
    os.environ.update(SINGLE_THREAD)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def pinned_here() -> bool:
    """Whether trials may run in this process: it started with the pinned environment
    and no library chose its code before :func:`pin` set it."""
    return started_pinned() and not late_imports()


@contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """``workers`` local worker processes, started with the pinned environment (and, more
    than one, single-threaded); each dies with this process."""
    pin()
    context = multiprocessing.get_context("spawn")  # no GL context or renderer is inherited
    with (one_thread_each() if workers > 1 else nullcontext()), ProcessPoolExecutor(
            workers, mp_context=context, initializer=init_worker) as pool:
        yield pool


# A worker process that dies (killed, out of memory, a native crash, or aborted by glibc's
# heap check: once in four CI runs of the regression sweep) breaks its whole pool. The
# trials that were in flight on it run again, each alone in a fresh process (so that a
# death names its trial), this many times at most; a trial whose process dies every time
# is failed. Each trial is seeded by its own indices, so a rerun gives what the first run
# would have. The other trials go on on a fresh pool.
TRIAL_ATTEMPTS = 3


class _PoolBrokenError(Exception):
    """A worker of the pool died; ``in_flight`` are the trials it left unfinished."""

    def __init__(self, in_flight: list[TrialSpec], cause: BrokenProcessPool) -> None:
        super().__init__(str(cause))
        self.in_flight = in_flight


def _named(spec: TrialSpec) -> str:
    return (f"trial {spec.trial} at density {spec.density:g} (density index "
            f"{spec.density_index}, seed {spec.seed})")


def _local(specs: list[TrialSpec], workers: int
           ) -> Iterator[dict[str, Any] | TrialFailure]:
    left = list(specs)
    while left:
        finished: set[int] = set()  # ids of the specs whose records were yielded
        try:
            for spec, record in run_on_pool(left, workers):
                finished.add(id(spec))
                yield record
            return
        except _PoolBrokenError as broken:
            print(f"taskcam: a worker process died ({broken}); the {len(broken.in_flight)} "
                  "trial(s) it left unfinished run again, each in a process of its own (up "
                  f"to {TRIAL_ATTEMPTS} times), the others on a fresh pool",
                  file=sys.stderr, flush=True)
            for spec in broken.in_flight:
                finished.add(id(spec))
                outcome = _alone(spec)
                if isinstance(outcome, TrialFailure):
                    print(f"taskcam: {_named(spec)} failed: {outcome.reason}; the sweep goes on",
                          file=sys.stderr, flush=True)
                yield outcome
        left = [spec for spec in left if id(spec) not in finished]


def _alone(spec: TrialSpec) -> dict[str, Any] | TrialFailure:
    """The trial's record, from a process of its own, tried ``TRIAL_ATTEMPTS`` times while
    that process dies; a trial that raises raises here (as from a pool)."""
    deaths = []
    for _ in range(TRIAL_ATTEMPTS):
        outcome = _in_own_process(spec)
        if isinstance(outcome, dict):
            return outcome
        deaths.append(outcome)
    how = sorted(set(deaths))
    reason = (f"worker died with {how[0]}, {len(deaths)} times" if len(how) == 1
              else f"worker died {len(deaths)} times ({', '.join(deaths)})")
    return TrialFailure(spec, len(deaths), reason)


def _run_and_send(spec: TrialSpec, conn: Connection) -> None:
    """In a trial's own process: run it, send its record (or its exception) back."""
    init_worker()
    try:
        result: tuple[str, Any] = ("record", run_trial(spec))
    except Exception as exc:
        result = ("error", exc)
    conn.send(result)
    conn.close()


def _in_own_process(spec: TrialSpec) -> dict[str, Any] | str:
    """The trial's record, run in a fresh pinned process, or how that process died
    (``SIGSEGV``, ``exit status 3``)."""
    pin()
    context = multiprocessing.get_context("spawn")
    receive, send = context.Pipe(duplex=False)
    process = context.Process(target=_run_and_send, args=(spec, send), daemon=True)
    process.start()
    send.close()
    try:
        kind, value = receive.recv()
    except EOFError:  # it died before it sent anything
        process.join()
        code = process.exitcode or 0
        with suppress(ValueError):
            return signal.Signals(-code).name if code < 0 else f"exit status {code}"
        return f"signal {-code}"
    finally:
        receive.close()
    process.join()
    if kind == "error":
        raise value
    return dict(value)


def run_on_pool(specs: list[TrialSpec], workers: int
             ) -> Iterator[tuple[TrialSpec, dict[str, Any]]]:
    """Each spec with its trial's record, run on a pool of ``workers`` processes, in the
    order they finish."""
    with worker_pool(workers) as pool:
        pending: dict[Future[dict[str, Any]], TrialSpec] = {}
        queue = iter(specs)

        def submit(spec: TrialSpec) -> None:
            try:
                pending[pool.submit(run_trial, spec)] = spec
            except BrokenProcessPool as exc:  # a worker died since the last result came
                raise _PoolBrokenError([*pending.values(), spec], exc) from exc

        try:
            for spec in queue:  # keep a few trials per worker queued, not all of them
                submit(spec)
                if len(pending) >= 2 * workers:
                    break
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    spec = pending.pop(future)
                    try:
                        record = future.result()
                    except BrokenProcessPool as exc:
                        raise _PoolBrokenError([spec, *pending.values()], exc) from exc
                    yield spec, record
                    spec_next = next(queue, None)
                    if spec_next is not None:
                        submit(spec_next)
        finally:
            for future in pending:
                future.cancel()


CONNECT_TIMEOUT = "10s"  # to reach a Dask scheduler before calling it unreachable


def _unpinned(client: Any) -> str | None:
    """Why the client's Dask workers cannot run trials (not started pinned); None if
    they can."""
    unpinned = sorted(w for w, ok in client.run(pinned_here).items() if not ok)
    if not unpinned:
        return None
    return (f"worker(s) {', '.join(unpinned)} did not start with taskcam's pinned "
            f"environment ({', '.join(PINS)}), so their results would depend on their "
            "processor: start them with `python -m taskcam.sim.pinned dask worker ADDRESS` "
            "(docs/reproducibility.md)")


def scheduler_problem(address: str) -> str | None:
    """Why a sweep cannot run on the Dask scheduler at ``address`` (unreachable, or
    workers not pinned); None if it can."""
    from distributed import Client

    try:
        with Client(address, timeout=CONNECT_TIMEOUT) as client:
            return _unpinned(client)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        return f"cannot be reached ({exc})"


def _allowed_failures() -> int:
    """On a Dask scheduler: how many of a task's workers may die before it fails."""
    import dask

    return int(dask.config.get("distributed.scheduler.allowed-failures"))


def _dask(specs: list[TrialSpec], address: str
          ) -> Iterator[dict[str, Any] | TrialFailure]:
    from distributed import Client, KilledWorker, as_completed

    with Client(address, timeout=CONNECT_TIMEOUT) as client:
        if (problem := _unpinned(client)) is not None:
            raise RuntimeError(f"Dask {problem}")
        futures = client.map(run_trial, specs, pure=False)
        by_key = {future.key: spec for future, spec in zip(futures, specs, strict=True)}
        try:
            for future in as_completed(futures):
                try:
                    record = future.result()
                except KilledWorker as exc:  # Dask reran it on others: each of them died
                    spec = by_key[future.key]
                    runs = 1 + client.run_on_scheduler(_allowed_failures)
                    failure = TrialFailure(spec, runs, f"Dask workers died running it, "
                                           f"{runs} times ({exc})")
                    print(f"taskcam: {_named(spec)} failed: {failure.reason}; the sweep "
                          "goes on", file=sys.stderr, flush=True)
                    yield failure
                    continue
                yield record
        finally:
            with suppress(Exception):
                client.cancel(futures)


def run_sweep(sweep: Sweep, db: str | Path, workers: int = 1, scheduler: str | None = None,
              resume: bool = False, progress: bool | None = None) -> SweepRun:
    """Run the sweep's trials not yet in ``db`` (those stored as failed run again) and
    store each as it finishes, or as failed if its worker died every time.
    ``progress`` None shows the bar only on a terminal."""
    start = time.perf_counter()
    with Results(db) as results:
        results.start(sweep.describe(), resume)
        done = results.done()
        every = trial_specs(sweep)
        specs = [t for t in every if (t.density_index, t.trial) not in done]
        total, already = len(every), len(every) - len(specs)
        records = _dask(specs, scheduler) if scheduler else _local(specs, workers)
        ran = failed = 0
        with tqdm(total=total, initial=already, unit="trial", disable=None if progress is None
                  else not progress, dynamic_ncols=True, smoothing=0.1) as bar:
            for record in records:
                if isinstance(record, TrialFailure):
                    s = record.spec
                    results.add_failure(s.density_index, s.trial, s.seed, s.density,
                                        record.attempts, record.reason)
                    failed += 1
                else:
                    results.add(record)
                    ran += 1
                bar.update()
    return SweepRun(total, already, ran, failed, time.perf_counter() - start)
