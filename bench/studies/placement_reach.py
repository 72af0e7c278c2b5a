"""Placement generality: over generated scenes that are hard to reach (far starts, walls
in the way, enclosures open on one side, three kinds of arm: sim/experiments/reach_scenes.py),
the share of robots the default pipeline places among those an oracle run of the same
scene places.

Run from the repository root: ``python -m bench.studies.placement_reach [--scenes 200]
[--workers 2] [--out runs/placement_reach] [--seed 2026]``. Each scene (drawn from
``numpy.random.default_rng([seed, index, attempt])``; a draw the scenario parser or the
scene builder refuses is counted and redrawn, as the soak does) runs twice in a worker
process, as ``taskcam run`` would run it (taskcam.sim.stages.episode.Episode, no recording):

- ``default`` (ours): the scene as drawn, every placement setting at the project's default;
- ``oracle`` (peer): the same scene with ``[search] planner_world = "model"``,
  ``check_sight = true`` and ``ik_candidates = 1000``.

Per robot it records whether each run placed it, the refusal, the candidates tried with
IK (``candidates_tried``) and the planning seconds: the episode timer's ``ik`` stage
(the standing-room test and every goal and path planned for the robot's candidates),
measured per robot as what that stage grew by during the robot's placement (and the
rating search's seconds, the ``placement`` stage, likewise). Each finished scene is
appended to ``--out``/scenes.jsonl at once: a rerun skips the scenes done, and runs
again those that raised (their scenario files are kept in ``--out``/scenes). The
per-robot records are written to ``--out``/robots.jsonl, the summary to
bench/results/placement_reach.json.

Rows (ours: default, peer: oracle): ``placed of placeable (...)``, robots placed by
both runs of those the oracle placed, over all robots and per feature, with a 95 %
interval over scenes (bootstrap, ``ci95``); the oracle's own share of all robots; the
median candidates tried and planning seconds of the robots both runs placed; and the
default run's refusals of robots the oracle placed, by their first clause.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import statistics
import sys
import time
import traceback
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, Future, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import append, done_records, print_table, write_results
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.experiments.reach_scenes import ORACLE, draw_reach_scene, oracle_table
from taskcam.sim.experiments.runner import worker_pool
from taskcam.sim.experiments.soak.draw_scenario import to_toml
from taskcam.sim.experiments.soak.scenes import MAX_DRAWS, discard_reason
from taskcam.sim.stages.episode import Episode

RUNS = ("default", "oracle")
POOL_RESTARTS = 2  # a pool whose worker died is started afresh this often at most
BOOTSTRAP = 2000  # resamples of the scenes for the share's interval
PLACEMENT_LINE = re.compile(r"^(r\d+): (?:placed|not placed)")
# the features the results are broken down by (a robot's own or its scene's)
BY_FEATURE = ("stereo", "render", "far_start", "wall", "enclosure", "taskcam", "ur5e",
              "compact_arm", "robots1", "robots2", "robots3", "robots4")


# ---------------------------------------------------------------- one scene


def run_episode(path: Path) -> dict[str, Any]:
    """Run the scenario file ``path`` in this process as ``taskcam run --no-record``
    does (ScenarioError if the parser or the scene builder refuses it). Returns each
    robot's placement (``robots``, by name), the seconds building the episode's world
    (``build_s``) and running its stages (``run_s``)."""
    start = time.perf_counter()
    episode = Episode(load_scenario(path))
    built = time.perf_counter()
    marks: list[tuple[str | None, dict[str, float]]] = [(None, episode.timer.rounded(6))]

    def progress(line: str) -> None:  # told as each stage ends: the timer then
        found = PLACEMENT_LINE.match(line)
        marks.append((found.group(1) if found else None, episode.timer.rounded(6)))

    summary, _ = episode.run(progress=progress)
    grew: dict[str, dict[str, float]] = {}
    for (_, before), (name, after) in itertools.pairwise(marks):
        if name is not None:
            grew[name] = {k: after.get(k, 0.0) - before.get(k, 0.0) for k in ("ik", "placement")}
    robots = {r["name"]: robot_record(r, grew.get(r["name"], {})) for r in summary["robots"]}
    return {"robots": robots, "build_s": round(built - start, 3),
            "run_s": round(time.perf_counter() - built, 3),
            "mapping_views": summary["mapping"].get("views")}


def robot_record(r: dict[str, Any], grew: dict[str, float]) -> dict[str, Any]:
    """One robot's outcome from its ``summary.json`` record (its search's counts kept as
    the pipeline reports them, under ``search``) and what the timer's stages grew by
    during its placement (s)."""
    path = r.get("path") or {}
    return {"placed": bool(r["placed"]), "refused": r.get("refused", ""),
            "candidates_tried": r["candidates_tried"], "rejections": r.get("rejections", {}),
            "search": r.get("search", {}),
            "planning_s": round(grew.get("ik", float("nan")), 4),
            "search_s": round(grew.get("placement", float("nan")), 4),
            "taken_plan_s": path.get("time_s")}


def run_scene(index: int, seed: int, workdir: Path) -> dict[str, Any]:
    """Draw scene ``index`` (redrawing what is refused), run it by default and as the
    oracle, and return its record: features, and per robot both runs' outcomes."""
    workdir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"index": index, "seed": seed, "discards": [], "error": None,
                              "robots": []}
    start = time.perf_counter()
    for attempt in range(MAX_DRAWS):
        scene = draw_reach_scene(np.random.default_rng([seed, index, attempt]),
                                 f"reach{index:04d}")
        paths = {run: workdir / f"reach{index:04d}_{run}.toml" for run in RUNS}
        paths["default"].write_text(to_toml(scene.table))
        paths["oracle"].write_text(to_toml(oracle_table(scene.table)))
        try:
            runs = {run: run_episode(paths[run]) for run in RUNS}
        except ScenarioError as exc:
            record["discards"].append({"reason": discard_reason(f"taskcam: error: {exc}"),
                                       "message": str(exc)[:300]})
            continue
        except Exception:
            record.update(attempt=attempt, error=traceback.format_exc()[-4000:],
                          features=list(scene.features))
            break
        record.update(attempt=attempt, features=list(scene.features), layout=scene.layout,
                      seconds_by_run={run: {k: runs[run][k] for k in ("build_s", "run_s")}
                                      for run in RUNS})
        for i, name in enumerate(f"r{k + 1}" for k in range(len(scene.robot_features))):
            record["robots"].append({
                "name": name, "features": list(scene.features_of(i)),
                "start_distance_m": scene.start_distances_m[i],
                **{run: runs[run]["robots"][name] for run in RUNS}})
        break
    if record["error"] is None:  # a failing scene keeps its files to reproduce it
        for path in workdir.glob(f"reach{index:04d}_*.toml"):
            path.unlink()
    record["seconds"] = round(time.perf_counter() - start, 3)
    return record


