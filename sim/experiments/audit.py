"""Auditing a run directory (``summary.json``, ``scene.xml`` and ``look.xml``): does the
summary tell the truth about the saved scenes?

Checks, each a kind of :class:`Finding`:

- ``unaccounted_robot``: every robot of the scene is in the summary, and every robot
  and every placement of it is either placed or refused with a reason;
- ``pose_mismatch``: each robot's reported ``pose`` is its camera's pose in
  ``scene.xml`` at keyframe ``final``, within what the XML round trip leaves (POSE_TOL_M,
  POSE_TOL_DEG); ``look_mismatch``: the placement it looked from is where ``look.xml``'s
  keyframe ``look`` has its camera (LOOK_TOL_M, LOOK_TOL_DEG);
- ``mirror_mismatch``: the robot's top-level fields are those of the placement it ended
  at, the last one placed;
- ``sighting_outside_image``, ``sighting_off_target``, ``sighting_obstructed``: every
  claimed sighting (``sightings``, and ``seen`` with its ``pixel``) lies inside the
  image, where the true target projects through the true pose of the placement it was
  made from, and an independent ray cast through the saved scene at keyframe ``look``
  (MuJoCo's ``mj_ray`` against the rendered geom groups, the camera's own body left
  out) reaches the target's true place (the hole geom of ``scene.xml``, the
  work-piece's misplacement included) from the camera (and, for a stereo sighting,
  from the right camera too) before anything else;
- ``correction_out_of_tolerance``, ``correction_misreported``: every pose correction
  is within 3 mm / 0.2 deg of the truth or reported as not trusted (``failed`` or
  ``uncertain``) with a reason, and its
  reported error agrees with its estimated pose against the true one;
- ``schema``: the summary lacks what the checks need (named); ``traceback``, ``crash``
  and ``timeout``: the run raised, killed its process or overran (found by the
  runner, sim/experiments/soak.py, not here).

The checks are pure: they read the three files and nothing else (mujoco only to load
the scenes, put them at a keyframe and cast rays).
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim.config.scenario import Scenario

# MuJoCo writes MJCF numbers with 6 significant digits, so a camera pose read back from
# scene.xml's keyframes is off the one the run computed by the rounding of every joint
# and mount: measured against the episode's own state (after mj_forward) over 60 robots
# of 29 soak scenes, at most 7.6e-6 m and 0.0008 deg (median 2.8e-6 m, 0.0003 deg). The
# tolerances are about 4 times that; the failures they are for are millimetres.
POSE_TOL_M = 3e-5
POSE_TOL_DEG = 0.003
# Where the camera looked from (keyframe "look") against the pose the placement it looked
# from reports (taken right after its move): the arm may settle on while the robots
# placed after it move (up to 1.1 mm / 0.08 deg measured in 40 soak scenes); a keyframe
# that does not hold the world as it was is centimetres off.
LOOK_TOL_M = 5e-3
LOOK_TOL_DEG = 0.5
CORRECTION_TOL_M = 0.003  # a correction within this of the truth ...
CORRECTION_TOL_DEG = 0.2  # ... and this, or reported as failed
REPORT_TOL_M = 1e-6  # a reported error against the one its poses give
REPORT_TOL_DEG = 1e-4
OFF_TARGET_SLACK_PX = 2.0  # a detection within the hole's image radius plus this
OBSTRUCTION_EPS_M = 1e-3  # something hit this far before the target hides it
RENDERED_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # MuJoCo's visible groups
# A correction is trusted ("corrected": within the tolerance above), or reported as not:
# "failed" (no estimate) or "uncertain" (an estimate its bundle adjustment disagrees
# with), each with its reason in "failed".
UNTRUSTED = ("failed", "uncertain")
MIRRORED = ("candidate_position", "commanded_pose", "target", "estimated_pose", "correction")

KINDS = ("traceback", "crash", "timeout", "schema", "unaccounted_robot", "pose_mismatch",
         "look_mismatch", "mirror_mismatch", "sighting_outside_image", "sighting_off_target",
         "sighting_obstructed", "correction_out_of_tolerance", "correction_misreported")


@dataclass(frozen=True)
class Finding:
    """One way a run directory does not tell the truth (``kind`` is one of KINDS)."""

    kind: str
    robot: str | None
    message: str

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Audit:
    """Findings of one run directory and the counts of what was checked."""

    findings: list[Finding] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # placements, by reason
    refused_robots: Counter[str] = field(default_factory=Counter)  # not placed, by reason
    correction_failures: Counter[str] = field(default_factory=Counter)  # by reason
    worst: dict[str, float] = field(default_factory=dict)  # largest discrepancies seen

    def add(self, kind: str, robot: str | None, message: str) -> None:
        self.findings.append(Finding(kind, robot, message))

    def at_most(self, name: str, value: float) -> None:
        self.worst[name] = max(self.worst.get(name, 0.0), float(value))

    def summary(self) -> dict[str, Any]:
        return {"findings": [f.as_dict() for f in self.findings], "counts": dict(self.counts),
                "refused": dict(self.refused), "refused_robots": dict(self.refused_robots),
                "correction_failures": dict(self.correction_failures), "worst": self.worst}


def reason_key(reason: str) -> str:
    """A reason with its numbers replaced by N, to count reasons alike."""
    return re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "N", reason.strip())[:160]


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

    def target(self, name: str) -> tuple[int, np.ndarray, float]:
        """The hole geom of target ``name``: id, the centre of its top face (world, at the
        current keyframe) and its radius (m)."""
        g = self.model.geom(f"workpiece/hole_{name}").id
        half = float(self.model.geom_size[g, 1])
        top = self.data.geom_xpos[g] + self.data.geom_xmat[g].reshape(3, 3)[:, 2] * half
        return g, top, float(self.model.geom_size[g, 0])

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


def _project(T_world_cam: np.ndarray, point: np.ndarray, width: int, height: int, f: float
             ) -> tuple[np.ndarray, float] | None:
    """Pixel (u right, v down; pixel centres at integers) of a world point seen by a
    MuJoCo camera (-z forward, +y up), and its depth (m); None behind the camera."""
    p = T_world_cam[:3, :3].T @ (point - T_world_cam[:3, 3])
    depth = -float(p[2])
    if depth <= 1e-6:
        return None
    return np.array([(width - 1) / 2 + f * p[0] / depth,
                     (height - 1) / 2 - f * p[1] / depth]), depth


def _inside(pixel: np.ndarray, width: int, height: int) -> bool:
    return bool(-0.5 <= pixel[0] <= width - 0.5 and -0.5 <= pixel[1] <= height - 0.5)


class _RobotAudit:
    """The checks of one robot of the summary."""

    def __init__(self, audit: Audit, scenes: dict[str, SavedScene], robot: dict[str, Any],
                 correction_on: bool | None) -> None:
        """``scenes``: the saved scene that holds each keyframe (``final``, ``look``), by
        its name; those missing are not checked."""
        self.a, self.scenes, self.r = audit, scenes, robot
        self.scene = next(iter(scenes.values()))  # any: the cameras and targets
        self.name = str(robot.get("name"))
        self.correction_on = correction_on
        placements = robot.get("placements")
        self.placements: list[dict[str, Any]] | None = (
            placements if isinstance(placements, list) and placements else None)

    def find(self, kind: str, message: str) -> None:
        self.a.add(kind, self.name, message)

    def at(self, key: str) -> SavedScene:
        """The scene holding keyframe ``key``, put at it."""
        scene = self.scenes[key]
        scene.at(key)
        return scene

    def run(self) -> None:
        camera = self.r.get("camera")
        try:
            self.scene.model.camera(camera)
        except (KeyError, TypeError):
            self.find("schema", f"camera {camera!r} is not in scene.xml")
            return
        self.camera = str(camera)
        if self.placements is None:
            self.find("schema", "no 'placements' list")
        self.accounted()
        self.final_pose()
        self.mirrored()
        self.corrections()
        self.sightings()

    # ------------------------------------------------------------ a. placed or refused

    def accounted(self) -> None:
        a, r = self.a, self.r
        a.counts["robots"] += 1
        placed = r.get("placed")
        if not isinstance(placed, bool):
            self.find("unaccounted_robot", f"'placed' is {placed!r}, not true or false")
            return
        a.counts["robots_placed" if placed else "robots_refused"] += 1
        if self.placements is None:  # no record of why: only a placed robot is accounted for
            if not placed and not (isinstance(r.get("refused"), str) and r["refused"].strip()):
                self.find("unaccounted_robot", "not placed, and no reason given")
            return
        last_placed = None
        for j, p in enumerate(self.placements):
            a.counts["placements"] += 1
            if p.get("index") != j:
                self.find("schema", f"placements[{j}].index is {p.get('index')!r}")
            step = p.get("step")
            if (j == 0) != (step is None):
                self.find("schema", f"placements[{j}].step is {step!r} (null only for the first)")
            if j > 0:
                a.counts["replacements"] += 1
            if p.get("placed") is True:
                last_placed = j
                a.counts["placements_placed"] += 1
                missing = [k for k in ("pose", "commanded_pose", "candidate_position", "target")
                           if k not in p]
                if missing:
                    self.find("schema", f"placements[{j}] is placed but lacks {missing}")
            elif p.get("placed") is False:
                why = p.get("refused")
                if isinstance(why, str) and why.strip():
                    a.refused[reason_key(why)] += 1
                else:
                    self.find("unaccounted_robot", f"placements[{j}] was not placed, and "
                              f"'refused' gives no reason ({why!r})")
            else:
                self.find("unaccounted_robot",
                          f"placements[{j}].placed is {p.get('placed')!r}, not true or false")
        why = self.placements[-1].get("refused")
        if not placed and isinstance(why, str) and why.strip():
            a.refused_robots[reason_key(why)] += 1
        index = r.get("placement")
        if placed and index != last_placed:
            self.find("unaccounted_robot", f"placed, at placement {index!r}, but the last "
                      f"placement placed is {last_placed!r}")
        if not placed and (index is not None or last_placed is not None):
            self.find("unaccounted_robot", f"reported not placed, but placement {index!r} / "
                      f"placements[{last_placed}] placed it")

    # ------------------------------------------------------------ b. pose = scene.xml

    def final_pose(self) -> None:
        if "final" not in self.scenes:
            return
        pose = self.r.get("pose")
        if not isinstance(pose, dict):
            self.find("schema", "no 'pose'")
            return
        dp, da = pose_gap(pose, self.at("final").camera_pose(self.camera))
        self.a.at_most("final_pose_m", dp)
        self.a.at_most("final_pose_deg", da)
        self.a.counts["poses_checked"] += 1
        if dp > POSE_TOL_M or da > POSE_TOL_DEG:
            self.find("pose_mismatch", f"reported pose is {dp * 1000:.3f} mm / {da:.4f} deg "
                      f"from camera '{self.camera}' at scene.xml's keyframe 'final'")
        looked = self.r.get("seen_from_placement")
        if "look" not in self.scenes or self.placements is None or not isinstance(looked, int):
            return
        if not 0 <= looked < len(self.placements):
            self.find("schema", f"seen_from_placement {looked!r} is not one of the robot's "
                      f"{len(self.placements)} placements")
            return
        if self.placements[looked].get("placed") is not True:
            return  # it looked from where it stood: nothing placed it (a claim is checked below)
        dp, da = pose_gap(self.placements[looked]["pose"],
                          self.at("look").camera_pose(self.camera))
        self.a.at_most("look_pose_m", dp)
        self.a.at_most("look_pose_deg", da)
        self.a.counts["looks_checked"] += 1
        if dp > LOOK_TOL_M or da > LOOK_TOL_DEG:
            self.find("look_mismatch", f"placements[{looked}].pose, where it looked from, is "
                      f"{dp * 1000:.3f} mm / {da:.4f} deg from camera '{self.camera}' at "
                      f"look.xml's keyframe 'look'")

    def mirrored(self) -> None:
        index = self.r.get("placement")
        if self.placements is None or not isinstance(index, int):
            return
        if not 0 <= index < len(self.placements):
            return  # reported by accounted()
        p = self.placements[index]
        for key in MIRRORED:
            if key in p and p[key] != self.r.get(key):
                self.find("mirror_mismatch", f"top-level '{key}' differs from "
                          f"placements[{index}]['{key}'], the placement it ended at")

    # ------------------------------------------------------------ d. corrections

    def corrections(self) -> None:
        placed = ([(f"placements[{j}]", p) for j, p in enumerate(self.placements)
                   if p.get("placed") is True] if self.placements is not None
                  else [("robot", self.r)] if self.r.get("placed") is True else [])
        for where, p in placed:
            c = p.get("correction")
            if c is None:
                if self.correction_on:
                    self.find("correction_misreported",
                              f"{where}: correction is on but none is reported")
                continue
            self.correction(where, p, c)

    def correction(self, where: str, p: dict[str, Any], c: dict[str, Any]) -> None:
        status = c.get("status")
        if status is None:
            self.find("schema", f"{where}.correction has no 'status'")
            status = "failed" if c.get("failed") or "error_after" not in c else "corrected"
        if status in UNTRUSTED:
            self.a.counts[f"corrections_{status}"] += 1
            why = c.get("failed")
            if not (isinstance(why, str) and why.strip()):
                self.find("correction_misreported", f"{where}: correction {status} without "
                          f"a reason ('failed' is {why!r})")
            else:
                self.a.correction_failures[f"{status}: {reason_key(why)}"] += 1
            return
        if status != "corrected":
            self.find("schema", f"{where}.correction.status is {status!r}")
            return
        self.a.counts["corrections_corrected"] += 1
        after = c.get("error_after")
        if not isinstance(after, dict):
            self.find("correction_misreported", f"{where}: corrected, with no error_after")
            return
        dp, da = float(after["position_m"]), float(after["orientation_deg"])
        self.a.at_most("correction_m", dp)
        self.a.at_most("correction_deg", da)
        if dp > CORRECTION_TOL_M or da > CORRECTION_TOL_DEG:
            self.find("correction_out_of_tolerance", f"{where}: corrected pose is "
                      f"{dp * 1000:.2f} mm / {da:.3f} deg off the truth (at most "
                      f"{CORRECTION_TOL_M * 1000:.0f} mm / {CORRECTION_TOL_DEG} deg), "
                      "reported as corrected")
        estimated, truth = p.get("estimated_pose"), p.get("pose")
        if isinstance(estimated, dict) and isinstance(truth, dict):
            ep, ea = pose_gap(estimated, truth)
            if abs(ep - dp) > REPORT_TOL_M or abs(ea - da) > REPORT_TOL_DEG:
                self.find("correction_misreported", f"{where}: error_after says {dp * 1000:.3f}"
                          f" mm / {da:.4f} deg, its estimated_pose against its pose "
                          f"{ep * 1000:.3f} mm / {ea:.4f} deg")
        else:
            self.find("correction_misreported", f"{where}: corrected, but no estimated_pose")

    # ------------------------------------------------------------ c. sightings

    def pose_of(self, what: str, k: Any) -> dict[str, Any] | None:
        """The true camera pose of placement ``k`` (the robot's pose on old summaries)."""
        if self.placements is None:
            return self.r.get("pose") if isinstance(self.r.get("pose"), dict) else None
        if not isinstance(k, int) or not 0 <= k < len(self.placements):
            self.find("schema", f"{what}: placement {k!r} is not one of the robot's "
                      f"{len(self.placements)} placements")
            return None
        pose = self.placements[k].get("pose")
        if self.placements[k].get("placed") is not True or not isinstance(pose, dict):
            self.find("unaccounted_robot", f"{what} was made from placements[{k}], "
                      "which did not place the camera")
            return None
        return pose

    def sightings(self) -> None:
        key = "look" if "look" in self.scenes else "final"
        if key not in self.scenes:
            return
        scene = self.at(key)
        rows = self.r.get("sightings") or []
        for i, s in enumerate(rows):
            what = f"sightings[{i}] of '{s.get('target')}'"
            if self.placements is not None and "placement" not in s:
                self.find("schema", f"{what} has no 'placement'")
                continue
            pose = self.pose_of(what, s.get("placement"))
            if pose is None:
                continue
            self.a.counts["sightings_checked"] += 1
            self.sighting(scene, what, s.get("target"), s.get("pixel"), pose,
                          s.get("disparity_px"))
        if self.r.get("seen") is True:
            target = self.r.get("target")
            k = self.r.get("seen_from_placement")
            if self.placements is not None:
                if not isinstance(k, int) or not 0 <= k < len(self.placements):
                    self.find("schema", f"seen, from placement {k!r}: no such placement")
                    return
                target = self.placements[k].get("target")
            pose = self.pose_of("the detection ('seen')", k)
            if pose is None or not isinstance(target, dict):
                return
            self.a.counts["seen_checked"] += 1
            self.sighting(scene, "the detection ('seen')", target.get("name"),
                          self.r.get("pixel"), pose, None)

    def sighting(self, scene: SavedScene, what: str, target: Any, pixel: Any,
                 pose: dict[str, Any], disparity: Any) -> None:
        try:
            g, truth, radius = scene.target(str(target))
        except KeyError:
            self.find("schema", f"{what}: no hole geom 'workpiece/hole_{target}' in scene.xml")
            return
        if not (isinstance(pixel, list) and len(pixel) == 2):
            self.find("schema", f"{what}: pixel is {pixel!r}")
            return
        width, height, f = scene.intrinsics(self.camera)
        px = np.asarray(pixel, float)
        T = pose_matrix(pose)
        views = [("left", T, px)]
        partner = scene.stereo_partner(self.camera)
        if disparity is not None and partner is not None:
            views.append(("right", T @ partner, px - (float(disparity), 0.0)))
        body = int(scene.model.cam_bodyid[scene.model.camera(self.camera).id])
        for eye, T_eye, claimed in views:
            if not _inside(claimed, width, height):
                self.find("sighting_outside_image", f"{what}: {eye} pixel "
                          f"{np.round(claimed, 2).tolist()} is outside the {width}x{height} image")
            seen = _project(T_eye, truth, width, height, f)
            if seen is None:
                self.find("sighting_outside_image", f"{what}: the target is behind the {eye} "
                          "camera")
                continue
            expected, depth = seen
            if not _inside(expected, width, height):
                self.find("sighting_outside_image", f"{what}: the target projects to "
                          f"{np.round(expected, 2).tolist()}, outside the {eye} image")
            radius_px = f * radius / depth
            off = float(np.linalg.norm(claimed - expected))
            self.a.at_most("sighting_off_px", off)
            self.a.at_most("sighting_off_radii", off / radius_px)
            if off > radius_px + OFF_TARGET_SLACK_PX:
                self.find("sighting_off_target", f"{what}: {eye} pixel is {off:.1f} px from "
                          f"where the target truly projects ({np.round(expected, 1).tolist()}; "
                          f"its image radius {radius_px:.1f} px)")
            hit, distance = scene.first_hit(T_eye[:3, 3], truth, body)
            reach = float(np.linalg.norm(truth - T_eye[:3, 3]))
            if hit != g and distance < reach - OBSTRUCTION_EPS_M:
                self.find("sighting_obstructed", f"{what}: from the {eye} camera, "
                          f"{scene.geom_label(hit)} is hit {distance:.3f} m along the "
                          f"{reach:.3f} m to the target (keyframe '{scene.keyframe}')")


def audit_run(run_dir: str | Path, scenario: Scenario | None = None) -> Audit:
    """Audit a run directory. ``scenario`` (optional) says whether correction was on,
    so that a placement without one is caught."""
    out = Audit()
    run_dir = Path(run_dir)
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError) as exc:
        out.add("schema", None, f"summary.json cannot be read: {exc}")
        return out
    scenes: dict[str, SavedScene] = {}
    for file, key in (("scene.xml", "final"), ("look.xml", "look")):
        try:
            scene = SavedScene(run_dir / file)
        except (OSError, ValueError) as exc:
            out.add("schema", None, f"{file} cannot be loaded: {exc}")
            continue
        if key in scene.keyframes():
            scenes[key] = scene
        else:
            out.add("schema", None, f"{file} has no keyframe '{key}' (it has {scene.keyframes()})")
    if not scenes:
        return out
    scene = next(iter(scenes.values()))
    robots = summary.get("robots")
    if not isinstance(robots, list):
        out.add("schema", None, "summary has no 'robots' list")
        return out
    names = [r.get("name") for r in robots if isinstance(r, dict)]
    for missing in sorted(set(scene.robots()) - set(names)):
        out.add("unaccounted_robot", missing, "in scene.xml but not in the summary")
    correction_on = None if scenario is None else scenario.correction.enabled
    for i, robot in enumerate(robots):
        try:
            _RobotAudit(out, scenes, robot, correction_on).run()
        except (AttributeError, KeyError, TypeError, ValueError, IndexError) as exc:
            name = robot.get("name") if isinstance(robot, dict) else None
            out.add("schema", name, f"robots[{i}]: malformed record: {exc!r}")
    return out
