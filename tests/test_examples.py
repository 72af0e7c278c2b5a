"""The examples run as a user runs them, so that they cannot rot."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_depth_of_field_study(tmp_path):
    """The scripted study runs; the rating puts each camera just beyond the depth of
    field's near limit (in focus, and as near as focus allows: within the target's radius
    before it, 0.15 m beyond)."""
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "depth_of_field_study.py"),
                           "--near", "0.35", "0.5", "--out", str(tmp_path)],
                          capture_output=True, text=True, cwd=tmp_path, timeout=900,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    rows = json.loads((tmp_path / "dof_study.json").read_text())
    assert [r["near_m"] for r in rows] == [0.35, 0.5]
    for r in rows:
        assert r["placed"], r
        assert r["near_m"] - 0.02 <= r["distance_m"] <= r["near_m"] + 0.15, r
    assert rows[1]["distance_m"] > rows[0]["distance_m"]
    picture = cv2.imread(str(tmp_path / "dof_study.png"))
    assert picture is not None and picture.std() > 5
    assert "near limit 0.5 m: " in done.stdout


@pytest.mark.slow
def test_a_users_own_placement_method_runs_in_a_sweep_on_spawned_workers(tmp_path):
    """examples/nearest_first.toml names examples/nearest_first.py's method as
    "module:callable": two workers (spawned processes, which import it by that name) run
    its two scenes, whose outcomes are stored under its name. It places both cameras on
    the slot, and in each scene its nearest camera (the first, free to take the nearest
    view it reaches) stands nearer the slot than any camera the paper's biased random
    placed (the recorded slot_distance_m)."""
    from taskcam.sim.experiments.results import Results

    sweep_file = ROOT / "examples" / "nearest_first.toml"
    db = tmp_path / "nearest.sqlite"
    done = subprocess.run([sys.executable, "-m", "taskcam.sim.cli", "sweep", str(sweep_file),
                           "--db", str(db), "--workers", "2"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    with Results(db) as results:
        placements = sorted(results.db.execute("SELECT trial, method, placement FROM outcomes"))
        records = [json.loads(r) for (r,) in results.db.execute("SELECT record FROM trials")]
    assert placements == [(k, m, p) for k in (0, 1) for m, p in
                          (("nearest", "examples.nearest_first:method"),
                           ("random", "biased_random"))]
    assert len(records) == 2
    for record in records:
        distance = {o["method"]: [r["slot_distance_m"] for r in o["robots"] if r["placed"]]
                    for o in record["methods"]}
        nearest = next(o for o in record["methods"] if o["method"] == "nearest")
        assert all(r["placed"] and r["target"] == "slot" for r in nearest["robots"]), nearest
        assert distance["random"] and min(distance["nearest"]) < min(distance["random"]), distance