def run_scenes(indices: list[int], seed: int, workdir: Path, workers: int
               ) -> Iterator[dict[str, Any]]:
    """The scenes' records as they finish, on ``workers`` worker processes; a pool whose
    worker died is started afresh (POOL_RESTARTS times at most) for the scenes left."""
    left = list(indices)
    for restart in range(POOL_RESTARTS + 1):
        try:
            for record in _on_pool(left, seed, workdir, workers):
                left.remove(record["index"])
                yield record
            return
        except BrokenProcessPool as exc:
            if restart == POOL_RESTARTS:
                raise RuntimeError(f"a worker process died {restart + 1} times ({exc}); "
                                   f"{len(left)} scene(s) not run: run again to resume") from exc
            print(f"a worker process died ({exc}); {len(left)} scene(s) go to a fresh pool",
                  file=sys.stderr, flush=True)


def _on_pool(indices: list[int], seed: int, workdir: Path, workers: int
             ) -> Iterator[dict[str, Any]]:
    with worker_pool(workers) as pool:
        queue = iter(list(indices))  # the caller strikes off the scenes done
        pending: set[Future[dict[str, Any]]] = set()

        def submit() -> None:
            index = next(queue, None)
            if index is not None:
                pending.add(pool.submit(run_scene, index, seed, workdir))

        for _ in range(2 * workers):  # a few scenes queued per worker, not all of them
            submit()
        try:
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    pending.discard(future)
                    yield future.result()
                    submit()
        finally:
            for future in pending:
                future.cancel()


