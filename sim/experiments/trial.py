"""One paired trial of a sweep: a random scene at an occlusion density, mapped once, and
every placement method run on it from the same start.

1. Obstacles are generated around the primary target until the requested occlusion
   density is reached (sim/experiments/generate.py); the density achieved is recorded.
2. The robots map the scene once (the episode's mapping stage).
3. Each method starts from the mapped state (the robots where mapping left them, the
   same map) with its own random stream, seeded by the trial and the method's name, so
   that its outcome does not depend on the other methods or their order. It places the
   cameras by its placement method (with the secondary targets or without), both given
   to the stages as arguments, and the task is run with them. The methods' searches
   share one rating problem over the map.

The result is plain data (JSON types), one record per trial with one per method.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import resource
import time
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.config.scenario import Scenario
from sim.config.sweep import MethodConfig
from sim.experiments.generate import generate, keep_outs
from sim.stages.episode import place_look_do
from sim.stages.exploration import explore
from sim.stages.rating_problem import RatingProblem
from sim.stages.timer import Timer
from sim.stages.world import build_world
from sim.world.render import Renderer
from sim.world.scene import build_scene


@dataclass(frozen=True)
class TrialSpec:
    """Everything one trial needs (sent to whichever worker runs it)."""

    scenario: Scenario  # the sweep's base scenario
    methods: tuple[MethodConfig, ...]
    density_index: int
    density: float  # requested
    trial: int
    seed: int


@functools.lru_cache(maxsize=4)
def _primary(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The primary target's position and normal in a scenario's scene (m)."""
    target = build_scene(dataclasses.replace(scenario, obstacles=())).primary
    return target.position, target.normal


def trial_scenario(spec: TrialSpec) -> tuple[Scenario, float]:
    """The trial's scenario, with obstacles generated at the requested density, and the
    density achieved."""
    s = spec.scenario
    position, normal = _primary(s)
    obstacles, achieved = generate(spec.density, position, normal, s.camera.far_m,
                                   keep_outs(s), np.random.default_rng([spec.seed, 0]))
    return dataclasses.replace(s, obstacles=obstacles, seed=spec.seed), achieved


def method_rng(seed: int, method: MethodConfig) -> np.random.Generator:
    """A method's own stream: the same for the same trial, whatever else runs."""
    return np.random.default_rng([seed, 1, zlib.crc32(method.name.encode())])


def _outcome(method: MethodConfig, robots: list[dict[str, Any]], frame: dict[str, Any],
             task: dict[str, Any] | None, seconds: float) -> dict[str, Any]:
    task = task or {}
    return {
        "method": method.name, "placement": method.placement, "secondary": method.secondary,
        "success": task.get("success", {}),
        "attempted": task.get("attempted"),
        "frame_robots": task.get("target_frame", {}).get("robots", []),
        "final_displacement_m": task.get("final_displacement_m"),
        "steps": task.get("steps"), "measurements": task.get("measurements"),
        "failed_measurements": task.get("failed_measurements"),
        "replacements": len(task.get("replacements", [])),
        "failures": task.get("failures", [])[:3],  # the first failed measurements, why
        "stopped_by": task.get("stopped_by"),
        "targets_measured": sorted(frame.get("targets", {})),
        "robots": [{"name": r["name"], "placed": r["placed"], "seen": r["seen"],
                    "target": r.get("target", {}).get("name"),
                    "rating": r.get("rating", {}),
                    "position": r["pose"]["position"],
                    # physics steps in contact over the robot's moves (none is the rule)
                    "contact_steps": sum((p.get("motion") or {}).get("contact_steps", 0)
                                         for p in r.get("placements", []))} for r in robots],
        "time_s": round(seconds, 3),
    }


def run_trial(spec: TrialSpec) -> dict[str, Any]:
    """Generate, map once, run every method; the trial's record."""
    start = time.perf_counter()
    scenario, achieved = trial_scenario(spec)
    timer = Timer()
    world = build_world(scenario, timer)
    scene = world.scene
    outcomes = []
    with Renderer(world.model, world.pinhole.width, world.pinhole.height) as renderer:
        mapping = explore(world, renderer)
        world.hold()
        mapped = world.snapshot()
        problem = RatingProblem(world.grid, scenario)  # the methods' searches share it
        for method in spec.methods:
            began = time.perf_counter()
            run = world.restored(mapped, method_rng(spec.seed, method))
            targets = scene.targets if method.secondary else (scene.primary,)
            outcome = place_look_do(run, renderer, problem, method.placement, targets)
            outcomes.append(_outcome(method, outcome.robots(run), outcome.frame, outcome.task,
                                     time.perf_counter() - began))
        render_s = renderer.seconds
    timings = timer.rounded(3)
    timings["rendering"] = round(render_s, 3)  # within the stages above
    timings["total"] = round(time.perf_counter() - start, 3)
    return {
        "density_index": spec.density_index, "trial": spec.trial, "seed": spec.seed,
        "density": spec.density, "achieved_density": round(achieved, 6),
        "obstacles": len(scenario.obstacles),
        "workpiece_error": world.workpiece_error.round(6).tolist(),
        "mapping": {"views": mapping.views_total,
                    "region_entropy_bits": mapping.region_entropy_history_bits[-1],
                    "region_known_fraction": mapping.region_known_fraction},
        "methods": outcomes,
        "timings_s": timings,
        "worker": {"pid": os.getpid(),  # and its peak memory so far (MiB)
                   "max_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                                        1)},
    }
