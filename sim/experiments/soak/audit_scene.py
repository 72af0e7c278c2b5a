"""A saved scene (``scene.xml``, ``look.xml``) loaded back for an audit, and the pose
geometry the audit compares with: camera poses at a keyframe, projections, rays."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from taskcam.sim.stages.relative import SLOT_WALLS
from taskcam.sim.stages.slot_target import SLOT, SLOT_SITE

RENDERED_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # MuJoCo's visible groups


def quat_angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Angle (deg) of the rotation between two unit quaternions (w, x, y, z)."""
    q1, q2 = q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2)
    return math.degrees(2 * math.acos(min(1.0, abs(float(q1 @ q2)))))


def pose_matrix(pose: dict[str, Any]) -> np.ndarray:
    """4x4 of a summary pose ({"position", "quat_wxyz"})."""
    T = np.eye(4)
    mat = np.zeros(9)
    q = np.asarray(pose["quat_wxyz"], float)
    mujoco.mju_quat2Mat(mat, q / np.linalg.norm(q))
    T[:3, :3] = mat.reshape(3, 3)
    T[:3, 3] = np.asarray(pose["position"], float)
    return T


def pose_gap(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, float]:
    """Position (m) and angle (deg) between two summary poses."""
    return (float(np.linalg.norm(np.subtract(a["position"], b["position"]))),
            quat_angle_deg(np.asarray(a["quat_wxyz"], float), np.asarray(b["quat_wxyz"], float)))


class SavedScene:
    """``scene.xml`` loaded, with its cameras, targets and rays at a keyframe."""

    def __init__(self, path: Path) -> None:
        self.model = mujoco.MjModel.from_xml_path(str(path))
        self.data = mujoco.MjData(self.model)
        self.keyframe: str | None = None

    def keyframes(self) -> list[str]:
        return [self.model.key(i).name for i in range(self.model.nkey)]

    def at(self, key: str) -> None:
        """Put the world at keyframe ``key``."""
        if self.keyframe != key:
            mujoco.mj_resetDataKeyframe(self.model, self.data, self.model.key(key).id)
            mujoco.mj_forward(self.model, self.data)
            self.keyframe = key

    def robots(self) -> list[str]:
        """The robots in the scene (bodies ``<name>/base``)."""
        names = (self.model.body(i).name for i in range(self.model.nbody))
        return sorted(n[:-5] for n in names if re.fullmatch(r"r\d+/base", n))

    def camera_pose(self, camera: str) -> dict[str, Any]:
        """The camera's world pose at the current keyframe, as a summary pose."""
        cam = self.data.camera(camera)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, cam.xmat)
        return {"position": cam.xpos.tolist(), "quat_wxyz": q.tolist()}

    def stereo_partner(self, camera: str) -> np.ndarray | None:
        """``T_left_right`` (4x4): the other camera on the same body, seen from this one."""
        c = self.model.camera(camera).id
        others = [i for i in range(self.model.ncam)
                  if i != c and self.model.cam_bodyid[i] == self.model.cam_bodyid[c]]
        if not others:
            return None

        def local(i: int) -> np.ndarray:
            return pose_matrix({"position": self.model.cam_pos[i], "quat_wxyz":
                                self.model.cam_quat[i]})

        return np.linalg.inv(local(c)) @ local(others[0])

    def intrinsics(self, camera: str) -> tuple[int, int, float]:
        """Width, height (px) and focal length (px) of a camera."""
        c = self.model.camera(camera).id
        width, height = (int(v) for v in self.model.cam_resolution[c])
        fovy = math.radians(float(self.model.cam_fovy[c]))
        return width, height, (height / 2) / math.tan(fovy / 2)

    def target(self, name: str) -> tuple[set[int], np.ndarray, float]:
        """The geoms of target ``name`` (a hole's; the slot's walls and the plate under
        it), its point (world, at the current keyframe: the centre of a hole's top face,
        the slot's point between its walls' feet) and its radius (m; the slot's: to its
        walls' outer faces)."""
        if name == SLOT:
            site = self.data.site_xpos[self.model.site(SLOT_SITE).id]
            walls = [self.model.geom(w).id for w in SLOT_WALLS]
            radius = max(float(np.linalg.norm((self.data.geom_xpos[w] - site)[:2])
                               + self.model.geom_size[w, 0]) for w in walls)
            return {*walls, self.model.geom("workpiece/plate").id}, site.copy(), radius
        g = self.model.geom(f"workpiece/hole_{name}").id
        half = float(self.model.geom_size[g, 1])
        top = self.data.geom_xpos[g] + self.data.geom_xmat[g].reshape(3, 3)[:, 2] * half
        return {g}, top, float(self.model.geom_size[g, 0])

    def first_hit(self, start: np.ndarray, end: np.ndarray, exclude_body: int
                  ) -> tuple[int, float]:
        """The first rendered geom on the segment's line from ``start`` toward ``end`` and
        its distance (m); (-1, inf) if none."""
        geom = np.zeros(1, dtype=np.int32)
        vec = end - start
        x = mujoco.mj_ray(self.model, self.data, start, vec, RENDERED_GROUPS, 1,
                          exclude_body, geom)
        if x < 0:
            return -1, math.inf
        return int(geom[0]), float(x * np.linalg.norm(vec))

    def geom_label(self, g: int) -> str:
        name = self.model.geom(g).name
        body = self.model.body(int(self.model.geom_bodyid[g])).name
        return f"geom '{name or g}' of body '{body}'"


def project(T_world_cam: np.ndarray, point: np.ndarray, width: int, height: int, f: float
            ) -> tuple[np.ndarray, float] | None:
    """Pixel (u right, v down; pixel centres at integers) of a world point seen by a
    MuJoCo camera (-z forward, +y up), and its depth (m); None behind the camera."""
    p = T_world_cam[:3, :3].T @ (point - T_world_cam[:3, 3])
    depth = -float(p[2])
    if depth <= 1e-6:
        return None
    return np.array([(width - 1) / 2 + f * p[0] / depth,
                     (height - 1) / 2 - f * p[1] / depth]), depth


def inside_image(pixel: np.ndarray, width: int, height: int) -> bool:
    """Whether a pixel (centres at integers) falls on a ``width`` x ``height`` image."""
    return bool(-0.5 <= pixel[0] <= width - 0.5 and -0.5 <= pixel[1] <= height - 0.5)
