"""How precisely the insertion task measures the panel's displacement from its slot, over
distance, angle and occlusion, against what the stereo geometry predicts.

Run from the repository root: ``python -m bench.studies.measurement`` (``--quick``: 5 views a
cell, ``--views N``). The scene is Table 1's (scenarios/table1.toml: no MSAA, the
work-piece off by N(0, 1 cm) in x and y and N(0, 2 deg) in yaw, drawn per view) without
obstacles but the occluder. For each cell of the grid (distance from the left camera to
the slot, angle off the slot's normal, share of the edges occluded) the panel hangs a
random displacement above its slot (uniform +-20 mm across, 35-60 mm up: just above the
rails, the end of the approach) and a stereo pair looks at the site from a random azimuth
within 45 deg of the panel's face normal (either side), aimed between the slot and the
panel's centre, rolled up to +-15 deg. The camera's believed pose is off its true one by
N(0, 1 mm) and N(0, 0.1 deg) RMS (the residual the pose correction leaves). Both
images are rendered once and every measurement in bench/studies/measurement_views.py's
``MEASUREMENTS`` runs on them; today that is the absolute one (the task's own code).

Occlusion: points along the 12 edges of the panel and of both rails (16 per edge) that
the left camera sees (ray cast from its centre, nothing within 3 mm short of the point);
a thin plate, square to the line of sight, between the site and the camera (halfway, at
most 0.3 m from the site), slides in from the side away from the holes until it hides
the grid's share of those points. The share it hides, cast again with the plate in place,
is what the table reports.

The error is the measured minus the true displacement, in the true left camera's frame
(x right, y down, z along the viewing axis). The geometry's prediction for a view at
depth z: each end (panel, slot) located to sigma_px = 0.1 px in each image, so
lateral sigma = sqrt(2) z / f sigma_px per axis and along the axis sqrt(2) z^2 / (f b)
sigma_px (f = 416 px, b = 0.12 m); the median and 95th percentile of |error| of one axis
are 0.674 and 1.96 sigma, of the lateral (2-D) error 1.18 and 2.45 sigma. 0.1 px is what
a model-based sub-pixel edge fit is expected to reach: the reference the relative
measurement is to be judged against, not a model of SGBM (whose per-point disparity error
on the panel is 0.24 px median). It does not model angle, blur or the pose's residual.

Writes bench/results/measurement.json (per cell and measurement: views, failures and
why, medians and 95th percentiles; every view's record) and prints the table.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from typing import Any

import numpy as np

from bench.common import write_results
from bench.studies.measurement_views import MEASUREMENTS, Site, View
from taskcam.mapping import opencv_pose

DISTANCES = (0.25, 0.5, 0.8, 1.2, 1.5, 2.0)  # m; depth of field 0.35-1.5 m
ANGLES = (0, 30, 50, 70)  # deg off the slot's normal
OCCLUSIONS = (0.0, 0.3, 0.6)  # share of the edges hidden
SIGMA_PX = 0.1  # the geometry's assumed error of one located feature, each image (px)
# |N(0, s)| of one axis: median 0.674 s, 95th percentile 1.96 s; of a 2-D error (Rayleigh):
# 1.177 s and 2.448 s
AXIS_QUANTILES = (0.6745, 1.96)
PLANE_QUANTILES = (1.1774, 2.4477)


def predicted_sd(depth_m: float, fx_px: float, baseline_m: float, sigma_px: float = SIGMA_PX
                 ) -> tuple[float, float]:
    """The stereo geometry's standard deviation (m) of a displacement between two points
    at ``depth_m``, each located to ``sigma_px`` in each image: per lateral axis
    sqrt(2) z / f sigma, along the viewing axis sqrt(2) z^2 / (f b) sigma."""
    lateral = math.sqrt(2) * depth_m / fx_px * sigma_px
    axial = math.sqrt(2) * depth_m ** 2 / (fx_px * baseline_m) * sigma_px
    return lateral, axial


def view_truth(view: View) -> np.ndarray:
    """The view's true displacement (world, m): panel minus slot."""
    return view.true_panel[:3, 3] - view.true_slot


