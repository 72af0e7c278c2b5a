"""How far from their targets the placed cameras end, per method and density, in one
or more sweep results databases (``taskcam sweep``'s): the distribution the planner's
reach shapes.

Run from the repository root: ``python -m bench.analyses.camera_distances DB [DB ...]`` (e.g.
``docs/table1/table1.sqlite``, the committed Table 1). For every trial and method,
each placed robot's camera position (the record's ``robots``) is measured to the
target it viewed, at its nominal place in the sweep's scene (the work-piece's
per-trial error, about 1 cm, is left out). Prints per database, density and method
the cameras counted, the 10th / 50th / 90th percentile of the distance (m) and the
share nearer than 0.9 m; ``--markdown`` prints the same as a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sqlite3
from collections import defaultdict
from pathlib import Path

import numpy as np

from bench.common import SCENARIOS
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.stages.slot_target import SLOT, SLOT_SITE
from taskcam.sim.world.scene import build_scene

TABLE1 = SCENARIOS / "table1.toml"
NEAR_M = 0.9  # the "nearer than 0.9 m"


def target_positions() -> dict[str, np.ndarray]:
    """Each target's nominal position (m) in Table 1's scene: the holes, and the slot
    (the task's primary target) at its own point between the rails' feet."""
    import mujoco  # after sim's pins

    scenario = load_sweep(TABLE1).scenario
    scene = build_scene(dataclasses.replace(scenario, obstacles=()))
    data = scene.make_data()
    mujoco.mj_kinematics(scene.model, data)
    return {t.name: np.asarray(t.position) for t in scene.targets} | {
        SLOT: data.site(SLOT_SITE).xpos.copy()}


def distances(db: Path, targets: dict[str, np.ndarray]) -> dict[tuple[float, str], list[float]]:
    """(density, method) -> the placed cameras' distances to their targets (m)."""
    out: dict[tuple[float, str], list[float]] = defaultdict(list)
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            for method in json.loads(record)["methods"]:
                for robot in method["robots"]:
                    if robot["placed"] and robot.get("target") in targets:
                        position = np.asarray(robot["position"])
                        out[(density, method["method"])].append(
                            float(np.linalg.norm(position - targets[robot["target"]])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dbs", nargs="+", type=Path)
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args()
    targets = target_positions()
    if args.markdown:
        print("| results | density | method | cameras | p10 (m) | median (m) | p90 (m) | "
              f"< {NEAR_M} m |")
        print("|---|---|---|---|---|---|---|---|")
    for db in args.dbs:
        for (density, method), d in sorted(distances(db, targets).items()):
            p10, p50, p90 = np.percentile(d, [10, 50, 90])
            near = float(np.mean(np.array(d) < NEAR_M))
            if args.markdown:
                print(f"| {db.name} | {density:.0%} | {method} | {len(d)} | {p10:.2f} | "
                      f"{p50:.2f} | {p90:.2f} | {near:.0%} |")
            else:
                print(f"{db.name:24} {density:>5.0%} {method:18} {len(d):5d}  p10 {p10:.2f}  "
                      f"median {p50:.2f}  p90 {p90:.2f}  nearer than {NEAR_M} m {near:.0%}")


if __name__ == "__main__":
    main()
