"""Rendered, defocused stereo views of the work-piece's holes for
bench/studies/detector_limits.py: a free stereo pair put at a distance and an angle off a
hole's normal, both images blurred by the lens, and each hole searched as the episode
searches it. A helper of that script (and of bench/studies/measurement_views.py), not a
script itself."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import cv2
import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from taskcam.calibration import disk_template, locate_hole, log_response, match_hole_near, to_gray
from taskcam.calibration.target_frame import projected_disk, search_slack_px, sight
from taskcam.mapping import Pinhole, Target, opencv_pose, world_to_camera
from taskcam.sim.config.scenario import Scenario, load_scenario
from taskcam.sim.stages.look import find_target
from taskcam.sim.world.optics import Lens, defocus
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import Scene

MAX_ERROR_PX = 1.0  # a find farther than this from the centre of the hole's image is wrong


def probe_scenario(width: int, height: int, samples: int) -> Scenario:
    """The default scenario without obstacles, one robot, at this image size."""
    s = load_scenario()
    return dataclasses.replace(
        s, obstacles=(), robots=dataclasses.replace(s.robots, count=1, bases=s.robots.bases[:1]),
        camera=dataclasses.replace(s.camera, width=width, height=height, samples=samples))


def look_rotation(position: np.ndarray, aim: np.ndarray, roll: float) -> np.ndarray:
    """World rotation of a MuJoCo camera (-z forward, +y up) at ``position`` looking at
    ``aim``, rolled by ``roll`` (rad) about its axis."""
    forward = (aim - position) / np.linalg.norm(aim - position)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    x = np.cross(forward, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, forward)
    c, s = math.cos(roll), math.sin(roll)
    return np.column_stack([c * x + s * y, -s * x + c * y, -forward])


def put_camera(model: mujoco.MjModel, data: mujoco.MjData, camera: str,
               position: np.ndarray, R: np.ndarray) -> None:
    """Place a camera at a world pose, through its pose in its body's frame."""
    cam = model.camera(camera).id
    body = model.cam_bodyid[cam]
    Rb, xb = data.xmat[body].reshape(3, 3), data.xpos[body]
    model.cam_pos[cam] = Rb.T @ (position - xb)
    model.cam_quat[cam] = Rotation.from_matrix(Rb.T @ R).as_quat(scalar_first=True)


def view_pose(target: Target, distance: float, angle: float, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray]:
    """Left camera position and rotation: ``distance`` (m) from the target, ``angle``
    (rad) off its normal at a random azimuth, aimed up to 8 deg off it, random roll."""
    n = target.normal
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    azimuth = rng.uniform(0, 2 * math.pi)
    direction = math.cos(angle) * n + math.sin(angle) * (
        math.cos(azimuth) * e1 + math.sin(azimuth) * e2)
    position = target.position + distance * direction
    off = math.radians(8.0) * math.sqrt(rng.uniform()) * distance
    sideways = np.cross(direction, rng.normal(size=3))
    aim = target.position + off * sideways / np.linalg.norm(sideways)
    return position, look_rotation(position, aim, rng.uniform(-math.pi, math.pi))


def ellipse_centre(target: Target, T_cv: np.ndarray, pinhole: Pinhole) -> np.ndarray:
    """Centre (u, v) of the ellipse the hole's rim projects to (perspective shifts it
    from the projection of the hole's centre; it is what the detector finds)."""
    rim = pinhole.project(world_to_camera(T_cv, target.rim(72)))
    (cu, cv), _, _ = cv2.fitEllipse(rim.astype(np.float32))
    return np.array([cu, cv])


def outcome(found: Any, ellipse: np.ndarray, centre: np.ndarray
            ) -> tuple[str, float | None, float | None]:
    """'found' (within MAX_ERROR_PX of the ellipse's centre), 'wrong' or 'missed'; the
    error (px) from the ellipse's centre and from the projection of the hole's centre."""
    if found is None:
        return "missed", None, None
    error = float(math.hypot(found[0] - ellipse[0], found[1] - ellipse[1]))
    return (("found" if error <= MAX_ERROR_PX else "wrong"), error,
            float(math.hypot(found[0] - centre[0], found[1] - centre[1])))


def geometry(position: np.ndarray, target: Target, pinhole: Pinhole) -> dict[str, float]:
    """Distance (m), angle off the normal (deg) and projected radius f r cos(a) / d (px)
    of a target seen from a camera centre."""
    to_camera = position - target.position
    distance = float(np.linalg.norm(to_camera))
    cos = float(np.clip(to_camera @ target.normal / distance, -1.0, 1.0))
    return {"distance_m": distance, "angle_deg": math.degrees(math.acos(cos)),
            "radius_px": pinhole.fy * target.radius * max(cos, 0.0) / distance}


