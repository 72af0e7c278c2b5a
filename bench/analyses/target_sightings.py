"""How far the cameras' target sightings and the secondary targets' stand-ins are from the
simulator's truth, over a sweep's trials.

Run from the repository root, e.g.
``python -m bench.analyses.target_sightings scenarios/table1.toml --density 1 --trials 40
--methods optimal,random``. Each trial is run again (as ``taskcam sweep`` runs it, one
method at a time) and, where the task begins, every sighting the placed cameras made is
compared with where the simulated world has that target (the slot's point; a hole's
face, moved with the work-piece and its ST_error draw), and every stand-in (where a
hole a camera sighted puts the slot; apart, those of cameras placed for that hole) with
the slot's true point: its error (mm) and its
squared Mahalanobis distance under the stand-in's own covariance (for a covariance that
holds, a chi-square of 3 degrees of freedom: mean 3, above 7.81 in 5 % of cases).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from taskcam.mapping import opencv_pose
from taskcam.sim.config.sweep import load_sweep
from taskcam.sim.experiments import trial as trial_module
from taskcam.sim.experiments.runner import trial_specs
from taskcam.sim.stages import insertion
from taskcam.sim.stages.slot_target import SLOT_SITE, is_slot

FAR_MM = 5.0  # 2.5 times the hard tolerance (2 mm): this far off alone fails the task


def true_positions(world: Any, targets: tuple[Any, ...]) -> dict[str, np.ndarray]:
    """Each target's point in the simulated world (m): the slot's site; a hole's face
    moved as its geom was (the work-piece's misplacement and the hole's ST_error)."""
    out = {}
    for t in targets:
        if is_slot(t):
            out[t.name] = world.data.site(SLOT_SITE).xpos.copy()
        else:
            moved = world.data.geom(t.geom).xpos - world.belief.geom(t.geom).xpos
            out[t.name] = t.position + moved
    return out


def observed(rows: list[dict[str, Any]]) -> Any:
    """:func:`insertion.stand_ins` wrapped so that it also files, in ``rows``, every
    sighting's and stand-in's error against the truth."""
    stand_ins = insertion.stand_ins

    def observing(world: Any, at: Any, sightings: Any, targets: Any, frame: Any, slot: Any,
                  prior_sd: Any) -> Any:
        out = stand_ins(world, at, sightings, targets, frame, slot, prior_sd)
        truth = true_positions(world, targets)
        slot_name = next(t.name for t in targets if is_slot(t))
        for s in sightings:
            rows.append({"kind": "slot sighting" if s.target == slot_name else "hole sighting",
                         "error_mm": 1e3 * float(np.linalg.norm(s.position - truth[s.target]))})
        for name, found in out.items():
            pose = opencv_pose(at[name].camera(prior_sd).believed)
            for f in found:
                error = pose[:3, :3] @ f.goal + pose[:3, 3] - truth[slot_name]
                cov = pose[:3, :3] @ f.covariance @ pose[:3, :3].T
                rows.append({"kind": "stand-in, placed for its hole" if f.placed_for
                             else "stand-in, other",
                             "error_mm": 1e3 * float(np.linalg.norm(error)),
                             "d2": float(error @ np.linalg.solve(cov, error)),
                             "sd_mm": 1e3 * float(np.sqrt(np.trace(cov)))})
        return out

    return observing


def summary(values: list[float]) -> str:
    v = np.asarray(values)
    return (f"median {np.median(v):.2f}, 90th percentile {np.percentile(v, 90):.2f}, "
            f"largest {v.max():.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path)
    parser.add_argument("--density", type=int, default=1, help="the density's index")
    parser.add_argument("--trials", type=int, default=20, help="the first N trials")
    parser.add_argument("--methods", default="optimal,random")
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    insertion.stand_ins = observed(rows)
    names = args.methods.split(",")
    for spec in trial_specs(load_sweep(args.sweep)):
        if spec.density_index != args.density or spec.trial >= args.trials:
            continue
        for method in (m for m in spec.methods if m.name in names):
            trial_module.run_trial(dataclasses.replace(spec, methods=(method,)))
    for kind in ("slot sighting", "hole sighting", "stand-in, placed for its hole",
                 "stand-in, other"):
        mine = [r for r in rows if r["kind"] == kind]
        if not mine:
            continue
        errors = [r["error_mm"] for r in mine]
        far = sorted(e for e in errors if e > FAR_MM)
        line = (f"{kind} ({len(mine)}): error mm {summary(errors)}; beyond {FAR_MM:g} mm "
                f"{len(far)}" + (f" ({far[0]:.1f}-{far[-1]:.1f})" if far else ""))
        if "d2" in mine[0]:
            d2 = [r["d2"] for r in mine]
            line += (f"; own sd mm {summary([r['sd_mm'] for r in mine])}; Mahalanobis^2 mean "
                     f"{np.mean(d2):.2f}, above 7.81 in {100 * np.mean(np.array(d2) > 7.81):.0f} %")
        print(line)


if __name__ == "__main__":
    main()
