"""The checks of one robot of a run's summary against its saved scenes: accounted
for, its pose where the scene has its camera, its corrections within tolerance or
reported as not trusted, its sightings where the true target projects and in sight
(the list of checks: sim/experiments/soak/audit.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from taskcam.sim.experiments.soak.audit_findings import Audit, reason_key
from taskcam.sim.experiments.soak.audit_scene import (
    SavedScene,
    inside_image,
    pose_gap,
    pose_matrix,
    project,
)

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
# A correction is trusted ("corrected": within the tolerance above), or reported as not:
# "failed" (no estimate) or "uncertain" (an estimate its bundle adjustment disagrees
# with), each with its reason in "failed".
UNTRUSTED = ("failed", "uncertain")
MIRRORED = ("candidate_position", "commanded_pose", "target", "estimated_pose", "correction")


class RobotAudit:
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
        a.count("robots")
        placed = r.get("placed")
        if not isinstance(placed, bool):
            self.find("unaccounted_robot", f"'placed' is {placed!r}, not true or false")
            return
        a.count("robots_placed" if placed else "robots_refused")
        if self.placements is None:  # no record of why: only a placed robot is accounted for
            if not placed and not (isinstance(r.get("refused"), str) and r["refused"].strip()):
                self.find("unaccounted_robot", "not placed, and no reason given")
            return
        last_placed = None
        for j, p in enumerate(self.placements):
            a.count("placements")
            if p.get("index") != j:
                self.find("schema", f"placements[{j}].index is {p.get('index')!r}")
            step = p.get("step")
            if (j == 0) != (step is None):
                self.find("schema", f"placements[{j}].step is {step!r} (null only for the first)")
            if j > 0:
                a.count("replacements")
            if p.get("placed") is True:
                last_placed = j
                a.count("placements_placed")
                missing = [k for k in ("pose", "commanded_pose", "candidate_position", "target")
                           if k not in p]
                if missing:
                    self.find("schema", f"placements[{j}] is placed but lacks {missing}")
            elif p.get("placed") is False:
                why = p.get("refused")
                if isinstance(why, str) and why.strip():
                    a.count(reason_key(why), "refused")
                else:
                    self.find("unaccounted_robot", f"placements[{j}] was not placed, and "
                              f"'refused' gives no reason ({why!r})")
            else:
                self.find("unaccounted_robot",
                          f"placements[{j}].placed is {p.get('placed')!r}, not true or false")
        why = self.placements[-1].get("refused")
        if not placed and isinstance(why, str) and why.strip():
            a.count(reason_key(why), "refused_robots")
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
        self.a.count("poses_checked")
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
        self.a.count("looks_checked")
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
            self.a.count(f"corrections_{status}")
            why = c.get("failed")
            if not (isinstance(why, str) and why.strip()):
                self.find("correction_misreported", f"{where}: correction {status} without "
                          f"a reason ('failed' is {why!r})")
            else:
                self.a.count(f"{status}: {reason_key(why)}", "correction_failures")
            return
        if status != "corrected":
            self.find("schema", f"{where}.correction.status is {status!r}")
            return
        self.a.count("corrections_corrected")
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
            self.a.count("sightings_checked")
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
            self.a.count("seen_checked")
            self.sighting(scene, "the detection ('seen')", target.get("name"),
                          self.r.get("pixel"), pose, None)

    def sighting(self, scene: SavedScene, what: str, target: Any, pixel: Any,
                 pose: dict[str, Any], disparity: Any) -> None:
        try:
            geoms, truth, radius = scene.target(str(target))
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
            if not inside_image(claimed, width, height):
                self.find("sighting_outside_image", f"{what}: {eye} pixel "
                          f"{np.round(claimed, 2).tolist()} is outside the {width}x{height} image")
            seen = project(T_eye, truth, width, height, f)
            if seen is None:
                self.find("sighting_outside_image", f"{what}: the target is behind the {eye} "
                          "camera")
                continue
            expected, depth = seen
            if not inside_image(expected, width, height):
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
            if hit not in geoms and distance < reach - OBSTRUCTION_EPS_M:
                self.find("sighting_obstructed", f"{what}: from the {eye} camera, "
                          f"{scene.geom_label(hit)} is hit {distance:.3f} m along the "
                          f"{reach:.3f} m to the target (keyframe '{scene.keyframe}')")
