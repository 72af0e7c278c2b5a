"""A run directory: one episode run and written as ``taskcam run`` writes it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mapping import opencv_pose
from sim.stages.episode import Episode
from sim.stages.overview import Film, Overview, framed_points, save_png
from sim.stages.record import Recorder
from sim.world.render import camera_pose
from sim.world.scene import save_scene


def write_run(episode: Episode, out: Path, record: bool = True,
              record_unknown: bool = False, progress: Callable[[str], None] | None = None,
              video: bool = False) -> dict[str, Any]:
    """Run ``episode`` and write ``out/summary.json``, ``scene.xml``, ``look.xml`` (with
    the textures they read), ``overview.png`` and, if ``record``, ``run.rrd``
    (never-observed voxels too if ``record_unknown``), if ``video``, ``episode.mp4``;
    ``progress`` is told a line as each stage ends. Returns the summary."""
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
        summary, scenes = episode.run(recorder, progress)
    finally:
        recorder.close()
        if film is not None:
            film.overview.close()
    for name, (xml, files) in scenes.items():
        save_scene(out, xml, files, name)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    write_overview(episode, out / "overview.png")
    return summary


def write_overview(episode: Episode, path: Path) -> None:
    """The world as the episode left it, from a free camera that frames the work-piece
    and the robots, every robot's camera's frustum drawn in (``path``, PNG)."""
    world = episode.world
    robots = [r.body_ids for r in world.scene.robots]
    frusta = [opencv_pose(camera_pose(world.data, r.camera)) for r in world.scene.robots]
    with Overview(world.model, framed_points(world.model, world.data, robots)) as view:
        save_png(path, view.render(world.data, frusta, world.pinhole))
