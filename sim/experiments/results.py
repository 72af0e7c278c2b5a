"""The results database of a sweep (SQLite): one transaction per trial.

Tables:

- ``sweep``: the sweep's description (settings and base scenario, JSON), written once;
  a resumed sweep must match it.
- ``trials``: one row per paired scene (density index, trial): its seed, the requested
  and achieved occlusion density, the obstacle count, mapping, timings and the whole
  record (JSON).
- ``outcomes``: one row per scene and method: placement, secondary targets allowed,
  final displacement, task steps, and ``success`` per tolerance in ``successes``.
- ``failed``: one row per scene whose worker died every time it ran it: its seed,
  requested density, how many times it ran and why it failed. Written by the sweeps
  that have it (a database from before reads as having none); a trial stored later
  leaves it.

Everything a table needs is in ``outcomes`` and ``successes``; the ``record`` column
keeps the rest, so tables can be recomputed without rerunning anything.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sqlite3
import tempfile
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS sweep (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS trials (
    density_index INTEGER NOT NULL, trial INTEGER NOT NULL, seed INTEGER NOT NULL,
    density REAL NOT NULL, achieved_density REAL NOT NULL, obstacles INTEGER NOT NULL,
    time_s REAL NOT NULL, record TEXT NOT NULL,
    PRIMARY KEY (density_index, trial));
CREATE TABLE IF NOT EXISTS outcomes (
    density_index INTEGER NOT NULL, trial INTEGER NOT NULL, method TEXT NOT NULL,
    placement TEXT NOT NULL, secondary INTEGER NOT NULL, final_displacement_m REAL,
    steps INTEGER, stopped_by TEXT,
    PRIMARY KEY (density_index, trial, method));
CREATE TABLE IF NOT EXISTS successes (
    density_index INTEGER NOT NULL, trial INTEGER NOT NULL, method TEXT NOT NULL,
    tolerance REAL NOT NULL, success INTEGER NOT NULL,
    PRIMARY KEY (density_index, trial, method, tolerance));
"""

# Optional: not in TABLES, so that databases written before it are still read.
FAILED_SCHEMA = """
CREATE TABLE IF NOT EXISTS failed (
    density_index INTEGER NOT NULL, trial INTEGER NOT NULL, seed INTEGER NOT NULL,
    density REAL NOT NULL, attempts INTEGER NOT NULL, reason TEXT NOT NULL,
    PRIMARY KEY (density_index, trial))"""


SQLITE_HEADER = b"SQLite format 3\x00"


class ResultsError(ValueError):
    """A file that is not a results database, or one that cannot take this sweep's
    results: ``found`` says what it is, ``accepted`` what would do."""

    def __init__(self, path: Path, found: str, accepted: str, key: str | None = None) -> None:
        self.path, self.found, self.accepted, self.key = path, found, accepted, key
        named = "" if key is None else f"key '{key}': "
        super().__init__(f"{path}: {named}{found}; accepted: {accepted}")

    def given_as(self, key: str) -> ResultsError:
        """The same error, naming the command-line argument that gave the file."""
        return ResultsError(self.path, self.found, self.accepted, key)


def _columns(db: sqlite3.Connection) -> dict[str, list[str]]:
    names = [n for (n,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table' "
                                      "AND name NOT LIKE 'sqlite_%' ORDER BY name")]
    return {n: [c[1] for c in db.execute(f"PRAGMA table_info('{n}')")] for n in names}


def _expected_columns() -> dict[str, list[str]]:
    with sqlite3.connect(":memory:") as db:
        db.executescript(SCHEMA)
        return _columns(db)


TABLES = _expected_columns()  # table -> its columns, from SCHEMA


def _rolled_back_copy(path: Path) -> sqlite3.Connection:
    """An in-memory copy of the database as its last committed transaction left it: SQLite
    rolls a copy of the file and of its hot journal back, the file itself is not touched."""
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / "copy.sqlite"
        shutil.copyfile(path, copy)
        journal = path.with_name(path.name + "-journal")
        if journal.exists():
            shutil.copyfile(journal, copy.with_name(copy.name + "-journal"))
        memory = sqlite3.connect(":memory:")
        with contextlib.closing(sqlite3.connect(copy)) as source:
            source.backup(memory)
    return memory


