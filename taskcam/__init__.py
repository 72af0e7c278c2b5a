"""taskcam: task-directed camera placement by cooperating robots, in MuJoCo.

The repository's folders are this package's subpackages (pyproject.toml maps them):
``taskcam.sim`` (everything that touches MuJoCo, and the ``taskcam`` command),
``taskcam.mapping``, ``taskcam.placement`` and ``taskcam.calibration`` (pure numpy /
OpenCV algorithms), with the MJCF assets in ``taskcam/models`` and the scenario files in
``taskcam/scenarios``. Importing ``taskcam`` imports none of them.
"""
