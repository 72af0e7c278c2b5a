"""What the bad-input tests share: ``taskcam`` run in this process, and the one-line
error they expect."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from taskcam.sim.cli import main
from taskcam.sim.config.scenario import SCENARIO_DIR
from taskcam.sim.config.schema import one_line

SMOKE = (SCENARIO_DIR / "smoke.toml").read_text()


def cli(*argv: str) -> tuple[int, str]:
    """``taskcam`` in this process: exit code and stderr."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(list(argv))
        except SystemExit as stop:  # argparse
            code = int(stop.code or 0)
    return code, err.getvalue()


def assert_one_line_error(code: int, err: str, source: Path | str, key: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"taskcam: error: {one_line(str(source))}"), err
    assert f"key '{one_line(key)}'" in lines[0] and "accepted: " in lines[0], err
    assert "Traceback" not in err


