"""Output paths checked before any work: a command that would fail to write its results
after minutes of work says so at once, in one line naming the option, the path and why.

A path passes when it can be created and written: each missing folder is made and a
probe file written there, then both are removed again, so a check leaves nothing
behind. Trying, rather than reading permission bits, gives the answer the write itself
would give, as any user (root writes through permission bits, not to a path under a
regular file, to ``/proc`` or to a read-only mount).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from taskcam.sim.config.schema import ScenarioError


class OutputPathError(ScenarioError):
    """An output path that cannot be written: ``option``, ``path`` and ``reason``."""

    def __init__(self, option: str, path: Path, reason: str, accepted: str) -> None:
        key = option.lstrip("-")
        super().__init__(option, key, str(path), accepted, problem="cannot write")
        self.path, self.reason = path, reason
        self.args = (f"{option}: key '{key}': cannot write '{path}': {reason}; "
                     f"accepted: {accepted}",)


def _nearest_existing(path: Path) -> Path:
    """``path`` or the nearest of its parents that exists (the current folder at worst)."""
    absolute = Path(os.path.abspath(path))
    while not os.path.lexists(absolute) and absolute != absolute.parent:
        absolute = absolute.parent
    return absolute


def _probe(folder: Path) -> str | None:
    """Why ``folder`` (a directory, made if missing, then removed again) cannot be
    written, or None when it can."""
    base = _nearest_existing(folder)
    if not base.is_dir():
        return f"{base} is {'a file' if base.is_file() else 'not a directory'}"
    missing = Path(os.path.abspath(folder)).relative_to(base).parts
    made: list[Path] = []
    try:
        here = base
        for part in missing:
            here = here / part
            try:
                here.mkdir()
            except OSError as exc:
                return f"cannot create {here} ({exc.strerror or exc})"
            made.append(here)
        try:
            handle, probe = tempfile.mkstemp(prefix=".taskcam-probe-", dir=here)
        except OSError as exc:
            return f"cannot write in {here} ({exc.strerror or exc})"
        os.close(handle)
        os.unlink(probe)
        return None
    finally:
        for folder_made in reversed(made):
            with contextlib.suppress(OSError):  # only what this check made, if empty
                folder_made.rmdir()


def _file_problem(path: Path) -> str | None:
    """Why an existing ``path`` cannot be overwritten as a file, or None."""
    if not os.path.lexists(path):
        return None
    if path.is_dir():
        return f"{path} is a directory"
    try:
        with open(path, "ab"):  # opened to append, not truncated: nothing changes
            pass
    except OSError as exc:
        return f"cannot write {path} ({exc.strerror or exc})"
    return None


def check_directory(option: str, path: Path, files: Iterable[str] = (),
                    folders: Iterable[str] = ()) -> None:
    """Raise OutputPathError unless ``path`` can be created (if missing) and written,
    and each of the ``files`` and ``folders`` the command writes into it can be."""
    accepted = "a directory taskcam can create and write into"
    if path.exists() and not path.is_dir():
        raise OutputPathError(option, path, "it is a file", accepted)
    if (why := _probe(path)) is not None:
        raise OutputPathError(option, path, why, accepted)
    for name in files:
        if (why := _file_problem(path / name)) is not None:
            raise OutputPathError(option, path, why, accepted)
    for name in folders:
        inner = path / name
        if os.path.lexists(inner) and not inner.is_dir():
            raise OutputPathError(option, path, f"{inner} is not a directory", accepted)
        if inner.is_dir() and (why := _probe(inner)) is not None:
            raise OutputPathError(option, path, why, accepted)


def check_file(option: str, path: Path) -> None:
    """Raise OutputPathError unless the file ``path`` can be written (made or appended to)
    in a directory that can be created and written (SQLite writes its journal beside)."""
    accepted = "a file path taskcam can create and write"
    if path.is_dir():
        raise OutputPathError(option, path, "it is a directory", accepted)
    if (why := _probe(path.parent)) is not None:
        raise OutputPathError(option, path, why, accepted)
    if (why := _file_problem(path)) is not None:
        raise OutputPathError(option, path, why, accepted)
