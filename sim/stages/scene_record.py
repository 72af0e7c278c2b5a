"""The simulated world in a rerun recording: every visible geom as rerun geometry under
its body, and the bodies' poses as they move, so that the recording replays the episode.

Entity paths: ``world/scene/<body>`` carries the body's world pose (a ``Transform3D``),
``world/scene/<body>/<geom>`` the geom's pose in its body and its shape. Bodies welded to
the world are logged once (static); the others (robots' links, bases, the carried panel)
whenever :func:`log_poses` is called, on the timelines then set. Sizes in metres.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import mujoco
import numpy as np
import rerun as rr

SCENE = "world/scene"
# MuJoCo draws geom groups 0-2 by default; higher groups are collision proxies and aids
DRAWN_GROUPS = 3
# a plane of "infinite" size is drawn this far (m) either side of its origin
PLANE_HALF_M = 3.0
PLANE_THICKNESS_M = 0.001  # a plane as a box this thin


def _part(name: str, fallback: str) -> str:
    """An entity-path part for a MuJoCo name (letters, digits, ``_-.`` kept)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) if name else fallback


def body_path(model: mujoco.MjModel, body: int) -> str:
    """The entity path of ``body``'s frame."""
    return f"{SCENE}/{_part(model.body(body).name, f'body{body}')}"


def geom_path(model: mujoco.MjModel, geom: int) -> str:
    """The entity path of ``geom``, beneath its body's."""
    name = _part(model.geom(geom).name, f"geom{geom}")
    return f"{body_path(model, int(model.geom_bodyid[geom]))}/{name}"


def geom_colour(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """The geom's RGBA (0-1) as MuJoCo draws it, in one colour: its material's where it
    keeps the default grey and has a material, times the mean of the material's colour
    texture if it has one (rerun's primitives take no texture)."""
    rgba = np.asarray(model.geom_rgba[geom], float)
    material = model.geom_matid[geom]
    if material < 0 or not np.allclose(rgba, [0.5, 0.5, 0.5, 1.0]):
        return rgba
    rgba = np.asarray(model.mat_rgba[material], float)
    texture = model.mat_texid[material, mujoco.mjtTextureRole.mjTEXROLE_RGB]
    if texture >= 0 and model.tex_nchannel[texture] >= 3:
        start = model.tex_adr[texture]
        size = model.tex_height[texture] * model.tex_width[texture] * model.tex_nchannel[texture]
        texels = model.tex_data[start:start + size].reshape(-1, model.tex_nchannel[texture])
        rgba = rgba * np.concatenate([texels[:, :3].mean(axis=0) / 255.0, [1.0]])
    return rgba


def _shape(model: mujoco.MjModel, geom: int, rgba: np.ndarray) -> rr.AsComponents | None:
    """The rerun archetype of one geom, in the geom's own frame (None for a type that is
    not drawn: height fields, signed-distance fields)."""
    kind, size = model.geom_type[geom], model.geom_size[geom]
    colour = np.round(255 * rgba).astype(np.uint8)
    g = mujoco.mjtGeom
    if kind == g.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size], colors=[colour], fill_mode="solid")
    if kind == g.mjGEOM_PLANE:
        half = [s if s > 0 else PLANE_HALF_M for s in size[:2]]
        return rr.Boxes3D(half_sizes=[[*half, PLANE_THICKNESS_M / 2]],
                          centers=[[0, 0, -PLANE_THICKNESS_M / 2]], colors=[colour],
                          fill_mode="solid")
    if kind == g.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[colour], fill_mode="solid")
    if kind == g.mjGEOM_ELLIPSOID:
        return rr.Ellipsoids3D(half_sizes=[size], colors=[colour], fill_mode="solid")
    if kind == g.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[colour],
                              fill_mode="solid")
    if kind == g.mjGEOM_CAPSULE:  # rerun's capsule starts at the origin
        return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]],
                             translations=[[0, 0, -size[1]]], colors=[colour],
                             fill_mode="solid")
    if kind == g.mjGEOM_MESH:
        mesh = model.geom_dataid[geom]
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
        return rr.Mesh3D(vertex_positions=model.mesh_vert[v0:v0 + nv],
                         triangle_indices=model.mesh_face[f0:f0 + nf],
                         albedo_factor=rgba)
    return None


@dataclass(frozen=True)
class SceneGeometry:
    """What of a model is recorded: the drawn geoms (``geoms``) and which bodies move."""

    geoms: tuple[int, ...]
    moving: tuple[int, ...]  # bodies with drawn geoms, not welded to the world
    still: tuple[int, ...]  # bodies with drawn geoms, welded to the world

    @classmethod
    def of(cls, model: mujoco.MjModel) -> SceneGeometry:
        drawn = tuple(int(g) for g in range(model.ngeom)
                      if model.geom_group[g] < DRAWN_GROUPS and geom_colour(model, g)[3] > 0)
        bodies = {int(model.geom_bodyid[g]) for g in drawn}
        moves = {b for b in range(1, model.nbody)
                 if model.body_weldid[b] != 0 or model.body_mocapid[b] >= 0}
        return cls(drawn, tuple(sorted(bodies & moves)), tuple(sorted(bodies - moves)))


def log_geometry(rec: rr.RecordingStream, model: mujoco.MjModel, data: mujoco.MjData
                 ) -> SceneGeometry:
    """Log every drawn geom under its body (static) and every body's pose now: the still
    ones static, the moving ones on the timelines set. Returns what was logged."""
    scene = SceneGeometry.of(model)
    for g in scene.geoms:
        shape = _shape(model, g, geom_colour(model, g))
        if shape is None:
            continue
        path = geom_path(model, g)
        rec.log(path, rr.Transform3D(translation=model.geom_pos[g],
                                     quaternion=rr.Quaternion(xyzw=_xyzw(model.geom_quat[g]))),
                static=True)
        rec.log(path, shape, static=True)
    _log_bodies(rec, model, data, scene.still, static=True)
    log_poses(rec, model, data, scene)
    return scene


def log_poses(rec: rr.RecordingStream, model: mujoco.MjModel, data: mujoco.MjData,
              scene: SceneGeometry) -> None:
    """The moving bodies' world poses, on the timelines set (``data`` after
    ``mj_forward`` or a step)."""
    _log_bodies(rec, model, data, scene.moving, static=False)


def _log_bodies(rec: rr.RecordingStream, model: mujoco.MjModel, data: mujoco.MjData,
                bodies: tuple[int, ...], static: bool) -> None:
    for b in bodies:
        rec.log(body_path(model, b),
                rr.Transform3D(translation=data.xpos[b],
                               quaternion=rr.Quaternion(xyzw=_xyzw(data.xquat[b]))),
                static=static)


def _xyzw(wxyz: np.ndarray) -> list[float]:
    """A MuJoCo quaternion (w, x, y, z) as rerun's (x, y, z, w)."""
    return [float(wxyz[1]), float(wxyz[2]), float(wxyz[3]), float(wxyz[0])]
