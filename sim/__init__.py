"""The MuJoCo side of taskcam, in rooms that follow the data flow: ``config`` (scenario
and sweep files), ``world`` (the MuJoCo world: scene, rendering, IK, motion), ``stages``
(the episode's stages over a world), ``experiments`` (trials, sweeps, results, studies)
and the command line (``cli``) on top.

Importing ``taskcam.sim`` pins the processor-dependent code paths (environment variables that
numpy, OpenCV, OpenBLAS and Mesa read when they load: sim/determinism.py) and does
nothing else: no GL backend is probed and mujoco is not imported until a program that
renders asks for it (:func:`taskcam.sim.world.gl.resolve_gl_backend`).
"""

from taskcam.sim.determinism import pin

pin()
