"""Where the hole detector stops finding the target: its smallest projected radius and
its largest angle off the target's normal, measured on rendered, defocused images.

Run from the repository root: ``python -m bench.studies.detector_limits`` (about 2.5 min). The
scene is the default scenario's without obstacles (the work-piece with its primary and
secondary holes, the panel; the one robot is sunk under the floor). A free stereo pair
(the scenario's baseline) is put at a grid of distances (0.35-8 m: the depth of field
0.35-1.5 m and beyond) and angles off the target's normal (0-89 deg), each jittered
(distance +-5 %, angle +-2.5 deg), at a random azimuth and roll, aimed up to 8 deg off
the primary or the secondary hole in turn; every hole in the left view is a sample.
Both images are rendered, blurred by the lens as the task blurs them (sim/world/optics.py),
and searched as ``sight`` searches them (left and right, its stereo checks), as
``find_target`` does (with the segmentation), and each on its own with its camera's own
projected ellipse (and, for the first configuration, the left one without blur too).

A find is right when it lies within 1 px of the centre of the ellipse the hole's rim
projects to; the error from the projection of the hole's centre (which perspective
shifts by up to ~1 px at 0.35 m) is recorded too. The projected radius is the
foreshortened one, f r cos(a) / d (px): the minor semi-axis of the hole's image when
the camera looks straight at it (d the distance from that camera's centre, f the focal
length in pixels); a is the angle between the target's normal and the direction to the
camera. The limits are per image, from the depth of field's near limit on, where the
detector's matching window lies inside the image: the rectangle radius >= R, angle <= A
(bin edges) in which every radius bin and every angle bin finds >= 95 % of its samples
under every configuration (640x480 with and without MSAA, 320x240 with), accepting the
most samples. Then taskcam.placement.detectable with DetectorLimits' defaults is checked against
the detector on the views aimed at a hole: its success rate where the limits accept the
view ("inside", predicted 1) and where they refuse it ("outside", predicted 0). Prints
the grids and that table and writes bench/results/detector_limits.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import time
from typing import Any

import numpy as np

from bench.common import write_results
from bench.studies.detector_views import MAX_ERROR_PX, observe, probe_scenario, view_pose
from taskcam.placement import CameraModel, DetectorLimits, TargetModel, detectable
from taskcam.sim.config.scenario import Scenario, load_scenario
from taskcam.sim.world.optics import Lens
from taskcam.sim.world.render import Renderer
from taskcam.sim.world.scene import Scene, build_scene

CONFIGS = (  # label, width, height, MSAA samples: as table1, the default, regression
    ("640x480", 640, 480, 0), ("640x480 MSAA 4", 640, 480, 4), ("320x240 MSAA 4", 320, 240, 4))
DISTANCES = (0.35, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)  # m
ANGLES = (0, 25, 45, 55, 62, 68, 72, 76, 80, 85, 89)  # deg off the normal
RADIUS_BINS = (0.0, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 6.0, 10.0,
               math.inf)  # px
ANGLE_BINS = (0.0, 30.0, 50.0, 60.0, 65.0, 70.0, 72.5, 75.0, 77.5, 80.0, 85.0, 90.0)  # deg
RELIABLE = 0.95  # success rate a bin needs
MIN_BIN = 10  # samples a bin needs to be judged on its own


def study(label: str, width: int, height: int, samples: int, repeats: int,
          rng: np.random.Generator, sharp: bool = False) -> list[dict[str, Any]]:
    """Every view of the grid under one image size and multisampling (and the left image
    without blur too if ``sharp``)."""
    scenario = probe_scenario(width, height, samples)
    scene = build_scene(scenario)
    model = scene.model
    model.body_pos[model.body(f"{scene.robots[0].name}/base").id, 2] = -3.0  # out of sight
    data = scene.make_data()
    lens = Lens(scenario.camera.near_m, scenario.camera.far_m, scenario.camera.coc_px)
    rows: list[dict[str, Any]] = []
    with Renderer(model, width, height) as renderer:
        for distance in DISTANCES:
            for angle in ANGLES:
                for k in range(repeats):
                    aimed = scene.targets[(k + len(rows)) % len(scene.targets)]
                    d = distance * rng.uniform(0.95, 1.05)
                    a = min(max(angle + rng.uniform(-2.5, 2.5), 0.0), 89.5)
                    position, R = view_pose(aimed, d, math.radians(a), rng)
                    for row in observe(scene, data, renderer, lens, position, R, sharp):
                        rows.append(row | {"config": label,
                                           "aimed": row["target"] == aimed.name})
    return rows


def image_samples(rows: list[dict[str, Any]], near_m: float, sharp: bool = False,
                  left_only: bool = False) -> list[dict[str, Any]]:
    """One sample per image a hole was looked for in (left and right; the left only, or
    the sharp left only), from ``near_m`` on and where the matching window fits: its
    radius, angle and outcome."""
    out = []
    for r in rows:
        for side in ("left",) if sharp or left_only else ("left", "right"):
            if (r[f"{side}_outcome"] is None or not r[f"{side}_fits"]
                    or (sharp and r["left_sharp"] is None)):
                continue
            if r[f"{side}_distance_m"] < near_m:
                continue
            out.append({"radius_px": r[f"{side}_radius_px"], "angle_deg": r[f"{side}_angle_deg"],
                        "outcome": r["left_sharp"] if sharp else r[f"{side}_outcome"],
                        "score": r[f"{side}_score_at_hole"], "log": r[f"{side}_log_at_hole"]})
    return out


def camera_model(scenario: Scenario) -> CameraModel:
    c = scenario.camera
    return CameraModel(math.radians(c.fovy_deg), c.height, c.near_m, c.far_m)


def rate(rows: list[dict[str, Any]], key: str = "outcome") -> float | None:
    return None if not rows else sum(r[key] == "found" for r in rows) / len(rows)


def binned(rows: list[dict[str, Any]], field: str, edges: tuple[float, ...]
           ) -> list[list[dict[str, Any]]]:
    return [[r for r in rows if lo <= r[field] < hi] for lo, hi in itertools.pairwise(edges)]


def reliable(samples: list[dict[str, Any]], radius: float, angle: float,
             min_bin: int = MIN_BIN) -> bool:
    """Whether every radius bin from ``radius`` (px) on, pooled over the angles up to
    ``angle`` (deg), and every angle bin up to ``angle``, pooled over the radii from
    ``radius``, succeeds in RELIABLE of its samples (a bin of fewer than ``min_bin`` is
    not judged on its own; its samples still count in the bins across it)."""
    inside = [r for r in samples if r["radius_px"] >= radius and r["angle_deg"] <= angle]
    bands = binned(inside, "radius_px", RADIUS_BINS) + binned(inside, "angle_deg", ANGLE_BINS)
    return all(rate(b) >= RELIABLE for b in bands if len(b) >= min_bin)  # type: ignore[operator]


def derive_limits(per_config: list[list[dict[str, Any]]]) -> tuple[float, float]:
    """(smallest radius px, largest angle deg), bin edges both, reliable under every
    configuration, that accept the most samples (ties: the smaller radius)."""
    best: tuple[int, float, float] | None = None
    for radius in RADIUS_BINS[:-1]:
        for angle in ANGLE_BINS[1:]:
            if not all(reliable(samples, radius, angle) for samples in per_config):
                continue
            accepted = sum(r["radius_px"] >= radius and r["angle_deg"] <= angle
                           for samples in per_config for r in samples)
            if best is None or accepted > best[0]:
                best = (accepted, radius, angle)
    if best is None:
        raise RuntimeError("no limits are reliable: the detector failed everywhere")
    return best[1], best[2]


def grid(samples: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Success count per radius bin and angle bin (the cells :func:`print_grid` shows)."""
    cells = []
    for lo, band in zip(RADIUS_BINS, binned(samples, "radius_px", RADIUS_BINS), strict=False):
        for start, cell in zip(ANGLE_BINS, binned(band, "angle_deg", ANGLE_BINS), strict=False):
            if cell:
                cells.append({"radius_px_from": lo, "angle_deg_from": start,
                              "samples": len(cell),
                              "found": sum(r["outcome"] == "found" for r in cell)})
    return cells


