"""The episode's stages as functions over an explicit world, and the episode that
composes them.

- ``world``: what the stages share (models, belief and world data, map, generator);
- ``exploration``: stage 1, mapping by expected information (``explore``);
- ``rating_problem``, ``place``, ``move``, ``placement_result``: stage 2, placing one
  robot's camera and moving it there; ``correction``, ``corrector``: its pose corrected;
- ``look``: stage 3, the cameras look for the targets;
- ``task``, ``task_result``, ``insertion``: stage 4, the insertion task;
- ``episode``: the stages composed (a sweep's trial composes the same ones);
- ``record``, ``timer``: the rerun recording and the stages' wall-clock times.

Importing this package imports none of them (they import mujoco).
"""
