"""The boundary: the algorithm packages are pure numpy/OpenCV code.

``mapping``, ``placement`` and ``calibration`` never import mujoco, nor anything of
``sim`` (the arrows run one way: sim -> the algorithm packages). Checked in a fresh
interpreter, where nothing else has loaded them first, over every submodule found by
walking the packages, so a new module is held to it without being listed here.
"""

from __future__ import annotations

import json
import subprocess
import sys

PACKAGES = ("mapping", "placement", "calibration")
FORBIDDEN = ("mujoco", "sim")

IMPORT_EVERYTHING = """
import importlib, json, pkgutil, sys
walk, imported = sys.argv[1] == "walk", []
for top in sys.argv[2:]:
    package = importlib.import_module(top)
    imported.append(top)
    for module in pkgutil.walk_packages(package.__path__, top + ".") if walk else ():
        importlib.import_module(module.name)
        imported.append(module.name)
print(json.dumps({"imported": imported, "loaded": sorted(sys.modules)}))
"""


def fresh_import(*packages: str, walk: bool = True) -> dict[str, list[str]]:
    """Import ``packages`` and (``walk``) all their submodules in a new interpreter (this
    venv's python): the modules imported, and every module then in ``sys.modules``."""
    argv = [sys.executable, "-c", IMPORT_EVERYTHING, "walk" if walk else "only", *packages]
    done = subprocess.run(argv,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout))


def forbidden(loaded: list[str]) -> list[str]:
    """The modules of mujoco or sim among ``loaded``."""
    return sorted(m for m in loaded if m.split(".", 1)[0] in FORBIDDEN)


def test_the_algorithm_packages_import_neither_mujoco_nor_sim():
    found = fresh_import(*PACKAGES)
    # the walk found the packages' modules (not just their __init__), so the check bites
    for module in ("mapping.grid", "mapping.raycast", "placement.rating", "placement.tfv",
                   "calibration.ekf", "calibration.fiducials"):
        assert module in found["imported"], found["imported"]
    leaked = forbidden(found["loaded"])
    assert leaked == [], f"the algorithm packages loaded {leaked}"


def test_the_check_sees_mujoco_and_sim_when_they_are_imported():
    """The control: a fresh interpreter that imports them is caught by the same check
    (the test above does not pass for want of seeing)."""
    leaked = forbidden(fresh_import("mujoco", "sim.world.gl", walk=False)["loaded"])
    assert "mujoco" in leaked and "sim.world.gl" in leaked, leaked
