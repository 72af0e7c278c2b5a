"""Auditing a run directory (``summary.json``, ``scene.xml`` and ``look.xml``): does the
summary tell the truth about the saved scenes?

Checks, each a kind of :class:`Finding`:

- ``unaccounted_robot``: every robot of the scene is in the summary, and every robot
  and every placement of it is either placed or refused with a reason;
- ``pose_mismatch``: each robot's reported ``pose`` is its camera's pose in
  ``scene.xml`` at keyframe ``final``, within what the XML round trip leaves (POSE_TOL_M,
  POSE_TOL_DEG); ``look_mismatch``: the placement it looked from is where ``look.xml``'s
  keyframe ``look`` has its camera (LOOK_TOL_M, LOOK_TOL_DEG);
- ``mirror_mismatch``: the robot's top-level fields are those of the placement it ended
  at, the last one placed;
- ``sighting_outside_image``, ``sighting_off_target``, ``sighting_obstructed``: every
  claimed sighting (``sightings``, and ``seen`` with its ``pixel``) lies inside the
  image, where the true target projects through the true pose of the placement it was
  made from, and an independent ray cast through the saved scene at keyframe ``look``
  (MuJoCo's ``mj_ray`` against the rendered geom groups, the camera's own body left
  out) reaches the target's true place (the hole geom of ``scene.xml``, the
  work-piece's misplacement included) from the camera (and, for a stereo sighting,
  from the right camera too) before anything else;
- ``correction_out_of_tolerance``, ``correction_misreported``: every pose correction
  is within 3 mm / 0.2 deg of the truth or reported as not trusted (``failed`` or
  ``uncertain``) with a reason, and its
  reported error agrees with its estimated pose against the true one;
- ``schema``: the summary lacks what the checks need (named); ``traceback``, ``crash``
  and ``timeout``: the run raised, killed its process or overran (found by the
  runner, sim/experiments/soak/scenes.py, not here).

The checks are pure: they read the three files and nothing else (mujoco only to load
the scenes, put them at a keyframe and cast rays). One robot's checks and their
tolerances are in sim/experiments/soak/audit_robot.py, the saved scenes' geometry in
audit_scene.py, the findings in audit_findings.py.
"""

from __future__ import annotations

import json
from pathlib import Path

from taskcam.sim.config.scenario import Scenario
from taskcam.sim.experiments.soak.audit_findings import Audit
from taskcam.sim.experiments.soak.audit_robot import RobotAudit
from taskcam.sim.experiments.soak.audit_scene import SavedScene


def audit_run(run_dir: str | Path, scenario: Scenario | None = None) -> Audit:
    """Audit a run directory. ``scenario`` (optional) says whether correction was on,
    so that a placement without one is caught."""
    out = Audit()
    run_dir = Path(run_dir)
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError) as exc:
        out.add("schema", None, f"summary.json cannot be read: {exc}")
        return out
    scenes: dict[str, SavedScene] = {}
    for file, key in (("scene.xml", "final"), ("look.xml", "look")):
        try:
            scene = SavedScene(run_dir / file)
        except (OSError, ValueError) as exc:
            out.add("schema", None, f"{file} cannot be loaded: {exc}")
            continue
        if key in scene.keyframes():
            scenes[key] = scene
        else:
            out.add("schema", None, f"{file} has no keyframe '{key}' (it has {scene.keyframes()})")
    if not scenes:
        return out
    scene = next(iter(scenes.values()))
    robots = summary.get("robots")
    if not isinstance(robots, list):
        out.add("schema", None, "summary has no 'robots' list")
        return out
    names = [r.get("name") for r in robots if isinstance(r, dict)]
    for missing in sorted(set(scene.robots()) - set(names)):
        out.add("unaccounted_robot", missing, "in scene.xml but not in the summary")
    correction_on = None if scenario is None else scenario.correction.enabled
    for i, robot in enumerate(robots):
        try:
            RobotAudit(out, scenes, robot, correction_on).run()
        except (AttributeError, KeyError, TypeError, ValueError, IndexError) as exc:
            name = robot.get("name") if isinstance(robot, dict) else None
            out.add("schema", name, f"robots[{i}]: malformed record: {exc!r}")
    return out
