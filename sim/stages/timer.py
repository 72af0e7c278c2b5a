"""Wall-clock seconds per stage of an episode."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class Timer:
    """Accumulates wall-clock seconds per stage, and how often each was timed."""

    def __init__(self) -> None:
        self._totals: dict[str, float] = defaultdict(float)
        self._counts: dict[str, int] = defaultdict(int)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        self._counts[stage] += 1
        start = time.perf_counter()
        try:
            yield
        finally:
            self._totals[stage] += time.perf_counter() - start

    def move(self, seconds: float, source: str, destination: str) -> None:
        """Count ``seconds`` timed as ``source`` under ``destination`` instead (time spent
        on one stage's work inside another's)."""
        self._totals[source] -= seconds
        self._totals[destination] += seconds

    def set(self, stage: str, seconds: float) -> None:
        """The whole of a stage's time, measured elsewhere (s)."""
        self._totals[stage] = seconds

    def rounded(self, digits: int) -> dict[str, float]:
        """Seconds per stage, in the order first timed, rounded to ``digits``."""
        return {k: round(v, digits) for k, v in self._totals.items()}

    def counted(self, digits: int) -> dict[str, dict[str, float]]:
        """Per stage timed by ``with timer(stage)``, in the order first timed: how often
        (``count``) and its wall seconds in all (``time_s``, rounded to ``digits``)."""
        return {k: {"count": n, "time_s": round(self._totals[k], digits)}
                for k, n in self._counts.items()}
