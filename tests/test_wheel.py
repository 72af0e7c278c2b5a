"""The wheel as a user gets it: built from the repository's files, installed into a fresh
virtual environment, it adds one top-level name (``taskcam``), holds every module of the
repository's packages and their models and scenarios, and its ``taskcam`` command runs
the default scenario from a directory outside the repository.

The fresh environment gets no copy of the heavy pinned dependencies: a ``.pth`` file puts
this environment's site-packages after its own on the path (a directory named by a
``.pth`` line has its own ``.pth`` files left unread, so this environment's editable
install of taskcam stays out of it), and taskcam is checked to load from the wheel's copy.
Building needs setuptools from the package index (pip's build isolation), as
``scripts/setup`` does.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # a build, an install and an episode: a minute or more

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"sim": "sim", "mapping": "mapping", "placement": "placement",
            "calibration": "calibration"}
DATA = ("models", "scenarios")
# what the build reads: the project file, the files it names, the packages' folders
BUILT_FROM = ("pyproject.toml", "README.md", "LICENSE", "taskcam", *PACKAGES, *DATA)
TOP_LEVEL = ("sim", "mapping", "placement", "calibration", "models", "scenarios")
# where the fresh environment's taskcam comes from, and no folder name loaded at the top
WHERE = f"""
import json, sys, taskcam.sim.cli, taskcam.sim.config.scenario as s
stray = sorted(m for m in sys.modules if m.split(".")[0] in {TOP_LEVEL!r})
print(json.dumps([taskcam.sim.cli.__file__, str(s.SCENARIO_DIR), stray]))
"""


def build_wheel(out: Path) -> Path:
    """``pip wheel`` of a copy of the files the build reads (an in-tree build would leave
    build/ and an egg-info in the checkout)."""
    source = out / "source"
    for name in BUILT_FROM:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, source / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__"))
        else:
            source.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, source / name)
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps",
                           "-q", "-w", str(out / "dist")],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    wheels = sorted((out / "dist").glob("taskcam-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def fresh_environment(where: Path) -> tuple[Path, Path]:
    """A new virtual environment (no pip) whose path ends with this environment's
    site-packages: (its python, its site-packages)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True,
                   timeout=300)
    python = where / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; "
                                "print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    here = sysconfig.get_paths()["purelib"]
    (site / "this_environments_dependencies.pth").write_text(here + "\n")
    return python, site


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The wheel built and installed into a fresh environment."""
    work = tmp_path_factory.mktemp("wheel")
    wheel = build_wheel(work)
    python, site = fresh_environment(work / "venv")
    before = set(os.listdir(site))
    done = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install",
                           "--no-deps", "--no-index", "-q", str(wheel)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return {"wheel": wheel, "python": python, "site": site, "work": work,
            "added": set(os.listdir(site)) - before}


def test_the_wheel_holds_one_top_level_package_with_every_module_and_data_file(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert tops == {"taskcam", "taskcam-0.1.0.dist-info"}, sorted(tops)
    expected = {f"taskcam/{p.relative_to(ROOT).as_posix()}"
                for folder in (*PACKAGES, *DATA) for p in (ROOT / folder).rglob("*")
                if p.is_file() and "__pycache__" not in p.parts
                and p.suffix in (".py", ".xml", ".toml")}
    expected.add("taskcam/__init__.py")
    missing = sorted(expected - set(names))
    assert not missing, f"not in the wheel: {missing}"
    assert "taskcam/sim/experiments/soak/__init__.py" in names


def test_installing_adds_only_taskcam_at_the_top(installed):
    added = installed["added"]
    assert added == {"taskcam", "taskcam-0.1.0.dist-info"}, sorted(added)
    record = (installed["site"] / "taskcam-0.1.0.dist-info" / "RECORD").read_text()
    tops = {line.split(",", 1)[0].split("/", 1)[0] for line in record.splitlines() if line}
    assert tops - {"..", "taskcam", "taskcam-0.1.0.dist-info"} == set(), sorted(tops)


def test_the_installed_command_runs_the_default_scenario_outside_the_repository(installed):
    outside = installed["work"] / "elsewhere"
    outside.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = subprocess.run([str(installed["python"]), "-c", WHERE], cwd=outside, env=env,
                           capture_output=True, text=True, timeout=300)
    assert where.returncode == 0, where.stderr
    module, scenarios, stray = json.loads(where.stdout)
    assert Path(module).is_relative_to(installed["site"] / "taskcam"), module
    assert Path(scenarios) == installed["site"] / "taskcam" / "scenarios", scenarios
    assert stray == [], stray

    command = installed["python"].parent / "taskcam"
    done = subprocess.run([str(command), "run", "--no-record", "--quiet", "--out", "run"],
                          cwd=outside, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads((outside / "run" / "summary.json").read_text())
    assert summary["scenario"] == "default"
    assert (outside / "run" / "scene.xml").is_file()
