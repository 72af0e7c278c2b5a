"""Clearance: the bounding-sphere culling gives exactly the brute-force minimum."""

from __future__ import annotations

import mujoco
import numpy as np

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.world.collision import Proximity
from taskcam.sim.world.scene import build_scene


def brute_force(model: mujoco.MjModel, data: mujoco.MjData, pairs: np.ndarray,
                limit: float) -> float:
    fromto = np.zeros(6)
    return min([limit, *(mujoco.mj_geomDistance(model, data, int(g), int(h), limit, fromto)
                         for g, h in pairs)])


def test_culled_clearance_equals_every_pair_measured():
    scene = build_scene(load_scenario())
    model, data = scene.model, scene.make_data()
    rng = np.random.default_rng(3)
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    limited = model.jnt_limited.astype(bool)
    near = 0
    for _ in range(25):
        for j in range(model.njnt):
            if limited[j] and model.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE,
                                                    mujoco.mjtJoint.mjJNT_SLIDE):
                data.qpos[model.jnt_qposadr[j]] = rng.uniform(low[j], high[j])
        mujoco.mj_forward(model, data)
        for robot in scene.robots:
            probe = Proximity(model, robot, scene.robots, limit=1.0)
            found = probe.measure(data)
            assert found.robots == brute_force(model, data, probe.pairs_robots, 1.0)
            assert found.world == brute_force(model, data, probe.pairs_world, 1.0)
            assert found.own == brute_force(model, data, probe.pairs_own, 1.0)
            near += found.world < 1.0
    assert near > 10  # the poses come close to the scene, so culling had work to do