# ---------------------------------------------------------------- the results


def robots_of(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every robot of the scenes that ran both ways, with its scene's index."""
    return [{"scene": r["index"], **robot} for r in records if r.get("error") is None
            for robot in r["robots"]]


def share_row(case: str, robots: list[dict[str, Any]]) -> dict[str, Any]:
    """``placed of placeable``: robots placed by both runs (ours) of those the oracle
    placed (peer)."""
    placeable = sum(r["oracle"]["placed"] for r in robots)
    both = sum(r["oracle"]["placed"] and r["default"]["placed"] for r in robots)
    return {"case": case, "ours": both, "peer": placeable,
            "ratio": both / placeable if placeable else None, "unit": "robots",
            "robots": len(robots),
            "default_only": sum(r["default"]["placed"] and not r["oracle"]["placed"]
                                for r in robots)}


def bootstrap_share(robots: list[dict[str, Any]], rng: np.random.Generator,
                    reps: int = BOOTSTRAP) -> list[float] | None:
    """A 95 % interval of the share (placed by both / placed by the oracle), the scenes
    resampled with replacement; None without a placeable robot."""
    scenes: dict[int, list[int]] = {}
    for r in robots:
        counts = scenes.setdefault(r["scene"], [0, 0])
        counts[0] += bool(r["oracle"]["placed"] and r["default"]["placed"])
        counts[1] += bool(r["oracle"]["placed"])
    if not scenes or sum(c[1] for c in scenes.values()) == 0:
        return None
    table = np.array(list(scenes.values()), float)
    picks = rng.integers(0, len(table), size=(reps, len(table)))
    both, placeable = table[picks, 0].sum(axis=1), table[picks, 1].sum(axis=1)
    shares = both[placeable > 0] / placeable[placeable > 0]
    lo, hi = np.percentile(shares, [2.5, 97.5])
    return [round(float(lo), 4), round(float(hi), 4)]


def paired_row(case: str, robots: list[dict[str, Any]], key: str, unit: str
               ) -> dict[str, Any]:
    """The median of a robot's ``key`` in each run over the robots both runs placed
    (their means as extra fields)."""
    both = [r for r in robots if r["default"]["placed"] and r["oracle"]["placed"]
            and r["default"][key] is not None and r["oracle"][key] is not None]
    if not both:
        return {"case": case, "ours": None, "peer": None, "ratio": None, "unit": unit,
                "robots": 0}
    ours = statistics.median(r["default"][key] for r in both)
    peer = statistics.median(r["oracle"][key] for r in both)
    return {"case": case, "ours": ours, "peer": peer, "ratio": ours / peer if peer else None,
            "unit": unit, "robots": len(both),
            "mean_ours": statistics.fmean(r["default"][key] for r in both),
            "mean_peer": statistics.fmean(r["oracle"][key] for r in both)}


def first_clause(text: str) -> str:
    """A refusal's reason without its counts: up to its first parenthesis or semicolon."""
    return re.split(r" \(|;", text, maxsplit=1)[0].strip() or "(no reason given)"


def refusals(robots: list[dict[str, Any]]) -> tuple[Counter[str], Counter[str]]:
    """For the robots the oracle placed and the default run did not: the default run's
    refusals (first clause) and its rejections of the candidates it tried, by why."""
    reasons: Counter[str] = Counter()
    rejections: Counter[str] = Counter()
    for r in robots:
        if r["oracle"]["placed"] and not r["default"]["placed"]:
            reasons[first_clause(r["default"]["refused"])] += 1
            rejections.update(r["default"]["rejections"])
    return reasons, rejections


def summarise(records: list[dict[str, Any]], seed: int) -> tuple[list[dict[str, Any]],
                                                                   dict[str, Any]]:
    """The results' rows and their extra fields."""
    robots = robots_of(records)
    rng = np.random.default_rng([seed, 1])
    rows = []
    for case, subset in [("all robots", robots)] + [
            (f, [r for r in robots if f in r["features"]]) for f in BY_FEATURE]:
        row = share_row(f"placed of placeable ({case})", subset)
        row["ci95"] = bootstrap_share(subset, rng)
        rows.append(row)
    placed = sum(r["oracle"]["placed"] for r in robots)
    rows.append({"case": "oracle's own share", "ours": None, "peer": placed,
                 "ratio": placed / len(robots) if robots else None, "unit": "robots",
                 "robots": len(robots)})
    rows.append(paired_row("IK attempts per placed robot (median)", robots,
                           "candidates_tried", "candidates"))
    rows.append(paired_row("planning s per placed robot (median)", robots, "planning_s", "s"))
    reasons, rejections = refusals(robots)
    rows += [{"case": f"refused by default, oracle placed: {k}", "ours": v, "peer": None,
              "ratio": None, "unit": "robots"} for k, v in reasons.most_common()]
    failed = [r["index"] for r in records if r.get("error") is not None]
    extra = {"scenes": len(records), "scenes_failed": failed, "robots": len(robots),
             "discarded_draws": dict(Counter(d["reason"] for r in records
                                             for d in r["discards"])),
             "default_refusals_oracle_placed": dict(reasons),
             "default_rejections_oracle_placed": dict(rejections),
             "seconds_per_scene_median": (statistics.median(r["seconds"] for r in records)
                                          if records else None)}
    return rows, extra


# ---------------------------------------------------------------- the command


def write_robots(path: Path, records: list[dict[str, Any]]) -> None:
    """One JSON line per robot of the scenes that ran."""
    path.write_text("".join(json.dumps(r) + "\n" for r in robots_of(records)))


def progress_line(n: int, total: int, record: dict[str, Any]) -> str:
    """A finished scene, in a line: its robots placed by each run."""
    robots = record["robots"]
    placed = {run: sum(r[run]["placed"] for r in robots) for run in RUNS}
    what = ("error" if record.get("error") else f"{len(robots)} robot(s), placed default "
            f"{placed['default']} / oracle {placed['oracle']}")
    return f"[{n}/{total}] scene {record['index']} {record['seconds']:.1f} s: {what}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=200, help="scenes 0 .. N-1")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--seed", type=int, default=2026, help="master seed of the draws")
    parser.add_argument("--out", type=Path, default=Path("runs/placement_reach"),
                        help="scenes.jsonl, robots.jsonl and the files of failed scenes")
    args = parser.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    jsonl = args.out / "scenes.jsonl"
    records = done_records(jsonl)
    if any(r.get("seed") != args.seed for r in records.values()):
        sys.exit(f"{jsonl} holds scenes of another --seed; use another --out")
    # a scene that raised runs again (the pipeline may have been mended since)
    todo = [i for i in range(args.scenes) if i not in records or records[i].get("error")]
    print(f"placement_reach: {len(records)} of {args.scenes} scenes already in {jsonl}; "
          f"running {len(todo)} on {args.workers} worker(s)", flush=True)
    start = time.perf_counter()
    for n, record in enumerate(run_scenes(todo, args.seed, args.out / "scenes", args.workers), 1):
        append(jsonl, record)
        records[record["index"]] = record
        print(progress_line(n, len(todo), record), flush=True)
    wall = time.perf_counter() - start

    chosen = [records[i] for i in range(args.scenes) if i in records]
    write_robots(args.out / "robots.jsonl", chosen)
    rows, extra = summarise(chosen, args.seed)
    print_table(rows)
    command = (f"python -m bench.studies.placement_reach --scenes {args.scenes} --workers "
               f"{args.workers} --seed {args.seed}")
    path = write_results("placement_reach", rows, command=command, oracle=ORACLE,
                         scenes_requested=args.scenes, workers=args.workers,
                         wall_s_this_call=round(wall, 1), **extra)
    print(f"wrote {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")


if __name__ == "__main__":
    main()
