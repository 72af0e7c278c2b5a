"""Every output path is checked before any work: a path that cannot be created and
written exits 2 within seconds with one line naming the option, the path and why, and
nothing is written. The paths are ones no user can write, root included: under a
regular file, under ``/proc``."""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

import pytest
from conftest import run_taskcam
from input_errors import cli

from taskcam.sim.output_paths import OutputPathError, check_directory, check_file

SMOKE = Path(__file__).parents[1] / "scenarios" / "smoke.toml"


def _commands(tmp_path: Path, bad: Path) -> list[tuple[list[str], str]]:
    """Each command that writes, with ``bad`` as its output path: (argv, option)."""
    db = tmp_path / "results.sqlite"
    db.write_bytes(b"")  # report and compare fail on their input only after the check
    return [(["run", "--out", str(bad)], "--out"),
            (["run", "--out", str(bad), "--no-record", "--video", "--quiet"], "--out"),
            (["sweep", str(SMOKE), "--db", str(bad / "r.sqlite")], "--db"),
            (["report", str(db), "--out", str(bad)], "--out"),
            (["compare", str(db), str(db), "--out", str(bad / "c.md")], "--out"),
            (["figure7", "--out", str(bad)], "--out")]


def _assert_refused(argv: list[str], option: str, bad: Path, why: str) -> None:
    start = time.monotonic()
    done = run_taskcam(*argv)
    seconds = time.monotonic() - start
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].startswith(f"taskcam: error: {option}: "), lines[0]
    assert str(bad) in lines[0] and why in lines[0], lines[0]
    assert done.stdout == ""
    assert seconds < 5.0, f"{argv}: {seconds:.1f} s"


def test_a_path_under_a_regular_file_is_refused_at_once(tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("mine")
    bad = blocker / "sub"
    for argv, option in _commands(tmp_path, bad):
        _assert_refused(argv, option, bad, f"{blocker} is a file")
    assert blocker.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "results.sqlite"]


def test_a_path_under_proc_is_refused_at_once(tmp_path):
    bad = Path("/proc") / f"taskcam-{os.getpid()}" / "out"
    for argv, option in _commands(tmp_path, bad):
        _assert_refused(argv, option, bad, "cannot create /proc/taskcam-")
    assert not bad.parent.exists()


def test_a_run_directory_whose_files_cannot_be_written_is_refused(tmp_path):
    """What the run writes inside its directory: a directory where summary.json goes, a
    file where textures/ goes."""
    out = tmp_path / "run"
    (out / "summary.json").mkdir(parents=True)
    code, err = cli("run", "--out", str(out), "--no-record")
    assert code == 2 and "summary.json is a directory" in err and len(err.splitlines()) == 1
    (out / "summary.json").rmdir()
    (out / "textures").write_text("")
    code, err = cli("run", "--out", str(out), "--no-record")
    assert code == 2 and "textures is not a directory" in err
    (out / "textures").unlink()
    (out / "episode.mp4").mkdir()
    code, err = cli("run", "--out", str(out), "--video", "--no-record")
    assert code == 2 and "episode.mp4 is a directory" in err


def checked_as_user(folder: Path) -> list[str]:
    """Each check's verdict on a run directory and a database file in ``folder``, made
    in a forked process as the user; as root (who writes through permission bits), as
    the unprivileged user ``nobody``."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: drop root, check, report, leave without cleaning up
        try:
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            verdicts = []
            for check, path in ((check_directory, folder / "run"),
                                (check_file, folder / "r.sqlite")):
                try:
                    check("--out", path)
                    verdicts.append("passed")
                except OutputPathError as exc:
                    verdicts.append(str(exc))
            os.write(write, "\n".join(verdicts).encode())
        finally:
            os._exit(0)
    os.close(write)
    with os.fdopen(read) as f:
        out = f.read()
    os.waitpid(pid, 0)
    return out.splitlines()


def test_a_read_only_directory_is_refused():
    """A folder the user may not write into is refused, and one beside it that the user
    may write into passes."""
    top = Path(tempfile.mkdtemp(dir="/tmp"))
    try:
        top.chmod(0o755)
        read_only, writable = top / "ro", top / "rw"
        read_only.mkdir(mode=0o555)
        writable.mkdir()
        writable.chmod(0o777)
        refused = checked_as_user(read_only)
        assert len(refused) == 2 and all("Permission denied" in line for line in refused)
        assert checked_as_user(writable) == ["passed", "passed"]
    finally:
        shutil.rmtree(top, ignore_errors=True)


def test_a_check_leaves_nothing_behind(tmp_path):
    """A writable path passes, and the folders and probe made to find out are gone."""
    check_directory("--out", tmp_path / "a" / "b" / "c", ["summary.json"], ["textures"])
    check_file("--db", tmp_path / "x" / "r.sqlite")
    assert list(tmp_path.iterdir()) == []
    existing = tmp_path / "r.sqlite"
    existing.write_bytes(b"data")
    check_file("--db", existing)
    assert existing.read_bytes() == b"data"  # opened to append, never truncated
    with pytest.raises(OutputPathError, match="it is a directory"):
        check_file("--out", tmp_path)
    with pytest.raises(OutputPathError, match="it is a file"):
        check_directory("--out", existing)
