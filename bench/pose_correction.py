"""How well the episode corrects each camera's pose from natural fiducials (issue 6).

Runs the default scenario (errors and correction on) over seeds, and compares, against
the simulator's truth, the camera pose before correction (the commanded one), after it
with each estimator on the same fiducials (the paper's linear fit, Kabsch, SQPnP), and
the bundle adjustment's own last pose. Prints medians, the worst case, and how many
moves meet the target (3 mm and 0.2 degrees).

    .venv/bin/python bench/pose_correction.py [--seeds 12] [--workers 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import sim  # noqa: F401  (pins the processor-dependent code paths before numpy loads)
from sim.world.gl import resolve_gl_backend

resolve_gl_backend()  # an entry point: the GL backend before anything loads mujoco

# isort: split
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import write_results

TARGET_M, TARGET_DEG = 0.003, 0.2


def one_seed(seed: int) -> list[dict[str, Any]]:
    from sim.config.scenario import load_scenario
    from sim.stages.episode import Episode

    episode = Episode(load_scenario(seed=seed))
    start = time.perf_counter()
    summary, _ = episode.run()
    elapsed = time.perf_counter() - start
    rows = []
    for robot in summary["robots"]:
        c = robot.get("correction")
        if c is None:
            continue
        errors = {"before": c["error_before"], "bundle": c.get("bundle_error"),
                  c.get("estimator", "estimator"): c.get("error_after"),
                  **c["other_estimators_error"]}
        rows.append({"seed": seed, "robot": robot["name"], "frames": c["frames"],
                     "located": c["frames_located"], "failed": c.get("failed"),
                     "errors": errors, "correction_s": summary["timings_s"]["correction"],
                     "episode_s": elapsed})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [r for rs in pool.map(one_seed, range(args.seeds)) for r in rs]
    print(f"{len(rows)} moves over {args.seeds} seeds of the default scenario")
    print(f"{'pose':<10} {'median mm':>10} {'median deg':>11} {'worst mm':>9} {'worst deg':>10}"
          f" {'within 3 mm & 0.2 deg':>22}")
    summary = {}
    for name in ("before", "linear", "kabsch", "sqpnp", "bundle"):
        found = [r["errors"].get(name) for r in rows]
        pairs = np.array([(e["position_m"], e["orientation_deg"]) if e else (np.inf, np.inf)
                          for e in found])
        ok = int(np.sum((pairs[:, 0] <= TARGET_M) & (pairs[:, 1] <= TARGET_DEG)))
        med = np.median(pairs, axis=0)
        worst = pairs.max(axis=0)
        summary[name] = {"median_mm": 1e3 * med[0], "median_deg": med[1],
                         "worst_mm": 1e3 * worst[0], "worst_deg": worst[1], "within": ok}
        print(f"{name:<10} {1e3 * med[0]:>10.2f} {med[1]:>11.3f} {1e3 * worst[0]:>9.2f} "
              f"{worst[1]:>10.3f} {ok:>14} of {len(rows)}")
    seconds = sorted({(r["seed"], r["correction_s"]) for r in rows})
    per_move = sum(s for _, s in seconds) / max(len(rows), 1)
    print(f"correction: {per_move:.1f} s per move (frames "
          f"{np.median([r['frames'] for r in rows]):.0f} median, "
          f"{sum(r['located'] for r in rows)} of {sum(r['frames'] for r in rows)} located)")
    for r in rows:
        if r["failed"]:
            print(f"seed {r['seed']} {r['robot']}: failed: {r['failed']}")
    write_results("pose_correction", rows, summary=summary, seconds_per_move=per_move)


if __name__ == "__main__":
    main()