def print_grid(samples: list[dict[str, Any]]) -> None:
    """Success rate (%) and count per radius bin (rows) and angle bin (columns)."""
    head = "radius px \\ deg"
    print(f"{head:<11}" + "".join(f"{f'{lo:g}-{hi:g}':>9}"
                                  for lo, hi in itertools.pairwise(ANGLE_BINS)))
    for (lo, hi), bin_rows in zip(itertools.pairwise(RADIUS_BINS),
                                  binned(samples, "radius_px", RADIUS_BINS), strict=True):
        cells = []
        for cell in binned(bin_rows, "angle_deg", ANGLE_BINS):
            cells.append(f"{100 * rate(cell):>4.0f}/{len(cell):<3d}"  # type: ignore[operator]
                         if cell else f"{'':>8}")
        print(f"{f'{lo:g}-{hi:g}':<11}" + " ".join(cells))


def tests_at_hole(samples: list[dict[str, Any]], field: str, edges: tuple[float, ...]
                  ) -> list[dict[str, Any]]:
    """Per bin of ``field``: success rate and the median template score and LoG response
    at the hole (the detector needs a score of 0.5 and a response of 0.05)."""
    out = []
    for (lo, hi), part in zip(itertools.pairwise(edges), binned(samples, field, edges),
                              strict=True):
        if not part:
            continue
        scores = [r["score"] for r in part if r["score"] is not None]
        out.append({"bin": [lo, hi], "samples": len(part), "success": rate(part),
                    "median_score": float(np.median(scores)) if scores else None,
                    "median_log": float(np.median([r["log"] for r in part]))})
    return out


