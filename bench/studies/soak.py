"""A soak of unfamiliar scenes: random valid scenarios, each run as ``taskcam run FILE
--out DIR`` runs it and its run directory audited (sim/experiments/soak/scenes.py,
sim/experiments/soak/audit.py).

Run from the repository root: ``python -m bench.studies.soak`` (500 scenes, every tenth with the
pose correction and the task on, on 2 worker processes). Each finished scene is
appended to ``--out``/scenes.jsonl as one JSON line at once, so a killed soak loses
nothing finished and a rerun skips the scenes done. A scene with findings keeps its
scenario file and run directory under ``--out`` to reproduce it.

Prints the counts of each outcome and writes bench/results/soak.json and the table of
docs/soak.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from bench.common import ROOT, append, done_records, write_results
from taskcam.sim.experiments.soak.draw_scenario import is_heavy
from taskcam.sim.experiments.soak.scenes import Job, run_scenes, tally

DOCS = ROOT / "docs" / "soak.md"
BEGIN, END = "<!-- soak table: written by bench/studies/soak.py -->", "<!-- end of soak table -->"


def table(result: dict[str, Any], command: str) -> str:
    """The Markdown table of a soak's outcomes."""
    c = result["counts"]
    rows = [("scenes run", c.get("scenes", 0)),
            ("of them with correction and task on", c.get("heavy_scenes", 0)),
            ("draws discarded as invalid input", sum(result["discarded_draws"].values()))]
    rows += [(f"&nbsp;&nbsp;key `{k}`", v) for k, v in sorted(result["discarded_draws"].items())]
    rows += [("robots", c.get("robots", 0)),
             ("robots placed at the end", c.get("robots_placed", 0)),
             ("robots refused (by the reason of their last placement)",
              c.get("robots_refused", 0))]
    rows += [(f"&nbsp;&nbsp;{k}", v) for k, v in sorted(result["refused_robots"].items(),
                                                        key=lambda kv: -kv[1])]
    rows += [("placements (first and re-placements)", c.get("placements", 0)),
             ("re-placements during the task", c.get("replacements", 0)),
             ("placements refused", sum(result["refused_placements"].values()))]
    rows += [("corrections trusted (`corrected`)", c.get("corrections_corrected", 0)),
             ("corrections reported `uncertain`", c.get("corrections_uncertain", 0)),
             ("corrections reported `failed`", c.get("corrections_failed", 0)),
             ("poses checked against scene.xml", c.get("poses_checked", 0)),
             ("stereo sightings checked", c.get("sightings_checked", 0)),
             ("detections (`seen`) checked", c.get("seen_checked", 0)),
             ("tracebacks", c.get("tracebacks", 0)),
             ("scenes with findings", c.get("scenes_with_findings", 0))]
    rows += [(f"&nbsp;&nbsp;findings `{k}`", v) for k, v in sorted(result["findings"].items())]
    lines = [f"`{command}`", "", "| outcome | count |", "|---|---:|"]
    lines += [f"| {k} | {v} |" for k, v in rows]
    times = result["run_seconds"]
    lines += ["", "| scenes | run | median s | max s | total s |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {k} | {t['scenes']} | {t['median_s']} | {t['max_s']} | {t['total_s']} |"
              for k, t in times.items()]
    return "\n".join(lines) + "\n"


def write_docs(path: Path, text: str) -> None:
    """Replace the table between the markers of ``path`` (appended if there are none)."""
    old = path.read_text() if path.exists() else "# Soak of unfamiliar scenes\n"
    section = f"{BEGIN}\n{text}{END}"
    if BEGIN in old and END in old:
        new = old[:old.index(BEGIN)] + section + old[old.index(END) + len(END):]
    else:
        new = old.rstrip() + "\n\n" + section + "\n"
    path.write_text(new)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=500, help="scenes 0 .. N-1")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--seed", type=int, default=0, help="master seed of the draws")
    parser.add_argument("--out", type=Path, default=Path("runs/soak"),
                        help="scenes.jsonl and the run directories of scenes with findings")
    parser.add_argument("--timeout", type=float, default=1800.0, help="s per scene")
    parser.add_argument("--results", type=Path, default=None,
                        help="results JSON (default bench/results/soak.json)")
    parser.add_argument("--docs", type=Path, default=DOCS, help="Markdown file for the table")
    args = parser.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    jsonl = args.out / "scenes.jsonl"
    records = done_records(jsonl)
    stale = [r for r in records.values() if r.get("master_seed", args.seed) != args.seed]
    if stale:
        sys.exit(f"{jsonl} holds scenes of another --seed; use another --out")
    todo: list[Job] = [(i, None) for i in range(args.scenes) if i not in records]
    print(f"soak: {len(records)} of {args.scenes} scenes already in {jsonl}; running "
          f"{len(todo)} on {args.workers} worker(s)", flush=True)
    start = time.perf_counter()
    for n, record in enumerate(run_scenes(todo, args.out, args.workers, args.seed,
                                          timeout_s=args.timeout), 1):
        append(jsonl, record)
        records[record["index"]] = record
        kinds = sorted({f["kind"] for f in record["findings"]})
        print(f"[{n}/{len(todo)}] scene {record['index']} "
              f"{'heavy' if record.get('heavy') else 'light'} {record['seconds']:.1f} s"
              f"{' findings: ' + ', '.join(kinds) if kinds else ''}", flush=True)
    wall = time.perf_counter() - start

    chosen = [records[i] for i in range(args.scenes) if i in records]
    result = tally(chosen)
    heavy = sum(is_heavy(i) for i in range(args.scenes))
    command = (f"python -m bench.studies.soak --scenes {args.scenes} --workers {args.workers}"
               f"{'' if args.seed == 0 else f' --seed {args.seed}'}")
    text = table(result, command)
    print(text)
    seconds = [r["seconds"] for r in chosen]
    rows = [{"case": f"{k}: {v}", "ours": v, "peer": None, "ratio": None, "unit": "count"}
            for k, v in result["counts"].items()]
    if seconds:
        rows.append({"case": "seconds per scene (median, a worker's)", "ours":
                     statistics.median(seconds), "peer": None, "ratio": None, "unit": "s"})
    write_results(
        "soak", rows, to=args.results, command=command, scenes_requested=args.scenes,
        heavy_requested=heavy, workers=args.workers, wall_s_this_call=round(wall, 1),
        **result, finding_scenes=[
            {"index": r["index"], "kinds": sorted({f["kind"] for f in r["findings"]}),
             "first": r["findings"][0]["message"][:300]}
            for r in chosen if r["findings"]])
    write_docs(args.docs, text)


if __name__ == "__main__":
    main()
