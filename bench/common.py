"""The harness the benchmarks share: the repository's paths, the machine's description,
the results file each writes, the table each prints and resumable per-scene records.

The rest of the set-up (the code paths pinned, the GL backend chosen) is done by
importing the ``bench`` package itself, before any script's module loads."""

from __future__ import annotations

import json
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent  # the repository
RESULTS = ROOT / "bench" / "results"
SCENARIOS = ROOT / "scenarios"


def machine() -> dict[str, Any]:
    """The platform, processor, core count and the versions of the packages that set a
    benchmark's speed."""
    versions: dict[str, str | None] = {}
    for package in ("mujoco", "numpy", "numba", "octomap-python"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {"platform": platform.platform(), "processor": platform.processor(),
            "cpus": os.cpu_count(), "python": platform.python_version(), **versions}


def write_results(name: str, rows: list[dict[str, Any]], *, to: Path | None = None,
                  **extra: Any) -> Path:
    """``bench/results/NAME.json`` (or ``to``), which each benchmark writes as
    docs/benchmarks.md says: the rows of the table it prints (case, ours, peer, ratio,
    unit), the machine and the benchmark's own ``extra`` fields after them."""
    path = RESULTS / f"{name}.json" if to is None else to
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"benchmark": name, "machine": machine(), "rows": rows, **extra},
                               indent=2) + "\n")
    return path


def print_table(rows: list[dict[str, Any]]) -> None:
    """The rows as written to the results file, one a line: case, ours, peer, ratio, unit."""
    print(f"{'case':<44} {'ours':>14} {'peer':>14} {'ratio':>8}  unit")
    for r in rows:
        ours = "-" if r["ours"] is None else f"{r['ours']:.4g}"
        peer = "-" if r["peer"] is None else f"{r['peer']:.4g}"
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.3g}"
        print(f"{r['case']:<44} {ours:>14} {peer:>14} {ratio:>8}  {r['unit']}")


def done_records(path: Path) -> dict[int, dict[str, Any]]:
    """The scenes finished in a scenes.jsonl, the last record of each (a line cut short
    by a kill is ignored): what a resumed run skips."""
    records: dict[int, dict[str, Any]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue
            records[int(record["index"])] = record
    return records


def append(path: Path, record: dict[str, Any]) -> None:
    """One finished scene's record, on disk at once (a kill loses nothing finished)."""
    with path.open("a") as fh:
        fh.write(json.dumps(record) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
