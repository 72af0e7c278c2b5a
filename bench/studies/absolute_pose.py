"""How far the absolute measurement's panel pose is off the truth: the pose the insertion
task's relative fits start from after the carry, or after a step that measured nothing.

Run from the repository root: ``python -m bench.studies.absolute_pose`` (``--views N``).
The views are bench/studies/measurement_views.py's (Table 1's scene, the panel hanging
35-60 mm above its slot, a stereo pair at a random distance of 0.5-1.2 m and 10-70 deg
off the slot's normal, no occluder, the camera's believed pose off by the pose
correction's residual). In each, ``InsertionTask.measure`` (SGBM points fitted with the
panel's CAD model) starts from the view's guess turned a further 0, 3 and 6 deg about a
random axis: the orientation the task believes before its first fit is the lying pose's
(a few degrees off). Reported per start: the views fitted, and the median and 95th
percentile of the fit's rotation error (deg) and position error (mm).
Prints one table and writes bench/results/absolute_pose.json.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bench.common import print_table, write_results
from bench.studies.measurement_views import POSE_SD_M, Site, StoredImages
from taskcam.sim.stages.task_result import Camera

TURNS_DEG = (0.0, 3.0, 6.0)
DISTANCE_M = (0.5, 1.2)
ANGLE_DEG = (10.0, 70.0)


def rotation_deg(A: np.ndarray, B: np.ndarray) -> float:
    """The angle (deg) of the rotation taking B to A."""
    return math.degrees(float(np.linalg.norm(Rotation.from_matrix(A @ B.T).as_rotvec())))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=150)
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    site = Site(rng)
    errors: dict[float, list[tuple[float, float] | None]] = {t: [] for t in TURNS_DEG}
    try:
        for _ in range(args.views):
            view = site.view(rng.uniform(*DISTANCE_M), rng.uniform(*ANGLE_DEG), 0.0)
            site.task.renderer = StoredImages(site.renderer, view)
            camera = Camera(site.robot, view.believed, POSE_SD_M, "corrected")
            for turn in TURNS_DEG:
                axis = rng.normal(size=3)
                guess = view.guess.copy()
                guess[:3, :3] = Rotation.from_rotvec(
                    math.radians(turn) * axis / np.linalg.norm(axis)).as_matrix() @ guess[:3, :3]
                pose, _ = site.task.measure([camera], guess)
                errors[turn].append(None if pose is None else (
                    rotation_deg(pose[:3, :3], view.true_panel[:3, :3]),
                    1e3 * float(np.linalg.norm(pose[:3, 3] - view.true_panel[:3, 3]))))
    finally:
        site.close()
    rows: list[dict[str, Any]] = []
    for turn, found in errors.items():
        ok = np.array([e for e in found if e is not None]).reshape(-1, 2)
        rows.append({"case": f"start turned {turn:g} deg: views fitted", "ours": len(ok),
                     "peer": len(found), "ratio": len(ok) / max(len(found), 1), "unit": "views"})
        for column, name, unit in ((0, "rotation", "deg"), (1, "position", "mm")):
            for q in (50, 95):
                value = float(np.percentile(ok[:, column], q)) if len(ok) else None
                rows.append({"case": f"start turned {turn:g} deg: {name} p{q}", "ours": value,
                             "peer": None, "ratio": None, "unit": unit})
    print_table(rows)
    write_results("absolute_pose", rows, views=args.views)


if __name__ == "__main__":
    main()