def open_results(path: Path) -> sqlite3.Connection:
    """A read-only connection to an existing results database (to an in-memory copy if a
    killed sweep left a transaction to roll back); ResultsError, and the file untouched,
    if it is not one: not SQLite, or SQLite without taskcam's tables."""
    what = "a results database written by taskcam sweep"
    try:
        with path.open("rb") as f:
            header = f.read(len(SQLITE_HEADER))
    except OSError as exc:
        raise ResultsError(path, f"unreadable ({exc.strerror})", what) from None
    if header != SQLITE_HEADER:
        raise ResultsError(path, "not a SQLite database", what)
    db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    try:
        try:
            tables = _columns(db)
        except sqlite3.OperationalError as exc:
            if exc.sqlite_errorname != "SQLITE_READONLY_ROLLBACK":
                raise
            db.close()  # a transaction a kill interrupted: read it as rolled back
            db = _rolled_back_copy(path)
            tables = _columns(db)
    except sqlite3.DatabaseError as exc:
        db.close()
        raise ResultsError(path, f"an unreadable SQLite database ({exc})", what) from None
    wrong = sorted(t for t, columns in TABLES.items() if tables.get(t) != columns)
    if wrong:
        db.close()
        missing = [t for t in wrong if t not in tables]
        found = (f"a SQLite database without taskcam's tables {', '.join(missing)}" if missing
                 else f"a SQLite database whose tables {', '.join(wrong)} have other columns")
        raise ResultsError(path, found + f" (it has: {', '.join(tables) or 'no tables'})",
                           f"{what} (tables {', '.join(TABLES)})")
    return db


