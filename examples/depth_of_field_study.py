"""A study scripted with taskcam as a library: where does the rating function place a
camera as its lens's depth of field moves away?

The rating (eq. 1) grows as the camera nears its target (more pixels on it) and is zero
where the target would be out of focus: the best view should stand just beyond the depth
of field's near limit, as long as the robot can reach there. This script builds one
scenario in code (a robot, the work-piece, a post beside it), varies the near limit,
runs each episode's stages (mapping, placement, moving there, looking), reads where each
camera went from the episode's summary, and plots the distance against the near limit.

    MUJOCO_GL=egl .venv/bin/python examples/depth_of_field_study.py --out runs/dof-study

It writes ``dof_study.json`` (a row per near limit) and ``dof_study.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from taskcam.sim.determinism import pin

pin()  # the pinned arithmetic, before numpy and the others load (sim/determinism.py)

from taskcam.sim.world.gl import resolve_gl_backend  # noqa: E402

resolve_gl_backend()  # MUJOCO_GL, before mujoco loads

from taskcam.sim.config.scenario import Scenario, parse_scenario  # noqa: E402
from taskcam.sim.run_screen import distance_m  # noqa: E402
from taskcam.sim.stages.episode import Episode  # noqa: E402


def scenario(near_m: float, seed: int = 0) -> Scenario:
    """One robot, the work-piece with two holes, a post beside it; no task, and the
    camera reaching its pose as commanded (no positioning error to correct)."""
    return parse_scenario({
        "name": f"near{near_m:g}", "seed": seed,
        "camera": {"fovy_deg": 60.0, "width": 640, "height": 480, "near_m": near_m,
                   "far_m": 1.5},
        "robots": {"count": 1, "move_base": True,
                   "bases": [{"x": -1.6, "y": -0.4, "yaw_deg": 15.0}]},
        "workpiece": {"position": [0.0, 0.0], "targets": [
            {"name": "primary", "role": "primary", "offset_m": [0.05, 0.0], "radius_m": 0.02},
            {"name": "secondary", "role": "secondary", "offset_m": [0.17, 0.1],
             "radius_m": 0.015, "st_error_m": 0.001}]},
        "obstacles": [{"shape": "cylinder", "position": [-0.4, -0.3, 0.5], "size": [0.05, 0.5]}],
        # the base's way planned in the scene as it is (as scenarios/table1.toml does):
        # one robot maps only its own side, and the study is of the views, not the ways
        "search": {"planner_world": "model"},
        "task": {"enabled": False},
        "correction": {"enabled": False},
        "motion": {"joint_offset_deg": 0.0, "joint_noise_deg": 0.0, "base_offset_m": 0.0,
                   "base_yaw_deg": 0.0, "suspension_deg": 0.0},
    })


def study(near_limits: list[float], seed: int = 0) -> list[dict[str, Any]]:
    """Each near limit's episode: where its camera went (m from its target), its rating
    and the rating's resolution term."""
    rows = []
    for near in near_limits:
        summary, _ = Episode(scenario(near, seed)).run()
        robot = summary["robots"][0]
        rows.append({"near_m": near, "placed": robot["placed"],
                     "target": robot.get("target", {}).get("name"),
                     "distance_m": distance_m(robot),
                     "rating": robot.get("rating", {}).get("total"),
                     "resolution": robot.get("rating", {}).get("resolution")})
    return rows


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    placed = [r for r in rows if r["placed"]]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot([r["near_m"] for r in placed], [r["distance_m"] for r in placed], "o-",
            label="placed camera")
    ax.plot([r["near_m"] for r in rows], [r["near_m"] for r in rows], "--", color="grey",
            label="near limit")
    ax.legend()
    ax.set_xlabel("depth of field's near limit (m)")
    ax.set_ylabel("camera to target (m)")
    ax.set_title("Where the rating function places the camera")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--near", type=float, nargs="+", default=[0.35, 0.45, 0.55],
                        help="the depth of field's near limits to try (m)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/dof-study"))
    args = parser.parse_args()
    rows = study(args.near, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "dof_study.json").write_text(json.dumps(rows, indent=2) + "\n")
    plot(rows, args.out / "dof_study.png")
    for r in rows:
        where = f"{r['distance_m']:.2f} m from {r['target']}" if r["placed"] else "not placed"
        print(f"near limit {r['near_m']:g} m: {where}")


if __name__ == "__main__":
    main()
