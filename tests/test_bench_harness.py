"""The bench as a harness: every module under bench/ imports without running anything,
every script is a ``python -m bench.GROUP.NAME`` entry point with a ``main()`` and is
listed in docs/benchmarks.md, the shared set-up (paths, GL backend) is the ``bench``
package's alone, no bench file edits ``sys.path``, and every bench command or path the
docs and sources name exists (no private name imported: tests/test_boundary.py, over
the whole tree)."""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
GROUPS = ("peers", "studies", "analyses")
# modules of a group that are not scripts: images and measurements their script uses
HELPERS = {"bench.studies.detector_views", "bench.studies.measurement_views"}
# where commands and paths of bench scripts are written down
DOCUMENTED = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").rglob("*.md")),
              *sorted((ROOT / "scenarios").glob("*.toml"))]
SOURCES = sorted(p for d in ("sim", "mapping", "placement", "calibration", "tests", "bench",
                             "examples", "scripts")
                 for p in (ROOT / d).rglob("*") if p.is_file() and p.suffix in ("", ".py")
                 and "__pycache__" not in p.parts and "results" not in p.parts)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


BENCH_FILES = sorted(BENCH.rglob("*.py"))
MODULES = [module_name(p) for p in BENCH_FILES]
GROUPED = [m for m in MODULES if m.count(".") == 2 and m.split(".")[1] in GROUPS]
SCRIPTS = [m for m in GROUPED if m not in HELPERS]


def tree(module: str) -> ast.Module:
    return ast.parse((ROOT / (module.replace(".", "/") + ".py")).read_text())


def is_main_guard(node: ast.stmt) -> bool:
    """``if __name__ == "__main__":``"""
    return (isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
            and isinstance(node.test.left, ast.Name) and node.test.left.id == "__name__"
            and any(isinstance(c, ast.Constant) and c.value == "__main__"
                    for c in node.test.comparators))


def test_the_scripts_are_found_in_their_groups():
    """The test sees the scripts it claims to check, and every file lies in a group."""
    assert len(SCRIPTS) >= 17, SCRIPTS
    for group in GROUPS:
        assert any(m.startswith(f"bench.{group}.") for m in SCRIPTS), group
    loose = [m for m in MODULES if m not in GROUPED
             and m not in ("bench", "bench.common", *(f"bench.{g}" for g in GROUPS))]
    assert not loose, f"bench modules outside peers/studies/analyses: {loose}"
    assert set(GROUPED) >= HELPERS, "a helper listed here is gone: update HELPERS"


@pytest.mark.parametrize("module", MODULES)
def test_every_bench_module_imports(module):
    """Importing a module (as a test or another script does) succeeds."""
    importlib.import_module(module)


@pytest.mark.parametrize("module", GROUPED)
def test_importing_runs_nothing(module):
    """At module level only imports, definitions, constants and the ``__main__`` guard:
    importing a script does not run its benchmark."""
    for node in tree(module).body:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # a docstring
        assert not isinstance(node, ast.Expr | ast.With | ast.For | ast.While | ast.Try), (
            f"{module}:{node.lineno} runs a statement at import")
        if isinstance(node, ast.If):
            assert is_main_guard(node), f"{module}:{node.lineno} runs an if at import"


@pytest.mark.parametrize("module", SCRIPTS)
def test_a_script_has_main_behind_the_guard(module):
    body = tree(module).body
    guards = [n for n in body if is_main_guard(n)]
    assert len(guards) == 1, f"{module}: no `if __name__ == '__main__':`"
    assert callable(getattr(importlib.import_module(module), "main", None)), (
        f"{module}: no main()")


@pytest.mark.parametrize("module", sorted(HELPERS))
def test_a_helper_is_no_script(module):
    assert not any(is_main_guard(n) for n in tree(module).body), (
        f"{module} is a script now: take it out of HELPERS")


def test_every_script_is_listed_in_docs_benchmarks_with_its_command():
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    missing = [m for m in SCRIPTS if not re.search(rf"python -m {re.escape(m)}\b", text)]
    assert not missing, f"not in docs/benchmarks.md as `python -m MODULE`: {missing}"


@pytest.mark.parametrize("path", BENCH_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_bench_file_edits_sys_path_or_sets_up_on_its_own(path):
    """The set-up is the bench package's (bench/__init__.py): no ``sys.path`` edit
    anywhere, and no script chooses the GL backend itself."""
    node: ast.AST
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and node.attr == "path":
            assert not (isinstance(node.value, ast.Name) and node.value.id == "sys"), (
                f"{path.name}:{node.lineno} uses sys.path")
        if isinstance(node, ast.ImportFrom) and node.module == "sys":
            assert "path" not in {a.name for a in node.names}, f"{path.name} imports sys.path"
        if isinstance(node, ast.Name) and path != BENCH / "__init__.py":
            assert node.id != "resolve_gl_backend", (
                f"{path.name}:{node.lineno} chooses the GL backend: bench/__init__.py does")


def test_bench_commands_and_paths_named_anywhere_exist():
    """Every ``python -m bench.…`` names a module and every ``bench/….py`` a file, in the
    docs, the scenarios and the sources (a moved script leaves no stale command)."""
    stale = []
    for path in DOCUMENTED + SOURCES:
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for m in re.finditer(r"-m (bench(?:\.\w+)+)", text):
            if any(part.isupper() for part in m[1].split(".")):
                continue  # a placeholder: bench.GROUP.NAME
            if not any((ROOT / (m[1].replace(".", "/") + suffix)).exists()
                       for suffix in (".py", "/__init__.py")):
                stale.append(f"{path.relative_to(ROOT)}: {m[0]}")
        for m in re.finditer(r"\bbench/[\w/]+\.py\b", text):
            if not (ROOT / m[0]).exists():
                stale.append(f"{path.relative_to(ROOT)}: {m[0]}")
    assert not stale, "\n".join(stale)


def help_of(module: str) -> subprocess.CompletedProcess[str]:
    """``python -m MODULE --help`` from the repository root, as the docs run it."""
    return subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def test_a_script_runs_as_a_module_from_the_repository_root():
    done = help_of("bench.analyses.secondary_targets")
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout


@pytest.mark.slow
@pytest.mark.parametrize("module", SCRIPTS)
def test_every_script_answers_help_as_a_module(module):
    done = help_of(module)
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout
