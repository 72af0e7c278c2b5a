"""A run directory: one episode run and written as ``taskcam run`` writes it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from taskcam.sim.screen import Meter
from taskcam.sim.stages.episode import Episode
from taskcam.sim.stages.overview import Film, Overview, framed_points, save_png
from taskcam.sim.stages.overview_marks import (
    TARGET_RGB,
    draw_labels,
    rgb255,
    robot_marks,
    target_marks,
)
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.slot_target import task_targets
from taskcam.sim.world.scene import save_scene


def write_run(episode: Episode, out: Path, record: bool = True,
              record_unknown: bool = False, progress: Callable[[str], None] | None = None,
              video: bool = False, meter: Meter | None = None) -> dict[str, Any]:
    """Run ``episode`` and write ``out/summary.json``, ``scene.xml``, ``look.xml`` (with
    the textures they read), ``overview.png`` and, if ``record``, ``run.rrd``
    (never-observed voxels too if ``record_unknown``), if ``video``, ``episode.mp4``;
    ``progress`` is told a line as each stage ends, ``meter`` shows the long stages'
    work as it goes (sim/screen.py). Returns the summary."""
    s = episode.scenario
    out.mkdir(parents=True, exist_ok=True)
    world = episode.world
    robots = [r.body_ids for r in world.scene.robots]
    film = None
    if video:  # framed on where the robots start and the work-piece: they stay within
        film = Film(out / "episode.mp4",
                    Overview(world.model, framed_points(world.model, world.data, robots)))
    recorder = Recorder(out / "run.rrd" if record else None,
                        recording_id=f"{s.name}-seed{s.seed}", unknown=record_unknown, film=film)
    try:
        summary, scenes = episode.run(recorder, progress, meter)
    finally:
        recorder.close()
        if film is not None:
            film.overview.close()
    for name, (xml, files) in scenes.items():
        save_scene(out, xml, files, name)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    write_overview(episode, out / "overview.png", summary)
    return summary


def write_overview(episode: Episode, path: Path, summary: dict[str, Any]) -> None:
    """The world as the episode left it, from a free camera that frames the work-piece
    and the robots (``path``, PNG): every robot's camera's frustum drawn in, green when
    ``summary`` has it placed and red when not, each robot and target labelled
    (sim/stages/overview_marks.py), in the roles the episode gave them."""
    world = episode.world
    robots, targets = robot_marks(summary), target_marks(summary, task_targets(world))
    with Overview(world.model, framed_points(world.model, world.data,
                                             [r.body_ids for r in world.scene.robots])) as view:
        picture = view.render(world.data, [r.T_world_cam for r in robots], world.pinhole,
                              [r.rgba for r in robots])
        at = view.pixels(np.array([r.T_world_cam[:3, 3] for r in robots]
                                  + [t.position for t in targets]))
    draw_labels(picture, [(r.label, at[k], rgb255(r.rgba)) for k, r in enumerate(robots)]
                + [(t.label, at[len(robots) + k], TARGET_RGB) for k, t in enumerate(targets)])
    save_png(path, picture)
