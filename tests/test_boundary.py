"""The boundary: the algorithm packages are pure numpy/OpenCV code.

``mapping``, ``placement`` and ``calibration`` never import mujoco, nor anything of
``sim`` (the arrows run one way: sim -> the algorithm packages). Checked in a fresh
interpreter, where nothing else has loaded them first, over every submodule found by
walking the packages, so a new module is held to it without being listed here.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

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


ROOT = Path(__file__).resolve().parent.parent
SOURCES = sorted(p for top in ("sim", "mapping", "placement", "calibration", "bench", "tests",
                               "examples") for p in (ROOT / top).rglob("*.py"))


def private_imports(source: str) -> list[tuple[int, str]]:
    """The private names (``_x``, not dunders) a module's source imports from another
    module, with their lines."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            names = [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            names = [part for a in node.names for part in a.name.split(".")]
        else:
            continue
        found += [(node.lineno, n) for n in names
                  if n.startswith("_") and not (n.startswith("__") and n.endswith("__"))]
    return found


def test_no_module_imports_another_modules_private_name():
    assert len(SOURCES) > 100
    offenders = {str(p.relative_to(ROOT)): hits for p in SOURCES
                 if (hits := private_imports(p.read_text()))}
    assert not offenders, offenders


def test_the_check_sees_a_private_import():
    assert private_imports("from a.b import c, _d\nimport e._f\nfrom g import __version__") \
        == [(1, "_d"), (2, "_f")]


def imported_modules(source: str) -> set[str]:
    """The top-level-qualified modules a source imports (absolute imports only)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return out


def test_shared_geometry_sits_below_the_rooms_that_use_it():
    """Targets and their geometry live in mapping (the bottom floor): calibration does
    not reach sideways into placement for them, nor the simulated world down into
    calibration."""
    for folder, forbidden in (("calibration", "placement"), ("sim/world", "calibration")):
        for path in sorted((ROOT / folder).rglob("*.py")):
            bad = {m for m in imported_modules(path.read_text())
                   if m == forbidden or m.startswith(forbidden + ".")}
            assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"
    assert "calibration.targets" in imported_modules("from calibration.targets import x")
