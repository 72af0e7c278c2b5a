"""What secondary targets do to a placement's tasks, scene by scene, in a sweep results
database (``taskcam sweep``'s), e.g. ``docs/table1/full.sqlite``.

Run from the repository root: ``python -m bench.analyses.secondary_targets DB [--tolerance 0.01]``.
For each placement method that ran both with and without secondary targets on the same
scenes (the sweep's paired methods, e.g. ``optimal`` and ``optimal_primary``) and each
density: successes at the tolerance (a fraction of the panel's size) either way, the
scenes met one way only and the exact two-sided McNemar test on them; and, of the
scenes met only without secondary targets, in how many a camera was placed for a secondary
target (a hole: neither the slot nor, during the task, the insertion site), how many of those tasks
stopped believing the panel within the tolerance (not at the step bound, nor having lost
the panel) and how far from the slot they ended (mm). ``bench/analyses/target_sightings.py``
measures the holes' sightings and stand-ins against the truth.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
from collections import defaultdict
from pathlib import Path
from typing import Any

from taskcam.calibration.displacement import STOPPED_WITHIN
from taskcam.sim.experiments.orderings import mcnemar
from taskcam.sim.stages.site_view import SITE
from taskcam.sim.stages.slot_target import SLOT


def pairs(db: Path) -> dict[tuple[str, str], dict[float, list[tuple[dict[str, Any],
                                                                    dict[str, Any]]]]]:
    """Per (method with secondary targets, the same placement without) and density, the
    two methods' records of every scene both ran."""
    out: dict[tuple[str, str], dict[float, list[tuple[dict[str, Any], dict[str, Any]]]]] = (
        defaultdict(lambda: defaultdict(list)))
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        for density, record in c.execute("SELECT density, record FROM trials"):
            methods = json.loads(record)["methods"]
            for with_ in (m for m in methods if m["secondary"]):
                for without in (m for m in methods if not m["secondary"]
                                and m["placement"] == with_["placement"]):
                    out[(with_["method"], without["method"])][density].append((with_, without))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("db", type=Path)
    parser.add_argument("--tolerance", default="0.01", help="as the records key it")
    args = parser.parse_args()
    tol = args.tolerance
    for (with_name, without_name), by_density in sorted(pairs(args.db).items()):
        print(f"{with_name} (with secondary targets) against {without_name} (without), "
              f"tolerance {tol}")
        for density, scenes in sorted(by_density.items()):
            met = [(w["success"][tol], o["success"][tol]) for w, o in scenes]
            only_with = sum(a and not b for a, b in met)
            lost = [w for w, o in scenes if o["success"][tol] and not w["success"][tol]]
            hole = sum(any(r["placed"] and r["target"] not in (SLOT, SITE) for r in w["robots"])
                       for w in lost)
            own = sorted(1e3 * w["final_displacement_m"] for w in lost
                         if w["stopped_by"].startswith(STOPPED_WITHIN)
                         and w["final_displacement_m"] is not None)
            ended = f"{own[0]:.1f}-{own[-1]:.1f} mm" if own else "-"
            print(f"  {100 * density:g} %: {sum(a for a, _ in met)} and "
                  f"{sum(b for _, b in met)} of {len(met)}; met only with {only_with}, "
                  f"only without {len(lost)} (McNemar p = {mcnemar(only_with, len(lost)):.2g}); "
                  f"of those, a camera for a hole in {hole}, stopped believing it within "
                  f"{len(own)} (ended {ended})")


if __name__ == "__main__":
    main()
