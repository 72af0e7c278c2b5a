"""The results database of a sweep (SQLite): one transaction per trial.

Tables:

- ``sweep``: the sweep's description (settings and base scenario, JSON), written once;
  a resumed sweep must match it.
- ``trials``: one row per paired scene (density index, trial): its seed, the requested
  and achieved occlusion density, the obstacle count, mapping, timings and the whole
  record (JSON).
- ``outcomes``: one row per scene and method: placement, secondary targets allowed,
  final displacement, task steps, and ``success`` per tolerance in ``successes``.

Everything a table needs is in ``outcomes`` and ``successes``; the ``record`` column
keeps the rest, so tables can be recomputed without rerunning anything.
"""

from __future__ import annotations

import json
import sqlite3
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


class ResultsError(ValueError):
    """A database that cannot take this sweep's results."""


class Results:
    """A sweep's results database."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
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
        row = self.db.execute("SELECT value FROM sweep WHERE key = 'description'").fetchone()
        return None if row is None else json.loads(row[0])

    def start(self, description: dict[str, Any], resume: bool) -> None:
        """Bind the database to a sweep: a new one, or (``resume``) the same one again."""
        stored = self.description()
        if stored is None:
            with self.db:
                self.db.execute("INSERT INTO sweep VALUES ('description', ?)",
                                (json.dumps(description, sort_keys=True),))
            return
        if not resume:
            raise ResultsError(f"{self.path} already holds results; pass --resume to "
                               "continue that sweep, or choose another --db")
        if _comparable(stored) != _comparable(json.loads(json.dumps(description))):
            raise ResultsError(f"{self.path} holds a different sweep (its settings or base "
                               "scenario differ); choose another --db")

    def done(self) -> set[tuple[int, int]]:
        """(density index, trial) of every trial stored."""
        return {(d, t) for d, t in self.db.execute("SELECT density_index, trial FROM trials")}

    # ------------------------------------------------------------ trials

    def add(self, record: dict[str, Any]) -> None:
        """Store one trial and its outcomes, all or nothing."""
        key = (record["density_index"], record["trial"])
        with self.db:
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

    def rows(self, table: str) -> list[tuple[Any, ...]]:
        """Every row of ``table`` in key order (timings and the worker left out: they vary
    from run to run)."""
        if table == "trials":
            query = ("SELECT density_index, trial, seed, density, achieved_density, obstacles, "
                     "record FROM trials ORDER BY density_index, trial")
            return [(*row[:-1], _without_timings(json.loads(row[-1])))
                    for row in self.db.execute(query)]
        if table not in ("outcomes", "successes"):
            raise ValueError(f"no table {table!r}; tables: trials, outcomes, successes")
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
