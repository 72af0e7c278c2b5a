"""The insertion task's targets (sec. 3): "the target is the displacement from the object
to the goal", so with the task on the primary target is the insertion site, the slot,
and the work-piece's holes are secondary targets whose relation to it the CAD model
gives within their ST_error (the scenario's ``st_error_m``; the hole the scenario calls
primary is exact to the slot: one machined plate).

The slot as a target is the rating's slot-shaped site (sim/stages/site_view.py): the
panel's half-length along the slot, the slot's half-width across, lifted over the
rails' voxels. It is found in a camera's stereo pair by fitting the rails' CAD model to
the edges (calibration/edge_fit.py), from where the work-piece's nominal place puts it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from taskcam.calibration.edge_fit import fit_edges
from taskcam.calibration.edge_model import Boxes, Seen, StereoRig
from taskcam.calibration.target_frame import Sighting
from taskcam.mapping import Target, opencv_pose
from taskcam.sim.stages.panel_model import panel_model
from taskcam.sim.stages.relative import (
    SlotBelief,
    slot_half_width,
    slot_model,
    slot_outer_half_width,
    slot_start_in,
)
from taskcam.sim.stages.site_view import box_corners, site_target
from taskcam.sim.stages.task_result import Camera
from taskcam.sim.stages.world import World
from taskcam.sim.world.optics import Lens

SLOT = "slot"  # the slot's name as a target
SLOT_SITE = "workpiece/slot"  # its frame in the model: the point between the rails' feet


def nominal_slot(world: World) -> np.ndarray:
    """The slot's frame (4x4, world) where the scenario puts the work-piece."""
    site = world.belief.site(SLOT_SITE)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = np.reshape(site.xmat, (3, 3)), site.xpos
    return pose


def slot_target(world: World) -> Target:
    """The slot as the task's primary target, at its nominal place, on the mapped grid:
    the insertion site, where the panel goes (the rating's slot-shaped site), found by
    fitting the walls beside it (its ``detect_radius``: their outer faces, 22 mm either
    side for the default rails), whose edges the detector's limits must resolve."""
    slot = nominal_slot(world)
    walls = slot_model(world.nominal)
    site = site_target(world.grid, world.scenario, slot[:3, 3], panel_model(world.nominal),
                       slot[:3, 1], slot_half_width(walls))
    return Target(SLOT, "primary", SLOT_SITE, slot[:3, 3], site.normal, site.radius, 0.0,
                  site.half_length, site.axis, detect_radius=slot_outer_half_width(walls),
                  lift=float(site.position[2] - slot[2, 3]))


def task_targets(world: World, secondary: bool = True) -> tuple[Target, ...]:
    """The targets the cameras are placed for: with the task on, the slot (primary) and,
    with ``secondary``, every hole as its secondary target (without, only views of the
    slot count); with the task off, the scenario's holes (without ``secondary``, its
    primary hole alone)."""
    scene = world.scene
    if not world.scenario.task.enabled:
        return scene.targets if secondary else (scene.primary,)
    holes = tuple(dataclasses.replace(t, role="secondary") for t in scene.targets)
    return (slot_target(world), *(holes if secondary else ()))


def nominal_panel(world: World) -> np.ndarray:
    """The panel's pose (4x4, world) where the scenario says it lies."""
    m = world.nominal
    mocap = int(m.body_mocapid[m.body("panel/panel").id])
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(world.belief.mocap_quat[mocap], scalar_first=True).as_matrix()
    pose[:3, 3] = world.belief.mocap_pos[mocap]
    return pose


def panel_over_slot(world: World) -> np.ndarray:
    """The panel's corners (m, world) where the task's carry will hang it: as it lies
    turned (the carrier does not turn it), ``approach_m`` over the slot's nominal place;
    the occluder the cameras must see the insertion site past."""
    pose = nominal_panel(world)
    pose[:3, 3] = nominal_slot(world)[:3, 3] + [0.0, 0.0, world.scenario.task.approach_m]
    return box_corners(panel_model(world.nominal), pose)


def is_slot(target: Target) -> bool:
    return target.half_length > 0


def stereo_rig(world: World) -> StereoRig:
    """The robots' stereo heads as the edge fit sees them, their lens's blur included."""
    s, p = world.scenario, world.pinhole
    lens = Lens(s.camera.near_m, s.camera.far_m, s.camera.coc_px)
    return StereoRig(p.width, p.height, p.fx, p.fy, p.cx, p.cy, s.camera.baseline_m,
                     lens.blur_sd_px)


def sight_slot(cam: Camera, images: tuple[np.ndarray, np.ndarray], target: Target,
               belief: SlotBelief, rig: StereoRig, slot: Boxes, seen: Seen | None = None
               ) -> Sighting | None:
    """The slot's rails (``slot``, their CAD model) fitted to a camera's stereo pair from
    where ``belief`` puts them, and ``target``'s point carried by the fitted frame into
    the world through the camera's believed pose; None if the fit is not to be used.
    ``seen``, the pair's disparity, hides the rails' edges that something nearer covers
    (as in the task's fits: a hood's slit over them is not taken for them)."""
    start, covariance = slot_start_in(cam, slot, belief)
    fit = fit_edges(images, slot, rig, start, covariance, seen=seen)
    if not fit.ok:
        return None
    in_cam = fit.pose @ np.linalg.solve(belief.pose, np.append(target.position, 1.0))  # origin
    u, v = rig.project(in_cam[None, :3], 0)[0]
    in_world = opencv_pose(cam.believed) @ in_cam
    return Sighting(cam.robot.name, target.name, (float(u), float(v)),
                    rig.fx * rig.baseline_m / float(in_cam[2]), None, in_world[:3])

