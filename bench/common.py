"""Helpers shared by the benchmarks: machine description, timing, results files."""

from __future__ import annotations

import json
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> dict[str, Any]:
    versions: dict[str, str | None] = {}
    for package in ("mujoco", "numpy", "numba", "octomap-python"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {"platform": platform.platform(), "processor": platform.processor(),
            "cpus": os.cpu_count(), "python": platform.python_version(), **versions}


def write_results(name: str, rows: list[dict[str, Any]], **extra: Any) -> Path:
    """``bench/results/NAME.json`` as DESIGN.md section 7 describes."""
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({"benchmark": name, "machine": machine(), "rows": rows, **extra},
                               indent=2) + "\n")
    return path


def print_table(rows: list[dict[str, Any]]) -> None:
    print(f"{'case':<44} {'ours':>14} {'peer':>14} {'ratio':>8}  unit")
    for r in rows:
        ours = "-" if r["ours"] is None else f"{r['ours']:.4g}"
        peer = "-" if r["peer"] is None else f"{r['peer']:.4g}"
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.3g}"
        print(f"{r['case']:<44} {ours:>14} {peer:>14} {ratio:>8}  {r['unit']}")