def in_image(image: np.ndarray, T_mjcam: np.ndarray, target: Target, pinhole: Pinhole
             ) -> dict[str, Any] | None:
    """The hole looked for in one image as ``sight`` looks for it in the left one, with
    this camera's own projected ellipse; None if it is not in the image. ``fits``: the
    detector's matching window around the hole lies inside the image (it never finds a
    hole whose window does not)."""
    disk = projected_disk(target, opencv_pose(T_mjcam), pinhole)
    if disk is None or not pinhole.contains(disk[0][None], margin=5.0)[0]:
        return None
    (u, v), shape = disk
    radius = math.sqrt(abs(float(np.linalg.det(shape))))
    slack = search_slack_px(1.0, pinhole.fx, 0.0, 0.0)  # the pose is exact
    found = locate_hole(image, (float(u), float(v)), radius, 3 * radius + slack, shape)
    reach = disk_template(radius, shape=shape).shape[0] // 2 + max(2, int(radius // 2))
    fits = reach <= min(u, v, pinhole.width - 1 - u, pinhole.height - 1 - v)
    ellipse = ellipse_centre(target, opencv_pose(T_mjcam), pinhole)
    score = log = None  # the detector's two tests, at the hole
    if fits:
        gray = to_gray(image)
        template = disk_template(radius, shape=shape)
        at = match_hole_near(gray, template, template.shape[0] // 2, round(u), round(v), radius)
        score = None if at is None else at.score
        response = log_response(gray, max(radius / math.sqrt(2), 0.7))
        x, y = round(u), round(v)
        log = float(response[max(y - 2, 0):y + 3, max(x - 2, 0):x + 3].max())
    result, error, from_centre = outcome(None if found is None else (found.u, found.v),
                                         ellipse, disk[0])
    axes = np.linalg.svd(shape, compute_uv=False)
    return {"outcome": result, "error_px": error, "centre_error_px": from_centre,
            "fits": bool(fits), "ellipse": ellipse, "centre": disk[0],
            "score_at_hole": score, "log_at_hole": log,
            "bias_px": float(np.linalg.norm(ellipse - disk[0])),
            "uv": None if found is None else (found.u, found.v),
            "major_px": float(axes[0]), "minor_px": float(axes[1])}


def observe(scene: Scene, data: mujoco.MjData, renderer: Renderer, lens: Lens,
            position: np.ndarray, R: np.ndarray, sharp: bool) -> list[dict[str, Any]]:
    """Render the stereo pair from a pose and look for every hole in the left view (also
    in the sharp left image if ``sharp``)."""
    model, robot, s = scene.model, scene.robots[0], scene.scenario
    baseline = s.camera.baseline_m
    right_position = position + baseline * R[:, 0]
    put_camera(model, data, robot.camera, position, R)
    put_camera(model, data, robot.right_camera, right_position, R)
    mujoco.mj_forward(model, data)
    pinhole = camera_pinhole(model, robot.camera)
    sharp_left, depth_left = renderer.rgb_and_depth(data, robot.camera)
    sharp_right, depth_right = renderer.rgb_and_depth(data, robot.right_camera)
    seg = renderer.segmentation(data, robot.camera)
    left, right = defocus(sharp_left, depth_left, lens), defocus(sharp_right, depth_right, lens)
    T, T_right = camera_pose(data, robot.camera), camera_pose(data, robot.right_camera)
    rows = []
    for target in scene.targets:
        found_left = in_image(left, T, target, pinhole)
        if found_left is None:
            continue
        found_right = in_image(right, T_right, target, pinhole)
        unblurred = in_image(sharp_left, T, target, pinhole) if sharp else None
        seen = sight(robot.name, left, right, target, T, pinhole, baseline,
                     position_sd_m=0.0, rotation_sd_deg=0.0)
        single = find_target(left, seg, target, model.geom(target.geom).id, T, pinhole)
        both = (found_right is not None and found_left["outcome"] == "found"
                and found_right["outcome"] == "found"
                and abs(found_left["uv"][1] - found_right["uv"][1]) <= 1.5
                and found_left["uv"][0] > found_right["uv"][0])
        row: dict[str, Any] = {"target": target.name}
        for side, where, found in (("left", position, found_left),
                                   ("right", right_position, found_right)):
            row |= {f"{side}_{k}": v for k, v in geometry(where, target, pinhole).items()}
            row |= {f"{side}_{k}": None if found is None else found[k]
                    for k in ("outcome", "error_px", "centre_error_px", "bias_px", "fits",
                              "major_px", "minor_px", "score_at_hole", "log_at_hole")}
        row["left_sharp"] = None if unblurred is None else unblurred["outcome"]
        row["both"] = "found" if both else "missed"
        for key, pixel in (("sight", None if seen is None else seen.pixel),
                           ("find_target", single["pixel"] if single["seen"] else None)):
            row[key], row[f"{key}_error_px"], row[f"{key}_centre_error_px"] = outcome(
                pixel, found_left["ellipse"], found_left["centre"])
        row |= {"position": position.tolist(), "right_position": right_position.tolist(),
                "quat_wxyz": Rotation.from_matrix(R).as_quat(scalar_first=True).tolist()}
        rows.append(row)
    return rows


