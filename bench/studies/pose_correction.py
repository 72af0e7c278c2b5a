"""How well and how fast the episode corrects each camera's pose from natural fiducials.

Runs the default scenario (errors and correction on) over seeds with each tracker
variant, on the same seeds in one run: ``taskcam`` (the scenario as it is), ``baseline``
(the first tracker: a frame every 3 degrees or 3 cm of the camera's travel, SIFT in
both images matched along the rows) and
``orb`` (the scenario's tracker with ORB corners refined to sub-pixel instead of SIFT),
``correlation`` (right pixels by correlation along the row instead of SIFT matching)
``flow`` (right pixels by optical flow from the left image instead), ``akaze`` (AKAZE
for SIFT; it needs OpenCV's contrib modules: :func:`akaze`), and two with fewer frames:
``track`` (no views added near the goal) and ``overlap30`` (a frame when under 0.3 of
the last frame's fiducials are expected found again).
For each it compares, against the simulator's truth, the camera pose before correction
(the commanded one), after it with each estimator on the same fiducials (the paper's
linear fit, Kabsch, SQPnP), and the bundle adjustment's own last pose; and the wall time
of a move's correction by part, against each part's budget, and by frame: why each was
taken (the first, to carry the track, a view near the goal, the final one), with what a
move would cost were its track frames free. The last lines give each
variant's time per move over the baseline's.

    .venv/bin/python -m bench.studies.pose_correction [--seeds 12] [--workers 1] \
        [--variants taskcam,baseline]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import cv2
import numpy as np

from bench.common import write_results

TARGET_M, TARGET_DEG = 0.003, 0.2
# [correction] keys of each variant over the default scenario's
VARIANTS: dict[str, dict[str, Any]] = {
    "taskcam": {},
    "baseline": {"frames": "fixed", "detector": "sift", "stereo": "descriptors"},
    "orb": {"detector": "orb"},
    "correlation": {"stereo": "correlation"},
    "flow": {"stereo": "flow"},
    # fewer frames: none added near the goal for the estimate's views; or the track's
    # frames when under 0.3 of the last frame's fiducials are expected found again
    "track": {"frames": "track"},
    "overlap30": {"frame_overlap": 0.3},
    "akaze": {},  # the scenario's tracker with AKAZE for SIFT: see akaze()
}
# Wall seconds a move's correction may spend on each part (1.5 s in all, one
# worker): about five stereo frames of two renders, a segmentation and SIFT on the pair,
# one bundle adjustment of them and the final estimate.
BUDGET_S = {"render": 0.45, "features": 0.5, "track": 0.15, "bundle": 0.25, "estimate": 0.15}


@contextlib.contextmanager
def akaze(threshold: float = 1e-5, most_bits: float = 120.0) -> Iterator[None]:
    """The tracker with AKAZE keypoints and descriptors instead of SIFT's, while inside.
    AKAZE is in opencv-contrib's ``xfeatures2d`` (OpenCV 5 moved it out of the main
    package), which the lock does not install: in a separate environment,
    ``pip install --no-deps opencv-contrib-python-headless==5.0.0.93`` ahead of the
    project's packages. Every keypoint is found and described in one pass (AKAZE's
    nonlinear scale space is most of its cost; describing the kept ones apart builds it
    again: 64 + 56 ms against 91 ms an image), then the spread ones are kept. A response
    threshold of 1e-5 finds about as many keypoints as SIFT at the tracker's contrast
    (2800-4400 an image); the 486-bit descriptors are compared by Hamming distance, and
    one further than a quarter of their bits (120) matches nothing."""
    import taskcam.calibration.stereo_features as stereo_features

    contrib = getattr(cv2, "xfeatures2d", None)
    if contrib is None:
        raise SystemExit("bench.studies.pose_correction: --variants akaze needs OpenCV's "
                         "contrib modules (see the akaze() docstring)")
    init = stereo_features.FeatureFinder.__init__
    keypoints = stereo_features.FeatureFinder.keypoints
    limit = stereo_features.DESCRIPTOR_MAX["orb"]  # byte descriptors are looked up as ORB's

    def akaze_init(self: Any, settings: Any) -> None:
        init(self, settings)
        self.detector = contrib.AKAZE_create(threshold=threshold)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def akaze_keypoints(self: Any, gray: np.ndarray, mask: np.ndarray,
                        expected: np.ndarray | None = None) -> tuple[np.ndarray, Any]:
        every, descriptors = self.detector.detectAndCompute(gray, mask)
        if descriptors is None or not every:
            return np.zeros((0, 2)), None
        keep = stereo_features.spread(np.array([k.response for k in every]),
                                      np.array([k.pt for k in every]), gray.shape[::-1],
                                      self.settings.features, expected)
        return np.array([every[i].pt for i in keep], float).reshape(-1, 2), descriptors[keep]

    stereo_features.FeatureFinder.__init__ = akaze_init  # type: ignore[method-assign]
    stereo_features.FeatureFinder.keypoints = akaze_keypoints  # type: ignore[method-assign]
    stereo_features.DESCRIPTOR_MAX["orb"] = most_bits
    try:
        yield
    finally:
        stereo_features.FeatureFinder.__init__ = init  # type: ignore[method-assign]
        stereo_features.FeatureFinder.keypoints = keypoints  # type: ignore[method-assign]
        stereo_features.DESCRIPTOR_MAX["orb"] = limit


def one_seed(job: tuple[str, int]) -> list[dict[str, Any]]:
    from taskcam.sim.config.scenario import load_scenario
    from taskcam.sim.stages.episode import Episode

    variant, seed = job
    scenario = load_scenario(seed=seed)
    scenario = dataclasses.replace(scenario, correction=dataclasses.replace(
        scenario.correction, **VARIANTS[variant]))
    with akaze() if variant == "akaze" else contextlib.nullcontext():
        episode = Episode(scenario)
        start = time.perf_counter()
        summary, _ = episode.run()
        elapsed = time.perf_counter() - start
    rows = []
    for robot in summary["robots"]:  # the move to each robot's first placement
        c = robot["placements"][0].get("correction")
        if c is not None:
            errors = {"before": c["error_before"], "bundle": c.get("bundle_error"),
                      c.get("estimator", "estimator"): c.get("error_after"),
                      **c["other_estimators_error"]}
            rows.append({"variant": variant, "seed": seed, "robot": robot["name"],
                         "status": c.get("status"), "sd": c.get("sd"),
                         "frames": c["frames"], "located": c["frames_located"],
                         "failed": c.get("failed"), "errors": errors,
                         "seconds": c.get("timings_s", {}), "episode_s": elapsed,
                         "frames_by_kind": c.get("frames_by_kind", {})})
    return rows


def report(variant: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Prints one variant's accuracy and time per move; returns its summary."""
    print(f"\n{variant}: {len(rows)} moves")
    print(f"{'pose':<10} {'median mm':>10} {'median deg':>11} {'worst mm':>9} {'worst deg':>10}"
          f" {'within 3 mm & 0.2 deg':>22}")
    out: dict[str, Any] = {}
    for name in ("before", "linear", "kabsch", "sqpnp", "bundle"):
        found = [r["errors"].get(name) for r in rows]
        pairs = np.array([(e["position_m"], e["orientation_deg"]) if e else (np.inf, np.inf)
                          for e in found])
        ok = int(np.sum((pairs[:, 0] <= TARGET_M) & (pairs[:, 1] <= TARGET_DEG)))
        med, worst = np.median(pairs, axis=0), pairs.max(axis=0)
        out[name] = {"median_mm": 1e3 * med[0], "median_deg": med[1],
                     "worst_mm": 1e3 * worst[0], "worst_deg": worst[1], "within": ok}
        print(f"{name:<10} {1e3 * med[0]:>10.2f} {med[1]:>11.3f} {1e3 * worst[0]:>9.2f} "
              f"{worst[1]:>10.3f} {ok:>14} of {len(rows)}")
    seconds = {k: float(np.mean([r["seconds"].get(k, 0.0) for r in rows])) for k in BUDGET_S}
    out["seconds_per_move"] = sum(seconds.values())
    out["parts_s"] = seconds
    print(f"per move: {out['seconds_per_move']:.2f} s (frames "
          f"{np.median([r['frames'] for r in rows]):.0f} median, "
          f"{sum(r['located'] for r in rows)} of {sum(r['frames'] for r in rows)} located)")
    print("  part      mean s  budget s")
    for k, v in seconds.items():
        print(f"  {k:<9} {v:>6.2f} {BUDGET_S[k]:>9.2f}{'  over' if v > BUDGET_S[k] else ''}")
    out["frames_by_kind"] = by_kind(rows)
    if "track" in out["frames_by_kind"]:
        rest = out["seconds_per_move"] - out["frames_by_kind"]["track"]["s_per_move"]
        out["without_track_frames_s"] = rest
        print(f"  a move with its track frames free: {rest:.2f} s (budget "
              f"{sum(BUDGET_S.values()):.2f})")
    ratios = [(e["position_m"] / r["sd"]["position_m"], e["orientation_deg"] / r["sd"][
        "orientation_deg"]) for r in rows if (e := r["errors"].get("sqpnp"))
        and r["sd"] and r["sd"]["position_m"] > 0 and r["sd"]["orientation_deg"] > 0]
    if ratios:
        p95 = np.percentile(np.array(ratios), 95, axis=0)
        out["error_over_sd_p95"] = p95.tolist()
        print(f"error over the reported sd, 95th percentile: position {p95[0]:.2f}, rotation "
              f"{p95[1]:.2f} (a covariance that holds: 1.61); "
              f"{sum(r['status'] == 'corrected' for r in rows)} of {len(rows)} trusted")
    for r in rows:
        if r["failed"]:
            print(f"  seed {r['seed']} {r['robot']}: {r['failed']}")
    return out