def error_in_camera(view: View, measured: np.ndarray) -> np.ndarray:
    """Measured minus true displacement (m) in the true left camera's OpenCV frame."""
    return opencv_pose(view.true_camera)[:3, :3].T @ (measured - view_truth(view))


def cell_stats(errors: list[np.ndarray]) -> dict[str, float | None]:
    """Medians and 95th percentiles (mm) of |error| per camera axis and laterally."""
    if not errors:
        return {k: None for k in ("x_p50_mm", "x_p95_mm", "y_p50_mm", "y_p95_mm",
                                  "lateral_p50_mm", "lateral_p95_mm", "axial_p50_mm",
                                  "axial_p95_mm")}
    e = np.abs(np.array(errors)) * 1e3
    lateral = np.hypot(e[:, 0], e[:, 1])
    out: dict[str, float | None] = {}
    for name, values in (("x", e[:, 0]), ("y", e[:, 1]), ("lateral", lateral),
                         ("axial", e[:, 2])):
        out[f"{name}_p50_mm"] = round(float(np.median(values)), 3)
        out[f"{name}_p95_mm"] = round(float(np.percentile(values, 95)), 3)
    return out


def run_cell(site: Site, distance: float, angle: float, occlusion: float, n: int,
             records: list[dict[str, Any]]) -> dict[str, Any]:
    """``n`` views of one cell, every measurement on each; the cell's row."""
    errors: dict[str, list[np.ndarray]] = {name: [] for name in MEASUREMENTS}
    clean: dict[str, list[np.ndarray]] = {name: [] for name in MEASUREMENTS}  # no note
    why: dict[str, Counter[str]] = {name: Counter() for name in MEASUREMENTS}
    notes: dict[str, Counter[str]] = {name: Counter() for name in MEASUREMENTS}
    seconds: dict[str, float] = dict.fromkeys(MEASUREMENTS, 0.0)
    spread: dict[str, list[float]] = {name: [] for name in MEASUREMENTS}  # Mahalanobis
    occluded, blur = [], []
    for _ in range(n):
        view = site.view(distance, angle, occlusion)
        occluded.append(view.occluded)
        blur.append(view.blur_px)
        record: dict[str, Any] = {"distance_m": distance, "angle_deg": angle,
                                  "occlusion": occlusion, "occluded": round(view.occluded, 3),
                                  "blur_px": round(view.blur_px, 2)}
        for name, measure in MEASUREMENTS.items():
            t0 = time.perf_counter()
            m = measure(site, view)
            seconds[name] += time.perf_counter() - t0
            if m.displacement is None:
                why[name][m.why or "?"] += 1
                record[name] = {"why": m.why}
            else:
                e = error_in_camera(view, m.displacement)
                errors[name].append(e)
                if m.why:
                    notes[name][m.why] += 1
                else:
                    clean[name].append(e)
                record[name] = {"error_cam_mm": (e * 1e3).round(3).tolist(), "note": m.why}
                if m.covariance is not None:  # the error in its own standard deviations
                    off = m.displacement - view_truth(view)
                    spread[name].append(float(np.sqrt(off @ np.linalg.solve(m.covariance, off))))
                    record[name]["mahalanobis"] = round(spread[name][-1], 3)
        records.append(record)
    fx, b = site.pinhole.fx, site.scenario.camera.baseline_m
    lateral_sd, axial_sd = predicted_sd(distance, fx, b)
    row: dict[str, Any] = {
        "case": f"{distance:g} m, {angle:g} deg, {occlusion:.0%} occluded",
        "distance_m": distance, "angle_deg": angle, "occlusion": occlusion,
        "occluded_mean": round(float(np.mean(occluded)), 3),
        "blur_px_at_slot": round(float(np.median(blur)), 2), "views": n,
        "predicted": {
            "lateral_axis_p50_mm": round(AXIS_QUANTILES[0] * lateral_sd * 1e3, 3),
            "lateral_axis_p95_mm": round(AXIS_QUANTILES[1] * lateral_sd * 1e3, 3),
            "lateral_p50_mm": round(PLANE_QUANTILES[0] * lateral_sd * 1e3, 3),
            "lateral_p95_mm": round(PLANE_QUANTILES[1] * lateral_sd * 1e3, 3),
            "axial_p50_mm": round(AXIS_QUANTILES[0] * axial_sd * 1e3, 3),
            "axial_p95_mm": round(AXIS_QUANTILES[1] * axial_sd * 1e3, 3)}}
    for name in MEASUREMENTS:
        row[name] = {**cell_stats(errors[name]), "measured": len(errors[name]),
                     "with_every_note_absent": {**cell_stats(clean[name]),
                                                "measured": len(clean[name])},
                     "failed": round(1 - len(errors[name]) / n, 3),
                     "why_failed": dict(why[name].most_common()),
                     "notes": dict(notes[name].most_common()),
                     "seconds_per_view": round(seconds[name] / n, 3)}
        if spread[name]:  # the error against the measurement's own covariance
            row[name]["mahalanobis_p50"] = round(float(np.percentile(spread[name], 50)), 2)
            row[name]["mahalanobis_p95"] = round(float(np.percentile(spread[name], 95)), 2)
    # The row keys of docs/benchmarks.md's tables (ours, peer, ratio, unit): the first
    # measurement's 95th-percentile lateral error against the geometry's
    first = row[next(iter(MEASUREMENTS))]
    ours, peer = first["lateral_p95_mm"], row["predicted"]["lateral_p95_mm"]
    row |= {"ours": ours, "peer": peer, "unit": "mm (lateral p95: measured, geometry)",
            "ratio": None if ours is None else round(ours / peer, 2)}
    return row


