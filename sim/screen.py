"""What a command prints while it works, on stderr: a line as each stage ends and, on a
terminal, a live meter inside the long stages (a robot's move with its correction's
frames, the task's steps), the way tqdm draws them. Not on a terminal (a log, a pipe), a
meter prints nothing; quiet, neither does a line.

The stages see only :data:`Meter`: given a label, a unit and a total (None: open-ended),
a context whose value is told how far the work has come (in units, from the start).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import TextIO

from tqdm import tqdm

Advance = Callable[[float], None]  # told the work done so far, in the meter's unit
Meter = Callable[[str, str, float | None], AbstractContextManager[Advance]]


def _ignore(done: float) -> None:
    """An advance nobody sees."""


@contextmanager
def no_meter(label: str, unit: str, total: float | None = None) -> Iterator[Advance]:
    """A meter that shows nothing (the stages' default)."""
    yield _ignore


class Screen:
    """Stage lines and meters on ``stream`` (default: stderr). ``quiet``: nothing at all;
    ``live``: meters are drawn (default: when ``stream`` is a terminal)."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False,
                 live: bool | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.quiet = quiet
        isatty = getattr(self.stream, "isatty", None)
        self.live = (bool(isatty and isatty()) if live is None else live) and not quiet

    def line(self, text: str) -> None:
        """A line, ``taskcam: text``, unless quiet."""
        if not self.quiet:
            print(f"taskcam: {text}", file=self.stream, flush=True)

    @contextmanager
    def meter(self, label: str, unit: str, total: float | None = None) -> Iterator[Advance]:
        """A live meter of ``label``'s work in ``unit`` s (out of ``total``), erased when
        the work ends; nothing unless live."""
        if not self.live:
            yield _ignore
            return
        with tqdm(total=total, desc=f"taskcam: {label}", unit=f" {unit}", leave=False,
                  file=self.stream, dynamic_ncols=True, mininterval=0.2) as bar:
            def advance(done: float) -> None:
                if done > bar.n:
                    bar.update(done - bar.n)
            yield advance
