"""The panel's CAD model, read from the scene's MuJoCo model: its box geoms, in its body
frame.
"""

from __future__ import annotations

import mujoco

from taskcam.mapping import BoxModel


def panel_model(model: mujoco.MjModel) -> BoxModel:
    """The panel's CAD model (its box geoms, in its body frame)."""
    body = model.body("panel/panel").id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
             and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    return BoxModel(model.geom_pos[geoms].copy(), model.geom_size[geoms].copy())