def short(reasons: dict[str, int]) -> str:
    """The commonest failure, abbreviated."""
    if not reasons:
        return ""
    text, count = next(iter(reasons.items()))
    return f"{count}x {text[:90]}"


def print_rows(rows: list[dict[str, Any]]) -> None:
    for name in MEASUREMENTS:
        print(f"\n{name}: |measured - true displacement| (mm), camera frame; "
              f"geo = stereo geometry at {SIGMA_PX} px; * = views without a note "
              f"(both holes sighted)")
        print(f"{'dist':>5} {'ang':>4} {'occ':>4} {'occ*':>5} {'blur':>5} {'n':>3} {'fail':>5} "
              f"{'lat50':>7} {'lat95':>7} {'geo95':>6} {'x95':>7} {'y95':>7} {'ax50':>7} "
              f"{'ax95':>7} {'geo95':>6} {'lat95*':>7} {'ax95*':>7}  commonest failure")
        for r in rows:
            m, p = r[name], r["predicted"]
            c = m["with_every_note_absent"]

            def f(v: float | None) -> str:
                return "-" if v is None else f"{v:.2f}"
            print(f"{r['distance_m']:>5.2f} {r['angle_deg']:>4.0f} {r['occlusion']:>4.0%} "
                  f"{r['occluded_mean']:>5.0%} {r['blur_px_at_slot']:>5.1f} {r['views']:>3} "
                  f"{m['failed']:>5.0%} {f(m['lateral_p50_mm']):>7} {f(m['lateral_p95_mm']):>7} "
                  f"{p['lateral_p95_mm']:>6.2f} {f(m['x_p95_mm']):>7} {f(m['y_p95_mm']):>7} "
                  f"{f(m['axial_p50_mm']):>7} {f(m['axial_p95_mm']):>7} "
                  f"{p['axial_p95_mm']:>6.2f} {f(c['lateral_p95_mm']):>7} "
                  f"{f(c['axial_p95_mm']):>7}  {short(m['why_failed'])}")