def by_kind(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Prints and returns a move's frames by why each was taken (first, track, goal
    view, step, final, wider search: the final frame tracked again): frames and wall
    seconds a move (mean), seconds a frame."""
    kinds = dict.fromkeys(k for r in rows for k in r["frames_by_kind"])
    out = {}
    print("  frames    a move  s a move  s a frame")
    for kind in kinds:
        n = float(np.mean([r["frames_by_kind"].get(kind, {}).get("count", 0) for r in rows]))
        s = float(np.mean([r["frames_by_kind"].get(kind, {}).get("time_s", 0.0) for r in rows]))
        each = s / max(n, 1e-9)
        out[kind] = {"frames_per_move": n, "s_per_move": s, "s_per_frame": each}
        print(f"  {kind:<13} {n:>5.1f} {s:>8.2f} {each:>10.3f}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--variants", default="taskcam,baseline",
                        help=f"comma-separated, of {', '.join(VARIANTS)}")
    args = parser.parse_args()
    variants = args.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants {','.join(unknown)}: accepted {', '.join(VARIANTS)}")
    jobs = [(v, s) for v in variants for s in range(args.seeds)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [r for rs in pool.map(one_seed, jobs) for r in rs]
    print(f"the default scenario, seeds 0-{args.seeds - 1}, {args.workers} worker(s)")
    summary = {v: report(v, [r for r in rows if r["variant"] == v]) for v in variants}
    if "baseline" in summary:
        base = summary["baseline"]["seconds_per_move"]
        for v in variants:
            if v != "baseline":
                mine = summary[v]["seconds_per_move"]
                print(f"{v}: {mine:.2f} s per move, baseline {base:.2f} s: "
                      f"{base / max(mine, 1e-9):.1f}x faster")
    write_results("pose_correction", rows, summary=summary)


if __name__ == "__main__":
    main()
