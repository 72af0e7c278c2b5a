"""A camera placed for a secondary target measures the panel against it
and carries the displacement to the slot through the known relation (eq. 4). The
triangulated hole's covariance against draws; the stand-in's place and covariance by
hand; the displacement through it; the task's targets with the slot as primary."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from taskcam.calibration.displacement import via_feature
from taskcam.calibration.edge_fit import EdgeFit, point_covariance
from taskcam.calibration.edge_model import StereoRig
from taskcam.calibration.ekf import StereoCamera
from taskcam.calibration.target_frame import Sighting
from taskcam.mapping import Target, opencv_pose
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.stages.relative import HOLE_CENTRE_SD_PX, stand_in
from taskcam.sim.stages.slot_target import SLOT, is_slot, task_targets
from taskcam.sim.stages.task_result import Camera
from taskcam.sim.stages.timer import Timer
from taskcam.sim.stages.world import build_world

CAMERA = StereoCamera(416.0, 416.0, 320.0, 240.0, 0.12)
RIG = StereoRig(640, 480, 416.0, 416.0, 320.0, 240.0, 0.12, 0.5)


def test_a_triangulated_point_is_as_uncertain_as_its_centres_say():
    """Left and right centres each found to 0.3 px per axis, on one rectified row: the
    covariance of the triangulated point against 200,000 draws, within 3 %."""
    rng = np.random.default_rng(0)
    p = np.array([0.15, -0.1, 0.9])
    sd = 0.3
    u, v, d = CAMERA.measure(p)
    n = 200_000
    left = rng.normal(0.0, sd, (n, 2))
    right_u = rng.normal(0.0, sd, n)
    z = np.column_stack([u + left[:, 0], v + left[:, 1], d + left[:, 0] - right_u])
    points = np.array([CAMERA.point(row) for row in z[:20_000]])
    drawn = np.cov(points.T)
    predicted = CAMERA.point_covariance(p, sd)
    assert np.allclose(np.sqrt(np.diag(drawn)), np.sqrt(np.diag(predicted)), rtol=0.03)
    assert drawn[0, 2] / math.sqrt(drawn[0, 0] * drawn[2, 2]) == pytest.approx(
        predicted[0, 2] / math.sqrt(predicted[0, 0] * predicted[2, 2]), abs=0.03)


def _camera(status: str = "corrected", rotation_sd: float = 0.0) -> Camera:
    """A camera 0.9 m straight above the world's origin, looking down (MuJoCo frame:
    -z forward, so its z axis is the world's)."""
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.9]
    return Camera(None, T, 0.0, status, rotation_sd)  # type: ignore[arg-type]


def _hole(st_error: float = 0.0) -> Target:
    return Target("h", "secondary", "", np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, st_error)


def test_a_stand_in_puts_the_slot_at_the_sighting_plus_the_relation_by_hand():
    """Head-on at 0.9 m, a hole of no radius (no perspective shift): the slot's point is
    the sighting plus the offset, in the camera's frame; the covariance is the
    triangulation's plus ST_error^2 along the plate plus the frame's turn on the lever
    (across it only), and an uncorrected camera's rotation error on the offset."""
    cam = _camera()
    seen = Sighting("r1", "h", (320.0, 240.0), 416 * 0.12 / 0.9, 1.0, np.zeros(3))
    offset = np.array([0.2, 0.0, 0.0])
    R = opencv_pose(cam.believed)[:3, :3]
    bare = stand_in(cam, seen, _hole(), offset, 0.0, RIG)
    assert np.allclose(bare.goal, R.T @ (offset - [0.0, 0.0, 0.9]), atol=1e-12)
    triangulated = CAMERA.point_covariance(np.array([0.0, 0.0, 0.9]), HOLE_CENTRE_SD_PX)
    assert np.allclose(bare.covariance, triangulated, atol=1e-15)
    # ST_error 2 mm along the plate's x and y, the turn 0.01 rad on a 0.2 m lever (2 mm
    # across the lever: the plate's y), not along the normal
    related = stand_in(cam, seen, _hole(0.002), offset, 0.01, RIG)
    world = R @ (related.covariance - triangulated) @ R.T
    assert np.allclose(np.diag(world), [0.002 ** 2, 0.002 ** 2 + 0.002 ** 2, 0.0], atol=1e-15)
    # an uncorrected camera: 0.5 deg on the same lever, across it (the plate's y and z)
    spun = stand_in(_camera("uncertain"), seen, _hole(), offset, 0.0, RIG)
    world = R @ (spun.covariance - triangulated) @ R.T
    across = (0.2 * math.radians(0.5)) ** 2
    assert np.allclose(np.diag(world), [0.0, across, across], atol=1e-15)


def test_the_displacement_through_a_stand_in_adds_both_uncertainties():
    """The object's origin minus the stand-in's goal, the covariances added."""
    pose = np.eye(4)
    pose[:3, 3] = [0.01, 0.02, 0.8]
    fit = EdgeFit(pose, np.diag([1e-8, 2e-8, 3e-8, 1e-6, 1e-6, 1e-6]), 100, 0.1,
                  np.array([0.0, 0.0, 0.05]), 0.0)
    goal = np.array([0.0, 0.0, 0.81])
    cov = np.diag([4e-6, 4e-6, 9e-6])
    d, c = via_feature(fit, goal, cov)
    assert np.allclose(d, [0.01, 0.02, -0.01])
    assert np.allclose(c, point_covariance(fit, np.zeros(3)) + cov)


@pytest.fixture(scope="module")
def world():
    s = load_scenario()
    return build_world(dataclasses.replace(s, task=dataclasses.replace(s.task, enabled=True)),
                       Timer())


def test_with_the_task_the_slot_is_primary_and_the_holes_its_secondary_targets(world):
    """The slot is the one primary target, slot-shaped (the panel's half-length along the
    work-piece's y, the slot's half-width across, facing up, over its nominal place,
    found by its rails: 22 mm either side);
    every hole is secondary with its own ST_error; without secondary targets only the
    slot remains; with the task off the holes are the targets, as declared."""
    targets = task_targets(world)
    slot = targets[0]
    assert [t.role for t in targets] == ["primary"] + ["secondary"] * len(world.scene.targets)
    assert slot.name == SLOT and is_slot(slot)
    assert slot.half_length == pytest.approx(0.1) and slot.radius == pytest.approx(0.007)
    assert slot.detect_radius == pytest.approx(0.022)
    assert slot.axis is not None and abs(float(slot.axis @ [0.0, 1.0, 0.0])) == pytest.approx(1.0)
    site = world.belief.site("workpiece/slot").xpos
    assert np.allclose(slot.position[:2], site[:2]) and slot.position[2] >= site[2]
    assert [(t.name, t.st_error) for t in targets[1:]] == [
        (t.name, t.st_error) for t in world.scene.targets]
    alone = task_targets(world, secondary=False)
    assert len(alone) == 1 and alone[0].name == SLOT
    off = dataclasses.replace(world.scene.scenario,
                              task=dataclasses.replace(world.scenario.task, enabled=False))
    without_task = dataclasses.replace(world, scene=dataclasses.replace(world.scene,
                                                                        scenario=off))
    assert task_targets(without_task) is world.scene.targets
    assert task_targets(without_task, secondary=False)[0] is world.scene.primary
