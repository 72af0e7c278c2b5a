"""A run directory: one episode run and written as ``taskcam run`` writes it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sim.stages.episode import Episode
from sim.stages.record import Recorder
from sim.world.scene import save_scene


def write_run(episode: Episode, out: Path, record: bool = True,
              record_unknown: bool = False) -> dict[str, Any]:
    """Run ``episode`` and write ``out/summary.json``, ``scene.xml``, ``look.xml`` (with
    the textures they read) and, if ``record``, ``run.rrd`` (never-observed voxels too
    if ``record_unknown``); returns the summary."""
    s = episode.scenario
    out.mkdir(parents=True, exist_ok=True)
    recorder = Recorder(out / "run.rrd" if record else None,
                        recording_id=f"{s.name}-seed{s.seed}", unknown=record_unknown)
    try:
        summary, scenes = episode.run(recorder)
    finally:
        recorder.close()
    for name, (xml, files) in scenes.items():
        save_scene(out, xml, files, name)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
