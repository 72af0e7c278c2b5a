"""The boundary: the algorithm packages are pure numpy/OpenCV code.

``taskcam.mapping``, ``taskcam.placement`` and ``taskcam.calibration`` never import
mujoco, nor anything of ``taskcam.sim`` (the arrows run one way: sim -> the algorithm
packages). Checked in a fresh
interpreter, where nothing else has loaded them first, over every submodule found by
walking the packages, so a new module is held to it without being listed here.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

PACKAGES = ("taskcam.mapping", "taskcam.placement", "taskcam.calibration")
FORBIDDEN = ("mujoco", "taskcam.sim")

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
    """The modules of mujoco or taskcam.sim among ``loaded``."""
    return sorted(m for m in loaded if any(m == f or m.startswith(f + ".") for f in FORBIDDEN))


def test_the_algorithm_packages_import_neither_mujoco_nor_sim():
    found = fresh_import(*PACKAGES)
    # the walk found the packages' modules (not just their __init__), so the check bites
    for module in ("taskcam.mapping.grid", "taskcam.mapping.raycast", "taskcam.placement.rating",
                   "taskcam.placement.tfv", "taskcam.calibration.ekf",
                   "taskcam.calibration.fiducials"):
        assert module in found["imported"], found["imported"]
    leaked = forbidden(found["loaded"])
    assert leaked == [], f"the algorithm packages loaded {leaked}"


def test_the_check_sees_mujoco_and_sim_when_they_are_imported():
    """The control: a fresh interpreter that imports them is caught by the same check
    (the test above does not pass for want of seeing)."""
    leaked = forbidden(fresh_import("mujoco", "taskcam.sim.world.gl", walk=False)["loaded"])
    assert "mujoco" in leaked and "taskcam.sim.world.gl" in leaked, leaked


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
    for folder, forbidden in (("calibration", "taskcam.placement"),
                              ("sim/world", "taskcam.calibration")):
        for path in sorted((ROOT / folder).rglob("*.py")):
            bad = {m for m in imported_modules(path.read_text())
                   if m == forbidden or m.startswith(forbidden + ".")}
            assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"
    assert "taskcam.calibration.targets" in imported_modules(
        "from taskcam.calibration.targets import x")


TOP_LEVEL = ("sim", "mapping", "placement", "calibration", "models", "scenarios")

LOAD_EVERYTHING = """
import importlib, json, os, pkgutil, sys
import taskcam.sim.cli
from taskcam.sim.config.scenario import load_scenario, SCENARIO_DIR
load_scenario(SCENARIO_DIR / "default.toml")
for top in ("taskcam.sim", "taskcam.mapping", "taskcam.placement", "taskcam.calibration"):
    package = importlib.import_module(top)
    for module in pkgutil.walk_packages(package.__path__, top + "."):
        importlib.import_module(module.name)
files, roots = {}, tuple(os.path.realpath(r) + os.sep for r in sys.argv[1:])
for name, module in list(sys.modules.items()):
    path = getattr(module, "__file__", None)
    if path and os.path.realpath(path).startswith(roots):
        files.setdefault(os.path.realpath(path), []).append(name)
print(json.dumps({"loaded": sorted(sys.modules),
                  "twice": {f: names for f, names in files.items() if len(names) > 1}}))
"""


def test_taskcam_loads_each_module_once_and_under_taskcam_only():
    """Every module of taskcam imported (the command's, a scenario loaded, then every
    submodule), from the repository root, where a stray ``import sim`` would succeed:
    no top-level ``sim``, ``mapping``, ... in ``sys.modules``, and no file of the
    repository loaded as two modules."""
    folders = [str(ROOT / top) for top in (*TOP_LEVEL, "taskcam")]
    done = subprocess.run([sys.executable, "-c", LOAD_EVERYTHING, *folders], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout)
    assert "taskcam.sim.experiments.soak" in found["loaded"]
    stray = sorted(m for m in found["loaded"] if m.split(".", 1)[0] in TOP_LEVEL)
    assert stray == [], f"loaded outside taskcam: {stray}"
    assert "taskcam.sim.cli" in found["loaded"]
    assert found["twice"] == {}, found["twice"]


def test_no_source_imports_a_package_by_its_folder_name():
    """Every import of the project's packages, in source, tests, bench and examples,
    goes through ``taskcam``."""
    offenders = {str(p.relative_to(ROOT)): bad for p in SOURCES
                 if (bad := sorted(m for m in imported_modules(p.read_text())
                                   if m.split(".", 1)[0] in TOP_LEVEL))}
    assert not offenders, offenders
