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
