"""The fiducial tracker's measurements against the simulator's truth, per
tracker variant of bench/studies/pose_correction.py, on the same seeds in one run.

For every located frame of every correction of the default scenario (errors and
correction on): each fiducial's disparity against the one the renderer's depth gives at
its pixel (the stereo error), and its pixel against the projection of the point it was
first seen at (the drift: the point is found from the depth image and the true camera
pose when the fiducial starts). A tracker whose measurements drift from the point they
began at triangulates and locates from a moving target.

    .venv/bin/python -m bench.studies.tracker_truth [--seeds 1] [--variants taskcam,flow]
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import numpy as np

from bench.common import write_results
from bench.studies.pose_correction import VARIANTS


class Truth:
    """Hooks on the corrector and the tracker that measure each located frame against
    the renderer's depth and the true camera pose at its render."""

    def __init__(self) -> None:
        self.reset()
        self.install()

    def reset(self) -> None:
        """Forget what was measured (a new run)."""
        self.stereo: list[float] = []  # |disparity - truth| (px), every observation
        self.drift: list[float] = []  # |pixel - first point's projection| (px)
        self._first: dict[int, np.ndarray] = {}  # fiducial -> world point at first sight
        self._view: tuple[Any, ...] | None = None  # (depth, T world<-camera, camera)

    def install(self) -> None:
        import taskcam.calibration.tracking as tracking
        import taskcam.sim.stages.corrector as corrector
        from taskcam.mapping import opencv_pose
        from taskcam.sim.world.render import camera_pose

        truth = self
        look, begin = corrector.PoseCorrector._look, corrector.PoseCorrector.begin
        add, start = tracking.FiducialTracker._add, tracking.FiducialTracker.start

        def hooked_begin(self: Any, *args: Any, **kwargs: Any) -> Any:
            truth._first = {}
            return begin(self, *args, **kwargs)

        def hooked_look(self: Any, robot: Any, *args: Any, **kwargs: Any) -> Any:
            found = look(self, robot, *args, **kwargs)
            truth._view = (self.renderer.depth(self.world, robot.camera),
                           opencv_pose(camera_pose(self.world, robot.camera)), self.camera)
            return found

        def hooked_add(self: Any, *args: Any, **kwargs: Any) -> Any:
            known = len(self.fiducials)
            frame = add(self, *args, **kwargs)
            if frame.located:
                truth.measure(frame, known)
            return frame

        def hooked_start(self: Any, *args: Any, **kwargs: Any) -> Any:
            frame = start(self, *args, **kwargs)
            truth.measure(frame, 0)
            return frame

        corrector.PoseCorrector.begin = hooked_begin  # type: ignore[method-assign]
        corrector.PoseCorrector._look = hooked_look  # type: ignore[method-assign]
        tracking.FiducialTracker._add = hooked_add  # type: ignore[method-assign]
        tracking.FiducialTracker.start = hooked_start  # type: ignore[method-assign]

    def measure(self, frame: Any, known: int) -> None:
        """A located frame's observations against the truth; fiducials from index
        ``known`` on start here."""
        assert self._view is not None, "a render first"
        depth, T, cam = self._view
        g = np.linalg.inv(T)
        for i, z in frame.observations.items():
            u, v = np.clip(np.rint(z[:2]).astype(int), 0, [depth.shape[1] - 1, depth.shape[0] - 1])
            d = float(depth[v, u])
            if not np.isfinite(d) or d <= 0:
                continue
            self.stereo.append(abs(z[2] - cam.fx * cam.baseline / d))
            if i >= known:
                p = np.array([(z[0] - cam.cx) / cam.fx * d, (z[1] - cam.cy) / cam.fy * d, d])
                self._first[i] = T[:3, :3] @ p + T[:3, 3]
            elif i in self._first:
                c = g[:3, :3] @ self._first[i] + g[:3, 3]
                uv = np.array([cam.fx * c[0] / c[2] + cam.cx, cam.fy * c[1] / c[2] + cam.cy])
                self.drift.append(float(np.linalg.norm(uv - z[:2])))


def one(truth: Truth, variant: str, seed: int) -> dict[str, Any]:
    from taskcam.sim.config.scenario import load_scenario
    from taskcam.sim.stages.episode import Episode

    truth.reset()
    scenario = load_scenario(seed=seed)
    scenario = dataclasses.replace(scenario, correction=dataclasses.replace(
        scenario.correction, **VARIANTS[variant]))
    summary, _ = Episode(scenario).run()
    errors = [r["placements"][0]["correction"].get("error_after") for r in summary["robots"]
              if r["placements"][0].get("correction")]
    return {"variant": variant, "seed": seed, "stereo_px": truth.stereo,
            "drift_px": truth.drift, "error_after_mm": [
                None if e is None else 1e3 * e["position_m"] for e in errors]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--variants", default="taskcam,flow",
                        help=f"comma-separated, of {', '.join(VARIANTS)}")
    args = parser.parse_args()
    variants = args.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants {','.join(unknown)}: accepted {', '.join(VARIANTS)}")
    truth = Truth()
    rows = [one(truth, variant, seed) for seed in range(args.seeds) for variant in variants]
    print(f"the default scenario, seeds 0-{args.seeds - 1}: px, median / 90th percentile")
    print(f"{'variant':<12} {'stereo error':>14} {'drift':>14} {'error after (mm)':>20}")
    summary = {}
    for variant in variants:
        mine = [r for r in rows if r["variant"] == variant]
        stereo = np.concatenate([r["stereo_px"] for r in mine])
        drift = np.concatenate([r["drift_px"] for r in mine])
        after = [e for r in mine for e in r["error_after_mm"] if e is not None]
        summary[variant] = {k: [float(np.median(x)), float(np.percentile(x, 90))]
                            for k, x in (("stereo_px", stereo), ("drift_px", drift))}
        print(f"{variant:<12} {np.median(stereo):>6.3f} / {np.percentile(stereo, 90):.3f} "
              f"{np.median(drift):>6.3f} / {np.percentile(drift, 90):.3f} "
              f"{' '.join(f'{e:.2f}' for e in after):>20}")
    if "taskcam" in summary:
        for variant in variants:
            if variant != "taskcam":
                ratio = summary[variant]["drift_px"][0] / summary["taskcam"]["drift_px"][0]
                print(f"{variant}: median drift {ratio:.2f}x taskcam's")
    for r in rows:  # the per-observation lists are long: the file keeps their summary
        for k in ("stereo_px", "drift_px"):
            x = np.asarray(r.pop(k))
            r[k] = {"count": len(x), "median": float(np.median(x)) if len(x) else None,
                    "p90": float(np.percentile(x, 90)) if len(x) else None}
    write_results("tracker_truth", rows, summary=summary)


if __name__ == "__main__":
    main()
