"""Wall-clock seconds per stage of an episode."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class Timer:
    """Accumulates wall-clock seconds per stage."""

    def __init__(self) -> None:
        self._totals: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
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