def markdown(rows: list[dict[str, Any]], name: str) -> str:
    """The cells of measurement ``name`` as the Markdown table of docs/measurement.md."""
    def pair(a: float | None, b: float | None) -> str:
        return "- / -" if a is None else f"{a:.1f} / {b:.1f}"

    def one(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    lines = ["| distance m | angle ° | occluded (target / measured) | blur px | failed | "
             "lateral p50 / p95 mm | geometry p95 | x p95 | y p95 | axial p50 / p95 mm | "
             "geometry p95 | both holes sighted: lateral p95 / axial p95 (views) | "
             "commonest failure |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        m, p, c = r[name], r["predicted"], r[name]["with_every_note_absent"]
        lines.append(
            f"| {r['distance_m']:g} | {r['angle_deg']:g} | {r['occlusion']:.0%} / "
            f"{r['occluded_mean']:.0%} | {r['blur_px_at_slot']:.1f} | {m['failed']:.0%} | "
            f"{pair(m['lateral_p50_mm'], m['lateral_p95_mm'])} | {p['lateral_p95_mm']:.2f} | "
            f"{one(m['x_p95_mm'])} | {one(m['y_p95_mm'])} | "
            f"{pair(m['axial_p50_mm'], m['axial_p95_mm'])} | {p['axial_p95_mm']:.2f} | "
            f"{pair(c['lateral_p95_mm'], c['axial_p95_mm'])} ({c['measured']}) | "
            f"{short(m['why_failed']).replace(' | ', '; ')} |")
    return "\n".join(lines) + "\n"


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 views a cell")
    parser.add_argument("--views", type=int, default=None, help="views a cell (default 50)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--distances", type=_floats, default=DISTANCES,
                        help="only these distances (m, comma-separated); results not written")
    parser.add_argument("--angles", type=_floats, default=ANGLES, help="only these angles")
    parser.add_argument("--occlusions", type=_floats, default=OCCLUSIONS,
                        help="only these occlusions")
    parser.add_argument("--samples", type=int, default=None,
                        help="multisample anti-aliasing, samples a pixel (default: Table 1's, "
                             "0; the default scenario's is 4); results not written")
    args = parser.parse_args()
    whole = (tuple(args.distances), tuple(args.angles), tuple(args.occlusions)) == (
        DISTANCES, ANGLES, OCCLUSIONS) and args.samples is None
    n = args.views or (5 if args.quick else 50)
    rng = np.random.default_rng(args.seed)
    started = time.perf_counter()
    rows: list[dict[str, Any]] = []
    records: list[dict[str, Any]] = []
    site = Site(rng, args.samples)
    cells = [(d, a, o) for d in args.distances for a in args.angles for o in args.occlusions]
    try:
        for i, (d, a, o) in enumerate(cells):
            t0 = time.perf_counter()
            rows.append(run_cell(site, d, a, o, n, records))
            print(f"[{i + 1}/{len(cells)}] {rows[-1]['case']}: "
                  f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    finally:
        site.close()
    seconds = time.perf_counter() - started
    print_rows(rows)
    for name in MEASUREMENTS:
        print(f"\n{name}, as docs/measurement.md's table:\n\n{markdown(rows, name)}")
    print(f"\ngrid {len(args.distances)} distances x {len(args.angles)} angles x "
          f"{len(args.occlusions)} occlusions = {len(cells)} cells x {n} views = "
          f"{len(cells) * n} views; {seconds:.0f} s")
    for name in MEASUREMENTS:
        pooled = [v[name]["mahalanobis"] for v in records
                  if isinstance(v.get(name), dict) and "mahalanobis" in v[name]]
        if pooled:  # a true covariance: the root of chi2 with 3 dof, 1.54 and 2.80
            print(f"{name}: error / its own standard deviation (Mahalanobis), all views: "
                  f"median {np.median(pooled):.2f} (1.54 if the covariance were true), "
                  f"95th percentile {np.percentile(pooled, 95):.2f} (2.80)")
    if not whole:
        return
    path = write_results(
        "measurement", rows, measurements=list(MEASUREMENTS), views_per_cell=n, seed=args.seed,
        grid={"distances_m": DISTANCES, "angles_deg": ANGLES, "occlusions": OCCLUSIONS},
        sigma_px=SIGMA_PX, fx_px=site.pinhole.fx,
        baseline_m=site.scenario.camera.baseline_m, seconds=round(seconds, 1),
        views=records)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
