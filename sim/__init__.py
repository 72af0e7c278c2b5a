"""The MuJoCo side of taskcam: scenes, rendering, IK, episodes and the CLI.

The processor-dependent code paths are pinned (sim/determinism.py) and the GL backend
is chosen here, before anything imports numpy, cv2 or mujoco.
"""

from .determinism import is_command, pin
from .gl import resolve_gl_backend

pin(restart=is_command())  # the taskcam command starts again, pinned, if it was not
resolve_gl_backend()

from .render import Renderer, camera_pinhole, camera_pose  # noqa: E402
from .scenario import Scenario, ScenarioError, load_scenario, parse_scenario  # noqa: E402
from .scene import Robot, Scene, Target, build_scene  # noqa: E402

__all__ = [
    "Renderer",
    "Robot",
    "Scenario",
    "ScenarioError",
    "Scene",
    "Target",
    "build_scene",
    "camera_pinhole",
    "camera_pose",
    "load_scenario",
    "parse_scenario",
    "pin",
    "resolve_gl_backend",
]
