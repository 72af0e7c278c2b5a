"""The paper's Figure 7: the optimum switches to the secondary target, in 2-D and in 3-D."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from taskcam.sim.cli import main
from taskcam.sim.config.scenario import SCENARIO_DIR
from taskcam.sim.experiments.figure7 import INSTANCES, PRIMARY, rate_instance


def test_figure7_command_writes_heatmaps_and_numbers(tmp_path, capsys):
    assert main(["figure7", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "figure7.json").read_text())
    a, b = report["instances"]
    assert a["target"] == "primary" and b["target"] == "secondary"
    for inst in (a, b):
        image = cv2.imread(str(tmp_path / inst["image"]))
        assert image is not None and image.shape[:2] == (500, 500)
        r = inst["rating"]
        product = r["dof"] * r["resolution"] * r["tfv"] * r["tav"] * r["free"]
        assert r["total"] == pytest.approx(product)
    # the optimum of the first instance is in front of the primary, close to the near limit
    assert abs(np.linalg.norm(np.array(a["optimum"]) - PRIMARY.position[:2]) - 5.0) < 1.0
    assert "secondary" in capsys.readouterr().err


def test_the_occluder_in_front_blocks_the_primary_views():
    field, image = rate_instance(INSTANCES[1])
    (x0, x1), (y0, y1) = INSTANCES[1].occluder
    assert np.all(image[x0:x1 + 1, y0:y1 + 1] == 0)  # no camera inside the occluder
    primary = field.target == 0
    in_front = primary & (np.abs(field.ratings.positions[:, 1] - 50) < 10) & \
        (field.ratings.positions[:, 0] > 62)
    assert in_front.any() and np.all(field.ratings.tfv[in_front] == 0)


@pytest.mark.slow
def test_the_same_switch_in_the_3d_pipeline(tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(SCENARIO_DIR / "figure7.toml"), "--out", str(out),
                 "--no-record"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for robot in summary["robots"]:
        assert robot["placed"] and robot["seen"]
        assert robot["target"]["role"] == "secondary", robot["target"]
