"""What the stereo geometry allows the task's fused displacement, at the views the rating
function chose, beside what the task measured there.

Run from the repository root on the run directories of ``taskcam run`` (their
``summary.json``): ``python -m bench.analyses.fused_geometry RUN [RUN ...]``. For every measured
step of each run's task:

- **geometry, the cameras that fitted the slot**: each camera that fitted the slot's
  rails itself at that step (not through a secondary target) contributes the covariance
  bench/studies/measurement.py's ``predicted_sd`` gives a displacement at its distance from the
  slot (each end located to 0.1 px in each image: lateral across its line of sight,
  axial along it); the cameras are fused by inverse covariance, as the task fuses them;
- **geometry, every placed camera**: the same with every camera, where it stands at
  that step, taken to fit the slot (the best the chosen views allow);
- **measured**: the task's fused displacement minus the true one.

Each is reported as the 95th percentile of |error| per world axis (the geometry's:
1.96 sd, its median over the steps), over all steps and over the final approach (true
displacement under ``--near`` mm). Pure arithmetic on the summaries: no rendering.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from bench.studies.measurement import AXIS_QUANTILES, predicted_sd

P95 = AXIS_QUANTILES[1]  # |N(0, s)| of one axis: 95th percentile at 1.96 s


def view_covariance(camera: np.ndarray, slot: np.ndarray, fx_px: float, baseline_m: float
                    ) -> np.ndarray:
    """The geometry's covariance (world, m^2) of a displacement at ``slot`` seen from
    ``camera`` (world, m): ``predicted_sd``'s lateral variance across the line of sight,
    its axial variance along it."""
    sight = slot - camera
    depth = float(np.linalg.norm(sight))
    along = np.outer(sight, sight) / depth ** 2
    lateral, axial = predicted_sd(depth, fx_px, baseline_m)
    return lateral ** 2 * (np.eye(3) - along) + axial ** 2 * along


def fused_p95(covariances: list[np.ndarray]) -> np.ndarray | None:
    """Per world axis, the 95th percentile (m) of |error| of the inverse-covariance
    fusion of ``covariances``; None for none."""
    if not covariances:
        return None
    fused = np.linalg.inv(sum(np.linalg.inv(c) for c in covariances))
    return P95 * np.sqrt(np.diag(fused))


def camera_positions(summary: dict[str, Any]) -> dict[str, list[tuple[int, np.ndarray]]]:
    """Per robot, (from step, true camera position) for each of its placements."""
    out = {}
    for robot in summary["robots"]:
        out[robot["name"]] = [(-1 if p["step"] is None else int(p["step"]),
                               np.array(p["pose"]["position"]))
                              for p in robot["placements"] if p.get("pose")]
    return out


def position_at(placements: list[tuple[int, np.ndarray]], step: int) -> np.ndarray:
    """Where a camera stood at ``step``: its last placement made before it."""
    return [p for s, p in placements if s < step][-1]


def steps(summary: dict[str, Any], fx_px: float, baseline_m: float
          ) -> list[dict[str, Any]]:
    """Per measured step: |true displacement| (m) and the three p95s (m, per axis)."""
    slot = np.array(summary["target_frame"]["targets"]["slot"]["position"])
    placements = camera_positions(summary)
    rows = []
    for m in summary["task"]["measurements_log"]:
        if not m.get("fused"):
            continue
        truth = np.array(m["true_displacement"])
        where = {n: position_at(p, m["step"]) for n, p in placements.items() if p}
        fitted = [n for n, c in m["cameras"].items()
                  if (c.get("edges") or {}).get("slot") and not c.get("via")]
        rows.append({
            "true_m": float(np.linalg.norm(truth)),
            "fitted": fused_p95([view_covariance(where[n], slot, fx_px, baseline_m)
                                 for n in fitted]),
            "every": fused_p95([view_covariance(p, slot, fx_px, baseline_m)
                                for p in where.values()]),
            "measured": np.abs(np.array(m["fused"]["displacement"]) - truth)})
    return rows


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Steps, and per world axis (mm): the geometry's p95 (median over the steps) for
    the cameras that fitted the slot and for every camera, the measured p95."""
    def geometry(key: str) -> list[float] | None:
        values = [r[key] for r in rows if r[key] is not None]
        return np.round(1e3 * np.median(values, axis=0), 2).tolist() if values else None

    measured = np.array([r["measured"] for r in rows])
    return {"steps": len(rows), "fitted_slot": geometry("fitted"),
            "every_camera": geometry("every"),
            "measured": np.round(1e3 * np.percentile(measured, 95, axis=0), 2).tolist()
            if len(rows) else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="taskcam run directories")
    parser.add_argument("--near", type=float, default=5.0,
                        help="the final approach: true displacement under this (mm)")
    parser.add_argument("--fx", type=float, default=416.0, help="focal length (px)")
    parser.add_argument("--baseline", type=float, default=0.12, help="stereo baseline (m)")
    args = parser.parse_args()
    every: list[dict[str, Any]] = []
    for run in args.runs:
        summary = json.loads((run / "summary.json").read_text())
        rows = steps(summary, args.fx, args.baseline)
        every += rows
        print(f"{run.name}: {summarise(rows)}")
    near = [r for r in every if r["true_m"] < args.near / 1e3]
    print("p95 |error| per world axis x, y, z (mm); geometry at 0.1 px per end and image")
    print(f"all steps:           {summarise(every)}")
    print(f"under {args.near:g} mm to go: {summarise(near)}")


if __name__ == "__main__":
    main()