class Results:
    """A sweep's results database: a new (or empty) file becomes one; an existing file
    must already be one, else ResultsError and the file is left as it was (opened to
    write, SQLite rolls back what a killed sweep left unfinished). ``readonly`` opens an
    existing database only for reading."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        if readonly or (self.path.exists() and self.path.stat().st_size > 0):
            try:
                ro = open_results(self.path)
            except ResultsError as exc:
                if readonly:
                    raise
                raise ResultsError(exc.path, exc.found, f"{exc.accepted}, or a new file") from None
            if readonly:
                self.db = ro
                return
            ro.close()
            self.db = sqlite3.connect(self.path)
        else:
            self.db = sqlite3.connect(self.path)
            self.db.executescript(SCHEMA)

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Results:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------ the sweep

    def description(self) -> dict[str, Any] | None:
        """The sweep the database holds (None: none yet)."""
        row = self.db.execute("SELECT value FROM sweep WHERE key = 'description'").fetchone()
        if row is None:
            return None
        try:
            description = json.loads(row[0])
        except (TypeError, ValueError):
            description = None
        if not isinstance(description, dict):
            raise ResultsError(self.path, "a sweep description that is not a JSON object",
                               "a results database written by taskcam sweep")
        return description

    def start(self, description: dict[str, Any], resume: bool) -> None:
        """Bind the database to a sweep: a new one, or (``resume``) the same one again."""
        problem = self.refusal(description, resume)
        if problem is not None:
            raise problem
        with self.db:
            self.db.execute(FAILED_SCHEMA)
            if self.description() is None:
                self.db.execute("INSERT INTO sweep VALUES ('description', ?)",
                                (json.dumps(description, sort_keys=True),))

    def refusal(self, description: dict[str, Any], resume: bool) -> ResultsError | None:
        """Why this database cannot take the sweep ``description`` (None: it can)."""
        stored = self.description()
        if stored is None:
            return None
        if not resume:
            return ResultsError(self.path, "a database that already holds a sweep",
                                "--resume to continue that sweep, or another --db")
        if _comparable(stored) != _comparable(json.loads(json.dumps(description))):
            return ResultsError(self.path, "a database of a different sweep (its settings "
                                "or base scenario differ)", "another --db")
        return None

    def done(self) -> set[tuple[int, int]]:
        """(density index, trial) of every trial stored (failed trials are not done)."""
        return {(d, t) for d, t in self.db.execute("SELECT density_index, trial FROM trials")}

    def failures(self) -> list[tuple[int, int, int, float, int, str]]:
        """(density index, trial, seed, density, attempts, reason) of every failed trial,
        in key order; none in a database from before failures were stored."""
        if self.db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' "
                           "AND name = 'failed'").fetchone() is None:
            return []
        return list(self.db.execute("SELECT * FROM failed ORDER BY density_index, trial"))

    def add_failure(self, density_index: int, trial: int, seed: int, density: float,
                    attempts: int, reason: str) -> None:
        """Store a trial that could not be run (its worker died every time), in place of
        an earlier failure of it."""
        with self.db:
            self.db.execute(FAILED_SCHEMA)
            self.db.execute("INSERT OR REPLACE INTO failed VALUES (?, ?, ?, ?, ?, ?)",
                            (density_index, trial, seed, density, attempts, reason))

    # ------------------------------------------------------------ trials

    def add(self, record: dict[str, Any]) -> None:
        """Store one trial and its outcomes, all or nothing."""
        key = (record["density_index"], record["trial"])
        with self.db:
            self.db.execute(FAILED_SCHEMA)  # a trial that failed before leaves it
            self.db.execute("DELETE FROM failed WHERE density_index = ? AND trial = ?", key)
            self.db.execute(
                "INSERT INTO trials VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (*key, record["seed"], record["density"], record["achieved_density"],
                 record["obstacles"], record["timings_s"]["total"],
                 json.dumps(record, sort_keys=True)))
            for m in record["methods"]:
                self.db.execute(
                    "INSERT INTO outcomes VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    (*key, m["method"], m["placement"], int(m["secondary"]),
                     m["final_displacement_m"], m["steps"], m["stopped_by"]))
                self.db.executemany(
                    "INSERT INTO successes VALUES (?, ?, ?, ?, ?)",
                    [(*key, m["method"], float(tol), int(ok))
                     for tol, ok in m["success"].items()])

    def successes(self) -> dict[tuple[str, int, float], dict[int, bool]]:
        """Success by (method, density index, tolerance rounded to 6 digits), then by
        trial."""
        out: dict[tuple[str, int, float], dict[int, bool]] = {}
        for method, d, trial, tol, ok in self.db.execute(
                "SELECT method, density_index, trial, tolerance, success FROM successes"):
            out.setdefault((method, d, round(tol, 6)), {})[trial] = bool(ok)
        return out

    def rows(self, table: str) -> list[tuple[Any, ...]]:
        """Every row of ``table`` in key order (timings and the worker left out: they vary
    from run to run)."""
        if table == "trials":
            query = ("SELECT density_index, trial, seed, density, achieved_density, obstacles, "
                     "record FROM trials ORDER BY density_index, trial")
            return [(*row[:-1], _without_timings(json.loads(row[-1])))
                    for row in self.db.execute(query)]
        if table == "failed":
            return list(self.failures())
        if table not in ("outcomes", "successes"):
            raise ResultsError(self.path, f"no table {table!r}",
                               "trials, outcomes, successes, failed")
        return list(self.db.execute(f"SELECT * FROM {table} ORDER BY 1, 2, 3, 4"))


def _without_timings(record: dict[str, Any]) -> str:
    record = dict(record)
    record.pop("timings_s", None)
    record.pop("worker", None)
    record["methods"] = [{k: v for k, v in m.items() if k != "time_s"}
                         for m in record["methods"]]
    return json.dumps(record, sort_keys=True)


def _comparable(description: dict[str, Any]) -> dict[str, Any]:
    """The description without the trial count (a resumed sweep may ask for more)."""
    out = json.loads(json.dumps(description, sort_keys=True))
    out.get("sweep", {}).pop("trials", None)
    return dict(out)
