"""The ``taskcam`` command line. Exit codes: 0 success, 2 invalid input, 1 other failure."""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.config.schema import ScenarioError
from taskcam.sim.determinism import is_command, pin
from taskcam.sim.experiments.results import ResultsError
from taskcam.sim.output_paths import check_directory, check_file
from taskcam.sim.run_screen import run_screen
from taskcam.sim.screen import Screen
from taskcam.sim.world.gl import resolve_gl_backend

EXIT_OK, EXIT_FAILURE, EXIT_INVALID = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_INVALID, f"taskcam: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="taskcam", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    run = sub.add_parser("run", help="run one episode and write its run directory")
    run.add_argument("scenario", nargs="?", type=Path,
                     help="scenario TOML file (default: scenarios/default.toml)")
    run.add_argument("--seed", type=int, help="override the scenario's seed")
    run.add_argument("--out", type=Path,
                     help="run directory (default: runs/<scenario>-seed<N>)")
    run.add_argument("--no-record", action="store_true", help="skip the rerun recording")
    run.add_argument("--record-unknown", action="store_true",
                     help="record never-observed voxels too (world/grid/unknown)")
    run.add_argument("--video", action="store_true",
                     help="film the episode from the overview's camera (episode.mp4)")
    run.add_argument("--quiet", action="store_true",
                     help="print the outcome table and errors only (no progress while it "
                     "runs)")
    sweep = sub.add_parser("sweep", help="run many paired trials into a results database")
    sweep.add_argument("spec", type=Path, help="sweep TOML file (e.g. scenarios/table1.toml)")
    sweep.add_argument("--db", type=Path, required=True, help="results database (SQLite)")
    sweep.add_argument("--trials", type=int, help="paired scenes per density (default: the file's)")
    sweep.add_argument("--workers", type=int, default=1, help="local worker processes")
    sweep.add_argument("--scheduler", help="address of a Dask distributed scheduler to run on")
    sweep.add_argument("--resume", action="store_true",
                       help="continue the sweep already in --db (finished trials are kept)")
    rep = sub.add_parser("report", help="Table 1 from a results database")
    rep.add_argument("db", type=Path, help="results database written by taskcam sweep")
    rep.add_argument("--out", type=Path,
                     help="directory for <db>.md, .csv, .png (default: beside the database)")
    cmp = sub.add_parser("compare", help="two sweeps of the same scenes, cell by cell: the "
                         "paired difference in success")
    cmp.add_argument("first", type=Path, help="results database (e.g. with correction on)")
    cmp.add_argument("second", type=Path, help="results database of the same scenes")
    cmp.add_argument("--out", type=Path, help="write the comparison to this Markdown file")
    fig = sub.add_parser("figure7", help="the paper's Figure 7: RF over a planar world")
    fig.add_argument("--out", type=Path, default=Path("runs/figure7"),
                     help="directory for figure7_a.png, figure7_b.png, figure7.json")
    return parser


def _log(message: str) -> None:
    print(f"taskcam: {message}", file=sys.stderr, flush=True)


def run_files(record: bool, video: bool) -> list[str]:
    """The files ``taskcam run`` writes into its run directory (and ``textures/``)."""
    return (["summary.json", "scene.xml", "look.xml", "overview.png"]
            + ["run.rrd"] * record + ["episode.mp4"] * video)


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, args.seed)
    out: Path = args.out or Path("runs") / f"{scenario.name}-seed{scenario.seed}"
    check_directory("--out", out, run_files(not args.no_record, args.video), ["textures"])

    resolve_gl_backend()  # this command renders: the GL backend before mujoco loads
    from taskcam.sim.stages.episode import (
        Episode,  # imports mujoco: after the arguments are known good
    )
    from taskcam.sim.stages.run_directory import write_run

    screen = Screen(quiet=args.quiet)  # quiet: the outcome table and errors only
    episode = Episode(scenario)  # builds the scene: the last check of the input
    start = time.perf_counter()
    screen.line(f"scenario '{scenario.name}' ({scenario.source}), seed {scenario.seed}, "
                f"{scenario.robots.count} robot(s)")
    summary = write_run(episode, out, not args.no_record, args.record_unknown, screen.line,
                        args.video, meter=screen.meter)
    screen.line(f"wrote {out}/summary.json, scene.xml, look.xml, overview.png"
                f"{'' if args.no_record else ', run.rrd'}{', episode.mp4' if args.video else ''}"
                f" in {time.perf_counter() - start:.1f} s")
    print(run_screen(summary, None if args.no_record else out / "run.rrd"), end="")
    return EXIT_OK


