"""View selection: target-region entropy against views taken, per strategy and gain.

Run from the repository root: ``python -m bench.peers.information_gain``. Every strategy maps
the default scene from the same start, with the same seeds (so the same candidate
sampler), with rendered depth; exploration runs to ``--views`` views without stopping
at the threshold, and the number of views each needs to reach it is read off its curve.
Compared with taskcam's cooperative, visibility-weighted entropy gain: one robot
choosing greedily alone; the "unobserved voxel" and "rear side voxel" gains of active
reconstruction work (Delmerico et al., 2018), chosen cooperatively; random views.
Prints one table and writes bench/results/information_gain.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

from bench.common import print_table, write_results
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.stages import ViewGain, ViewStrategy
from taskcam.sim.stages.episode import Episode
from taskcam.sim.world.render import Renderer

STRATEGIES: dict[str, tuple[ViewStrategy, ViewGain]] = {  # name: (strategy, gain)
    "cooperative entropy (taskcam)": ("cooperative", "entropy"),
    "single robot, greedy entropy": ("single", "entropy"),
    "cooperative unobserved voxels": ("cooperative", "unobserved"),
    "cooperative rear side voxels": ("cooperative", "rear_side"),
    "random reachable views": ("random", "entropy"),
}


def curve(strategy: ViewStrategy, gain: ViewGain, seed: int, views: int
          ) -> tuple[list[float], float]:
    s = load_scenario(seed=seed)
    s = dataclasses.replace(s, mapping=dataclasses.replace(
        s.mapping, strategy=strategy, gain=gain, max_views=views, entropy_threshold_bits=0.0))
    episode = Episode(s)
    start = time.perf_counter()
    with Renderer(episode.model, episode.pinhole.width, episode.pinhole.height) as renderer:
        summary = episode.map(renderer)
    return summary["region_entropy_history_bits"], time.perf_counter() - start


def views_to(history: list[float], threshold: float) -> float:
    """Views taken when the entropy first falls below ``threshold`` (inf if never)."""
    return next((i for i, h in enumerate(history) if h < threshold), float("inf"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=14)
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    threshold = load_scenario().mapping.entropy_threshold_bits
    curves: dict[str, list[list[float]]] = {}
    seconds: dict[str, list[float]] = {}
    for name, (strategy, gain) in STRATEGIES.items():
        for seed in range(args.seeds):
            history, took = curve(strategy, gain, seed, args.views)
            curves.setdefault(name, []).append(history)
            seconds.setdefault(name, []).append(took)
    ours = "cooperative entropy (taskcam)"

    def needed(name: str) -> float:
        return statistics.median(views_to(h, threshold) for h in curves[name])

    def entropy_at(name: str, k: int) -> float:
        return statistics.median(h[min(k, len(h) - 1)] for h in curves[name])

    rows = []
    for name in STRATEGIES:
        if name == ours:
            continue
        rows.append({"case": f"views to {threshold} bits vs {name}", "ours": needed(ours),
                     "peer": needed(name), "ratio": needed(name) / needed(ours),
                     "unit": "views (median over seeds)"})
    for k in (2, 4, 6):
        for name in STRATEGIES:
            if name == ours:
                continue
            rows.append({"case": f"entropy after {k} views vs {name}",
                         "ours": entropy_at(ours, k), "peer": entropy_at(name, k),
                         "ratio": entropy_at(name, k) / entropy_at(ours, k),
                         "unit": "bits, region mean"})
    print(f"default scene, rendered depth, {args.seeds} seeds, {args.views} views; "
          f"threshold {threshold} bits")
    print_table(rows)
    print("\nmedian region entropy (bits) after n views:")
    print(f"{'views':<32}" + "".join(f"{k:>7}" for k in range(args.views + 1)))
    for name in STRATEGIES:
        print(f"{name:<32}" + "".join(f"{entropy_at(name, k):7.3f}"
                                      for k in range(args.views + 1)))
    path = write_results("information_gain", rows, threshold_bits=threshold,
                         seeds=args.seeds, views=args.views, curves=curves,
                         seconds={k: statistics.median(v) for k, v in seconds.items()})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
