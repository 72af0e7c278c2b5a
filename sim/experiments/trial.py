"""One paired trial of a sweep: a random scene at an occlusion density, mapped once, and
every placement method run on it from the same start.

1. Obstacles are generated about the slot until the requested occlusion density holds
   from the depth of field's near limit to its far limit (sim/experiments/generate.py);
   the density achieved at each radius, and the density each placed camera faces (the
   share blocked within its distance of the slot), are recorded.
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
import signal
import time
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from taskcam.sim.config.scenario import Scenario
from taskcam.sim.config.sweep import MethodConfig
from taskcam.sim.experiments.generate import Clutter, scenario_clutter
from taskcam.sim.stages.episode import place_look_do
from taskcam.sim.stages.exploration import explore
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.stages.timer import Timer
from taskcam.sim.stages.world import build_world
from taskcam.sim.world.render import Renderer


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
def trial_scenario(spec: TrialSpec) -> tuple[Scenario, Clutter]:
    """The trial's scenario, with obstacles generated at the requested density, and the
    clutter's record (density achieved, each elevation band's share)."""
    s = spec.scenario
    clutter = scenario_clutter(s, spec.density, np.random.default_rng([spec.seed, 0]))
    return dataclasses.replace(s, obstacles=clutter.obstacles, seed=spec.seed), clutter


def method_rng(seed: int, method: MethodConfig) -> np.random.Generator:
    """A method's own stream: the same for the same trial, whatever else runs."""
    return np.random.default_rng([seed, 1, zlib.crc32(method.name.encode())])


def task_rng(seed: int) -> np.random.Generator:
    """The task's noise in a trial: one stream every method starts afresh from (common
    random numbers), so that paired methods differ by their placement alone."""
    return np.random.default_rng([seed, 2])


def _method_record(method: MethodConfig, robots: list[dict[str, Any]], frame: dict[str, Any],
                   task: dict[str, Any] | None, seconds: float, clutter: Clutter
                   ) -> dict[str, Any]:
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
                    # how far from the slot it stands (m), and the share of directions
                    # blocked within that distance: the density this camera faces
                    **({"slot_distance_m": round(float(np.linalg.norm(
                        np.asarray(r["pose"]["position"]) - clutter.origin)), 4),
                        "faced_density": round(clutter.faced(r["pose"]["position"]), 6)}
                       if r["placed"] else {}),
                    # physics steps in contact over the robot's moves (none is the rule)
                    "contact_steps": sum((p.get("motion") or {}).get("contact_steps", 0)
                                         for p in r.get("placements", [])),
                    "corrections": [_correction(p["correction"]) for p in r.get("placements", [])
                                    if p.get("correction")]} for r in robots],
        "time_s": round(seconds, 3),
    }


def _correction(c: dict[str, Any]) -> dict[str, Any]:
    """One move's pose correction, briefly: its status, and the camera's error against the
    simulator's truth before (the commanded pose) and after (none if it failed)."""
    return {"status": c["status"], "frames": c["frames"], "frames_located": c["frames_located"],
            "error_before": c["error_before"], "error_after": c.get("error_after"),
            "sd": c.get("sd")}


# For tests of crash handling only: set to "DENSITY_INDEX,TRIAL" (e.g. "1,0"), the process
# that runs that trial kills itself with SIGSEGV, as a native crash would. Unset: inert.
CRASH_TRIAL_ENV = "TASKCAM_TEST_CRASH_TRIAL"


def run_trial(spec: TrialSpec) -> dict[str, Any]:
    """Generate, map once, run every method; the trial's record. An error names the
    trial (density, index, seed), so that it can be run again alone."""
    if os.environ.get(CRASH_TRIAL_ENV) == f"{spec.density_index},{spec.trial}":
        os.kill(os.getpid(), signal.SIGSEGV)
    try:
        return _run_trial(spec)
    except Exception as exc:
        exc.add_note(f"in trial {spec.trial} at density {spec.density:g} (density index "
                     f"{spec.density_index}, seed {spec.seed}); the sweep's finished "
                     "trials are stored: --resume continues after a fix")
        raise


def _run_trial(spec: TrialSpec) -> dict[str, Any]:
    start = time.perf_counter()
    scenario, clutter = trial_scenario(spec)
    timer = Timer()
    world = build_world(scenario, timer)
    outcomes = []
    with Renderer(world.model, world.pinhole.width, world.pinhole.height) as renderer:
        mapping = explore(world, renderer)
        world.hold()
        mapped = world.snapshot()
        problem = RatingProblem(world.grid, scenario)  # the methods' searches share it
        for method in spec.methods:
            began = time.perf_counter()
            run = world.restored(mapped, method_rng(spec.seed, method), task_rng(spec.seed))
            outcome = place_look_do(run, renderer, problem, method.placement, method.secondary)
            outcomes.append(_method_record(method, outcome.robots(run), outcome.frame,
                                           outcome.task, time.perf_counter() - began, clutter))
        render_s = renderer.seconds
    timings = timer.rounded(3)
    timings["rendering"] = round(render_s, 3)  # within the stages above
    timings["total"] = round(time.perf_counter() - start, 3)
    return {
        "density_index": spec.density_index, "trial": spec.trial, "seed": spec.seed,
        "density": spec.density, "achieved_density": round(clutter.density, 6),
        # the blocked share of each 10 deg elevation band, 10-20 deg first
        "blocked_by_elevation": clutter.band_shares.round(4).tolist(),
        # [radius (m), blocked share within it]: the depth of field's near limit, 0.6,
        # 0.8 and 1.0 m, and its far limit (the density above is the last)
        "density_by_radius": clutter.by_radius(),
        "obstacles": len(scenario.obstacles),
        "workpiece_error": world.workpiece_error.round(6).tolist(),
        "secondary_errors": world.secondary_errors,
        "mapping": {"views": mapping.views_total,
                    "region_entropy_bits": mapping.region_entropy_history_bits[-1],
                    "region_known_fraction": mapping.region_known_fraction},
        "methods": outcomes,
        "timings_s": timings,
        "worker": {"pid": os.getpid(),  # and its peak memory so far (MiB)
                   "max_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                                        1)},
    }