def predictions(rows: list[dict[str, Any]], scene: Scene, limits: DetectorLimits
                ) -> dict[str, list[bool]]:
    """taskcam.placement.detectable's verdicts per sample: from both cameras' real positions
    ('pair'), from the left one alone ('left'), and from the left one with the baseline
    in its worst direction ('worst_roll', what placement can check before the roll is
    known)."""
    camera = camera_model(scene.scenario)
    baseline = scene.scenario.camera.baseline_m
    models = {t.name: TargetModel(t.name, t.position, t.normal, t.radius)
              for t in scene.targets}
    out: dict[str, list[bool]] = {"pair": [], "left": [], "worst_roll": []}
    for r in rows:
        t = models[r["target"]]
        left = np.array([r["position"]])
        ok_left = bool(detectable(left, t, camera, limits)[0])
        out["left"].append(ok_left)
        out["pair"].append(ok_left and bool(
            detectable(np.array([r["right_position"]]), t, camera, limits)[0]))
        out["worst_roll"].append(bool(detectable(left, t, camera, limits,
                                                 baseline_m=baseline)[0]))
    return out


COMPARISONS = (  # detection, prediction, what it says
    ("sight", "pair", "sight (as it runs) vs both cameras within the limits"),
    ("both", "pair", "each image with its own ellipse vs both cameras within the limits"),
    ("sight", "worst_roll", "sight vs the left camera with the baseline at its worst roll"),
    ("sight", "left", "sight vs the left camera alone within the limits"),
    ("find_target", "left", "find_target vs the left camera within the limits"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3,
                        help="views per distance and angle (azimuth, roll, aim, jitter)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    started = time.perf_counter()
    samples: list[dict[str, Any]] = []
    per_config: dict[str, dict[str, Any]] = {}
    per_image: dict[str, list[dict[str, Any]]] = {}
    near = load_scenario().camera.near_m
    for label, width, height, msaa in CONFIGS:
        t0 = time.perf_counter()
        first = label == CONFIGS[0][0]
        rows = study(label, width, height, msaa, args.repeats, rng, sharp=first)
        samples += rows
        images = image_samples(rows, near)
        per_image[label] = images
        radius, angle = derive_limits([images])
        sharp = derive_limits([image_samples(rows, near, sharp=True)]) if first else None
        blurred = derive_limits([image_samples(rows, near, left_only=True)]) if first else None
        per_config[label] = {
            "seconds": round(time.perf_counter() - t0, 1), "holes": len(rows),
            "image_samples": len(images), "grid": grid(images),
            "limits": {"min_radius_px": radius, "max_off_normal_deg": angle},
            "limits_left": None if blurred is None else
            {"min_radius_px": blurred[0], "max_off_normal_deg": blurred[1]},
            "limits_left_sharp": None if sharp is None else
            {"min_radius_px": sharp[0], "max_off_normal_deg": sharp[1]}}
        print(f"\n{label}: {len(rows)} holes in view in {per_config[label]['seconds']} s; "
              f"per image (from {near} m, matching window inside the image), success %/count:")
        print_grid(images)
        by_angle = tests_at_hole([r for r in images if r["radius_px"] >= 1.0], "angle_deg",
                                 ANGLE_BINS)
        by_radius = tests_at_hole([r for r in images if r["angle_deg"] <= 60.0], "radius_px",
                                  RADIUS_BINS)
        per_config[label] |= {"by_angle_from_1px": by_angle, "by_radius_to_60deg": by_radius}
        for name, rows_ in (("angle deg (radius >= 1 px)", by_angle),
                            ("radius px (angle <= 60 deg)", by_radius)):
            print(f"at the hole, by {name}: success / median template score / median LoG: "
                  + "; ".join(f"{b['bin'][0]:g}-{b['bin'][1]:g}: {b['success']:.2f}/"
                              f"{b['median_score'] or float('nan'):.2f}/{b['median_log']:.2f}"
                              for b in rows_))
        print(f"limits: radius >= {radius} px, angle <= {angle} deg"
              + ("" if sharp is None or blurred is None else
                 f"; left images alone: {blurred[0]} px, {blurred[1]} deg blurred, "
                 f"{sharp[0]} px, {sharp[1]} deg without blur"))

    measured = derive_limits(list(per_image.values()))
    chosen = DetectorLimits()
    print(f"\nreliable under every configuration: radius >= {measured[0]} px, "
          f"angle <= {measured[1]} deg; taskcam.placement.DetectorLimits defaults: {chosen}")
    table = []
    for label, width, height, msaa in CONFIGS:
        scene = build_scene(probe_scenario(width, height, msaa))
        rows = [r for r in samples if r["config"] == label and r["aimed"]
                and r["left_distance_m"] >= near]
        verdicts = predictions(rows, scene, chosen)
        for key, which, what in COMPARISONS:
            for name, want in (("inside", True), ("outside", False)):
                part = [r for r, v in zip(rows, verdicts[which], strict=True) if v is want]
                measured_rate = rate(part, key)
                table.append({"case": f"{label}: {what}, {name} ({len(part)} views)",
                              "ours": measured_rate, "peer": 1.0 if want else 0.0,
                              "ratio": measured_rate if want else None,
                              "unit": "success rate (peer: the limits' prediction)"})
        inside = [r for r, v in zip(rows, verdicts["pair"], strict=True) if v]
        errors = np.array([[r["sight_error_px"], r["sight_centre_error_px"]]
                           for r in inside if r["sight"] == "found"]).reshape(-1, 2)
        everywhere = [r for r in samples if r["config"] == label]
        cut = [r for r in everywhere if not r["left_fits"]]
        per_config[label]["window_outside_image"] = {
            "holes": len(cut), "found_by_sight": sum(r["sight"] == "found" for r in cut)}
        per_config[label]["aimed_views_from_near"] = {
            "views": len(rows), "inside_pair": len(inside),
            "sight_wrong_inside": sum(r["sight"] == "wrong" for r in inside),
            "sight_found_where_own_ellipses_fail": sum(
                r["sight"] == "found" and r["both"] != "found" for r in rows),
            "own_ellipses_found_where_sight_fails": sum(
                r["sight"] != "found" and r["both"] == "found" for r in rows),
            "inside_sight_error_px": {  # from the ellipse's centre; the hole's centre
                "median": np.median(errors, axis=0).tolist() if len(errors) else None,
                "p95": np.percentile(errors, 95, axis=0).tolist() if len(errors) else None,
                "max": errors.max(axis=0).tolist() if len(errors) else None},
            "sight_failures_inside": [
                {k: round(r[k], 3) for k in ("left_distance_m", "left_angle_deg",
                                             "left_radius_px", "right_angle_deg",
                                             "right_radius_px")}
                | {"target": r["target"], "sight": r["sight"], "both": r["both"]}
                for r in inside if r["sight"] != "found"]}
    print(f"\n{'case':<100} {'measured':>8} {'predicted':>9}")
    for r in table:
        value = "-" if r["ours"] is None else f"{r['ours']:.3f}"
        print(f"{r['case']:<100} {value:>8} {r['peer']:>9.0f}")
    biases = {label: max((r[f"{side}_bias_px"] for r in samples
                          for side in ("left", "right") if r["config"] == label
                          and r[f"{side}_bias_px"] is not None
                          and r[f"{side}_distance_m"] >= near), default=0.0)
              for label, *_ in CONFIGS}
    print("\nlargest perspective shift of the ellipse's centre from the projection of the "
          f"hole's centre, from {near} m: "
          + ", ".join(f"{label} {b:.2f} px" for label, b in biases.items()))
    for label, c in per_config.items():
        a = c["aimed_views_from_near"]
        print(f"{label}: sight inside the limits off the ellipse's centre / the hole's "
              f"centre, median {a['inside_sight_error_px']['median']}, max "
              f"{a['inside_sight_error_px']['max']} px; sight found where each image's own "
              f"ellipse did not: {a['sight_found_where_own_ellipses_fail']}, the reverse: "
              f"{a['own_ellipses_found_where_sight_fails']} of {a['views']}; holes whose "
              f"matching window leaves the image: {c['window_outside_image']}")
    print(f"{len(samples)} holes in view, {time.perf_counter() - started:.0f} s")
    path = write_results(
        "detector_limits", table,
        peer_note=("No peer detector: 'ours' is the measured success rate (found within "
                   f"{MAX_ERROR_PX} px of the hole's image's centre) over the views the limits "
                   "(taskcam.placement.DetectorLimits' defaults) accept or refuse, 'peer' what "
                   "the limits predict (1 inside, 0 outside); the ratio is the success "
                   "rate inside."),
        definitions={
            "radius_px": "f r cos(angle) / d: the minor semi-axis of the hole's image "
                         "when the camera looks straight at it (f = fy, d from the "
                         "camera's centre)",
            "angle_deg": "between the target's normal and the direction to the camera",
            "success": f"found within {MAX_ERROR_PX} px of the centre of the ellipse the "
                       "hole's rim projects to (the error from the projection of the "
                       "hole's centre, which perspective shifts, is recorded too); sight: "
                       "in both images with its stereo checks",
            "reliable": RELIABLE,
            "limits": "per image (left and right), from the depth of field's near limit "
                      "on, where the matching window lies inside the image"},
        measured={"min_radius_px": measured[0], "max_off_normal_deg": measured[1]},
        chosen=dataclasses.asdict(chosen), per_config=per_config,
        largest_ellipse_shift_px_from_near=biases,
        seconds=round(time.perf_counter() - started, 1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
