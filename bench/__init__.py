"""The benchmarks: scripts that measure taskcam and write ``bench/results/NAME.json``.

Run each from the repository root as a module, e.g. ``python -m bench.peers.integration``
(``--help`` lists its options); docs/benchmarks.md lists every script with what it
measures and its command. Three groups:

- ``bench.peers``: taskcam against a peer (another tool, another method or an earlier
  commit) on the same input, side by side;
- ``bench.studies``: one part of the pipeline measured over a grid of conditions or
  many generated scenes, against the simulator's truth;
- ``bench.analyses``: what a sweep's results database, its trials or ``taskcam run``'s
  run directories say, read again.

``bench.common`` is the harness they share (the repository's paths, the machine, the
results file, the printed table, resumable scene records).

Importing ``bench`` is every script's set-up, done once here so that no script repeats
it: the processor-dependent code paths are pinned (importing ``sim``) before numpy
loads, and MuJoCo's GL backend is chosen before anything imports mujoco
(:func:`taskcam.sim.world.gl.resolve_gl_backend`; an existing ``MUJOCO_GL`` is kept). Unlike the
library packages, ``bench`` is a package of entry points: this is why its import has
these effects. The repository root is on ``sys.path`` because the scripts run from it
with ``python -m``; nothing here edits ``sys.path``.
"""

import taskcam.sim  # noqa: F401  (pins the processor-dependent code paths before numpy loads)
from taskcam.sim.world.gl import resolve_gl_backend

resolve_gl_backend()
