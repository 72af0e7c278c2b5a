"""A target's fixture: a post that the work-piece carries elsewhere in the work cell,
with a small plate of the work-piece's steel on top whose hole is the target.
"""

from __future__ import annotations

import mujoco

from taskcam.sim.config.scene import TargetConfig
from taskcam.sim.config.schema import ScenarioError

FIXTURE_POST_HALF_M = 0.02  # a fixture's post: 4 cm square
FIXTURE_RIM_M = 0.04  # its top plate reaches this far beyond the hole's rim on every side
FIXTURE_PLATE_HALF_M = 0.01  # and is 2 cm thick


def add_fixture(wp: mujoco.MjSpec, t: TargetConfig, source: str, index: int) -> float:
    """Add target ``t``'s fixture to the work-piece ``wp``: a post standing on what is
    under it (the plate, the table or the floor) up to a small plate of the work-piece's
    steel whose top is at ``t.height_m``; returns that height (m)."""
    ox, oy = t.offset_m
    under = 0.0
    for name in ("table", "plate"):
        g = wp.geom(name)
        if abs(ox - g.pos[0]) <= g.size[0] and abs(oy - g.pos[1]) <= g.size[1]:
            under = max(under, float(g.pos[2] + g.size[2]))
    plate_half = t.radius_m + FIXTURE_RIM_M
    post_top = t.height_m - 2 * FIXTURE_PLATE_HALF_M
    if post_top - under < 0.02:
        raise ScenarioError(source, f"workpiece.targets[{index}].height_m", t.height_m,
                            f"a fixture's top at least {under + 0.02 + 2 * FIXTURE_PLATE_HALF_M:g}"
                            " m up: above what it stands on there")
    body = wp.body("workpiece")
    collision, plate = wp.find_default("collision"), wp.geom("plate")
    post = body.add_geom(collision, name=f"fixture_{t.name}_post")
    post.type = mujoco.mjtGeom.mjGEOM_BOX
    post.size = [FIXTURE_POST_HALF_M, FIXTURE_POST_HALF_M, (post_top - under) / 2]
    post.pos = [ox, oy, (post_top + under) / 2]
    post.material = plate.material
    top = body.add_geom(collision, name=f"fixture_{t.name}")
    top.type = mujoco.mjtGeom.mjGEOM_BOX
    top.size = [plate_half, plate_half, FIXTURE_PLATE_HALF_M]
    top.pos = [ox, oy, t.height_m - FIXTURE_PLATE_HALF_M]
    top.material = plate.material
    return t.height_m