def sweep(args: argparse.Namespace) -> int:
    from taskcam.sim.config.sweep import load_sweep

    check_file("--db", args.db)
    spec = load_sweep(args.spec, args.trials)
    resolve_gl_backend()  # this command renders: the GL backend before mujoco loads
    from taskcam.sim.world.scene import build_scene  # imports mujoco

    build_scene(spec.scenario)  # the robots' bases clear of the work-piece and each other
    if args.workers < 1:
        raise ScenarioError("--workers", "workers", args.workers, "an integer >= 1")
    from taskcam.sim.experiments.results import Results
    from taskcam.sim.experiments.runner import run_sweep

    if args.db.exists() and args.db.stat().st_size > 0:  # before anything starts
        try:
            with Results(args.db) as results:  # checks the file, writes nothing yet
                refused = results.refusal(spec.describe(), args.resume)
        except ResultsError as exc:
            raise exc.given_as("--db") from None
        if refused is not None:
            raise refused.given_as("--db")
    if args.scheduler:
        from taskcam.sim.experiments.runner import scheduler_problem

        if (problem := scheduler_problem(args.scheduler)) is not None:
            raise ScenarioError("--scheduler", "scheduler", args.scheduler,
                                "the address of a running Dask scheduler whose workers "
                                "started pinned (tcp://HOST:PORT)", problem=problem)
    args.db.parent.mkdir(parents=True, exist_ok=True)
    where = f"scheduler {args.scheduler}" if args.scheduler else f"{args.workers} worker(s)"
    _log(f"sweep '{spec.config.name}' ({args.spec}): {spec.config.trials} scenes x "
         f"{len(spec.config.densities)} densities x {len(spec.config.methods)} methods, on {where}")
    try:
        done = run_sweep(spec, args.db, args.workers, args.scheduler, args.resume)
    except ResultsError as exc:
        raise exc.given_as("--db") from None
    _log(f"{done.ran} trial(s) run in {done.seconds:.0f} s, {done.already} found done, "
         f"{done.failed} failed; {done.already + done.ran} of {done.total} in {args.db}"
         + (" (`taskcam report` lists the failed; --resume runs them again)"
            if done.failed else ""))
    return EXIT_FAILURE if done.failed else EXIT_OK


def report(args: argparse.Namespace) -> int:
    from taskcam.sim.experiments.report_files import write_report as tables

    if not args.db.is_file():
        found = "a directory" if args.db.is_dir() else "no such file"
        raise ResultsError(args.db, found, "a results database file", "<file>")
    stem = args.db.stem  # the tables go to --out, else beside the database
    check_directory("--out" if args.out is not None else "<db>",
                    args.out if args.out is not None else args.db.parent,
                    [f"{stem}.md", f"{stem}.csv", f"{stem}.png", f"{stem}-orderings.md",
                     f"{stem}-orderings.csv"])
    try:
        out = tables(args.db, args.out)  # reads the database only
    except ResultsError as exc:
        raise exc.given_as("<file>") from None
    print(out["markdown"], end="")
    print()
    print(out["orderings"], end="")
    _log("wrote " + ", ".join(str(p) for p in out["paths"].values()))
    return EXIT_OK


def compare(args: argparse.Namespace) -> int:
    from taskcam.sim.experiments import corrections
    from taskcam.sim.experiments.paired import compare as paired
    from taskcam.sim.experiments.paired import markdown

    if args.out is not None:
        check_file("--out", args.out)
    for key, db in (("<first>", args.first), ("<second>", args.second)):
        if not db.is_file():
            found = "a directory" if db.is_dir() else "no such file"
            raise ResultsError(db, found, "a results database file", key)
    try:
        cells = paired(args.first, args.second)  # reads the databases only
    except ResultsError as exc:
        raise exc.given_as("<second>" if exc.path == args.second else "<first>") from None
    text = markdown(cells, args.first.stem, args.second.stem)
    if cells:  # where the first sweep corrected its cameras: what that left, by outcome
        moves = corrections.markdown(args.first, args.second, min(c.tolerance for c in cells))
        text += "\n" + moves if moves else ""
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text)
        _log(f"wrote {args.out}")
    return EXIT_OK


def figure7(args: argparse.Namespace) -> int:
    from taskcam.sim.experiments.figure7 import figure7 as study

    check_directory("--out", args.out, ["figure7_a.png", "figure7_b.png", "figure7.json"])
    report = study(args.out)
    (args.out / "figure7.json").write_text(json.dumps(report, indent=2) + "\n")
    for instance in report["instances"]:
        _log(f"instance {instance['instance']}: optimum {instance['optimum']} views the "
             f"{instance['target']} target (RF {instance['rating']['total']:.2f})")
    _log(f"wrote {args.out}/figure7.json and the heatmaps")
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    pin(restart=is_command())  # the taskcam command starts again, pinned, if it was not
    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            return run(args)
        if args.command == "sweep":
            return sweep(args)
        if args.command == "report":
            return report(args)
        if args.command == "compare":
            return compare(args)
        if args.command == "figure7":
            return figure7(args)
    except (ScenarioError, ResultsError) as exc:  # invalid input: a scenario, sweep or database
        print(f"taskcam: error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print("taskcam: interrupted", file=sys.stderr)
        return EXIT_FAILURE
    except Exception:  # a failure of taskcam itself: show where
        traceback.print_exc()
        print("taskcam: failed (see the traceback above)", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
