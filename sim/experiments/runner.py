"""Running a sweep's trials: in this process, on a local process pool, or on a Dask
distributed cluster; each finished trial is stored at once (one transaction), so an
interrupted sweep resumes where it stopped, without losing or repeating a trial.

Trials are independent and seeded by their own indices (sim/config/sweep.py), so the stored
rows are the same whichever worker ran which trial, and in whatever order they ended;
and, their processes pinned to the same code paths (sim/determinism.py), on whichever
machine. A trial runs in this process only if it started pinned; otherwise in a worker
process started with the pinned environment.
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
from pathlib import Path
from typing import Any

from tqdm import tqdm

from sim.config.sweep import Sweep
from sim.determinism import PINS, late_imports, pin, started_pinned
from sim.experiments.results import Results
from sim.experiments.trial import TrialSpec, run_trial
from sim.world.gl import resolve_gl_backend

PR_SET_PDEATHSIG = 1  # prctl option: the signal a process gets when its parent dies


@dataclass(frozen=True)
class SweepRun:
    """What a call to :func:`run_sweep` did."""

    total: int  # trials in the sweep
    already: int  # stored before this call
    ran: int  # finished and stored by this call
    seconds: float


def trial_specs(sweep: Sweep) -> list[TrialSpec]:
    """Every trial of the sweep, the densities interleaved (a partial sweep covers all)."""
    c = sweep.config
    return [TrialSpec(sweep.scenario, c.methods, i, density, k, sweep.trial_seed(i, k))
            for k in range(c.trials) for i, density in enumerate(c.densities)]


def _worker_init() -> None:
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
            workers, mp_context=context, initializer=_worker_init) as pool:
        yield pool


# A worker process that dies (killed, out of memory, or aborted by glibc's heap check:
# once in four CI runs of the regression sweep) breaks its whole pool. The trials the pool
# left unfinished run again on a fresh one, this many times at most; each is seeded by its
# own indices, so it gives what it would have the first time.
POOL_RESTARTS = 2


def _local(specs: list[TrialSpec], workers: int) -> Iterator[dict[str, Any]]:
    if workers == 1 and pinned_here():
        for spec in specs:
            yield run_trial(spec)
        return
    left = list(specs)
    for restart in range(POOL_RESTARTS + 1):
        finished: set[int] = set()  # ids of the specs whose records were yielded
        try:
            for spec, record in _on_pool(left, workers):
                finished.add(id(spec))
                yield record
            return
        except BrokenProcessPool as exc:
            left = [spec for spec in left if id(spec) not in finished]
            if restart == POOL_RESTARTS:
                raise RuntimeError(
                    f"a worker process died {restart + 1} times ({exc}); {len(left)} "
                    "trial(s) not run: run the sweep again with --resume") from exc
            print(f"taskcam: a worker process died ({exc}); its pool's {len(left)} "
                  "unfinished trial(s) run on a fresh one", file=sys.stderr, flush=True)


def _on_pool(specs: list[TrialSpec], workers: int
             ) -> Iterator[tuple[TrialSpec, dict[str, Any]]]:
    """Each spec with its trial's record, run on a pool of ``workers`` processes, in the
    order they finish."""
    with worker_pool(workers) as pool:
        pending: dict[Future[dict[str, Any]], TrialSpec] = {}
        queue = iter(specs)

        def submit(spec: TrialSpec) -> None:
            pending[pool.submit(run_trial, spec)] = spec

        try:
            for spec in queue:  # keep a few trials per worker queued, not all of them
                submit(spec)
                if len(pending) >= 2 * workers:
                    break
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    yield pending.pop(future), future.result()
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
            "processor: start them with `python -m sim.pinned dask worker ADDRESS` "
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


def _dask(specs: list[TrialSpec], address: str) -> Iterator[dict[str, Any]]:
    from distributed import Client, as_completed

    with Client(address, timeout=CONNECT_TIMEOUT) as client:
        if (problem := _unpinned(client)) is not None:
            raise RuntimeError(f"Dask {problem}")
        futures = client.map(run_trial, specs, pure=False)
        try:
            for future in as_completed(futures):
                yield future.result()
        finally:
            with suppress(Exception):
                client.cancel(futures)


def run_sweep(sweep: Sweep, db: str | Path, workers: int = 1, scheduler: str | None = None,
              resume: bool = False, progress: bool | None = None) -> SweepRun:
    """Run the sweep's trials not yet in ``db`` and store each as it finishes.
    ``progress`` None shows the bar only on a terminal."""
    start = time.perf_counter()
    with Results(db) as results:
        results.start(sweep.describe(), resume)
        done = results.done()
        every = trial_specs(sweep)
        specs = [t for t in every if (t.density_index, t.trial) not in done]
        total, already = len(every), len(every) - len(specs)
        records = _dask(specs, scheduler) if scheduler else _local(specs, workers)
        ran = 0
        with tqdm(total=total, initial=already, unit="trial", disable=None if progress is None
                  else not progress, dynamic_ncols=True, smoothing=0.1) as bar:
            for record in records:
                results.add(record)
                ran += 1
                bar.update()
    return SweepRun(total, already, ran, time.perf_counter() - start)
