"""plumbing.outdir: an output folder appears whole or not at all, one writer at a time (issue 38, item 1)."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from plumbing.outdir import MARKER, FileLock, OutputBusy, output_folder
from tests.support.files import tree_hashes
from tests.support.procs import kill

#: a writer in its own process: writes one file into the staging folder, says so, then waits for a line
WRITER = textwrap.dedent("""
    import sys
    from plumbing.outdir import output_folder
    with output_folder(sys.argv[1], True) as w:
        (w.path / "new.txt").write_text("new")
        print(w.path, flush=True)
        sys.stdin.readline()
        (w.path / "late.txt").write_text("late")
""")


def _earlier(tmp_path: Path) -> Path:
    """An earlier run's folder, written by the helper (so it holds the marker that lets --force replace it)."""
    out = tmp_path / "R"
    with output_folder(out, False) as w:
        (w.path / "report.md").write_text("S1's report")
        (w.path / "tables").mkdir()
        (w.path / "tables" / "a.csv").write_text("1,2\n")
    return out


def _files(out: Path) -> list[str]:
    """The files of ``out`` but the helper's marker."""
    return sorted(name for name in tree_hashes(out) if name != MARKER)


def _debris(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("."))


def _start_writer(out: Path) -> tuple[subprocess.Popen, Path]:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[2])
    staging = Path(proc.stdout.readline().strip())   # the writer is inside its block, one file written
    assert staging.is_dir() and (staging / "new.txt").is_file(), proc.stderr.read()
    return proc, staging


def test_new_folder_appears_whole_and_leaves_nothing_beside(tmp_path):
    out = tmp_path / "R"
    with output_folder(out, False) as w:
        assert w.path.parent == tmp_path and w.path != out and not out.exists()
        (w.path / "a.txt").write_text("a")
        assert FileLock.busy(tmp_path / ".R.lock")
    assert _files(out) == ["a.txt"] and (out / MARKER).is_file()
    assert _debris(tmp_path) == []                           # no staging folder, no lock file


def test_earlier_results_refused_without_force_naming_them(tmp_path):
    out = _earlier(tmp_path)
    before = tree_hashes(out)
    with pytest.raises(ValueError, match=r"R already holds earlier results \(report.md, tables/\).*--force"):
        output_folder(out, False).open()
    assert tree_hashes(out) == before and _debris(tmp_path) == []


def test_force_replaces_the_whole_folder(tmp_path):
    out = _earlier(tmp_path)
    with output_folder(out, True) as w:
        assert w.replacing
        (w.path / "report.md").write_text("S2's report")
    assert _files(out) == ["report.md"]                      # no S1 table beside S2's report
    assert (out / "report.md").read_text() == "S2's report" and _debris(tmp_path) == []


def test_products_replace_only_the_commands_files(tmp_path):
    out = _earlier(tmp_path)
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(ValueError, match=r"\(report.md\)"):   # only the command's files count as earlier results
        output_folder(out, False, products=("report.*",)).open()
    with output_folder(out, True, products=("report.*", "tables")) as w:
        (w.path / "report.md").write_text("new")
    assert _files(out) == ["notes.txt", "report.md"]
    assert (out / "notes.txt").read_text() == "the user's" and _debris(tmp_path) == []


def test_a_failed_run_leaves_the_earlier_results_exactly(tmp_path):
    out = _earlier(tmp_path)
    before = tree_hashes(out)
    with pytest.raises(RuntimeError, match="boom"):
        with output_folder(out, True) as w:
            (w.path / "report.md").write_text("half")
            raise RuntimeError("boom")
    assert tree_hashes(out) == before and _debris(tmp_path) == []


def test_set_aside_keeps_a_failed_run_beside(tmp_path):
    out = _earlier(tmp_path)
    before = tree_hashes(out)
    for n, name in ((1, "R.failed"), (2, "R.failed.2")):
        w = output_folder(out, True).open()
        (w.path / "state.json").write_text(str(n))
        assert w.set_aside("failed") == tmp_path / name
    assert tree_hashes(out) == before and _debris(tmp_path) == []
    assert (tmp_path / "R.failed.2" / "state.json").read_text() == "2"


def test_a_second_writer_is_refused_naming_the_first(tmp_path):
    out = tmp_path / "R"
    proc, staging = _start_writer(out)
    try:
        with pytest.raises(OutputBusy, match=rf"R is being written by another run: pid {proc.pid} on host"):
            output_folder(out, True).open()
        assert staging.is_dir()                              # the refused writer touched nothing of the first's
        proc.stdin.write("\n")
        proc.stdin.close()
        assert proc.wait() == 0, proc.stderr.read()
    finally:
        kill(proc.pid)
    assert _files(out) == ["late.txt", "new.txt"] and _debris(tmp_path) == []


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGINT, -2)])
def test_a_signal_mid_write_leaves_the_earlier_results_and_no_debris(tmp_path, sig, code):
    out = _earlier(tmp_path)
    before = tree_hashes(out)
    proc, staging = _start_writer(out)
    try:
        proc.send_signal(sig)
        assert proc.wait() == code                           # SIGINT: KeyboardInterrupt, uncaught: Python re-raises the signal
    finally:
        kill(proc.pid)
    assert tree_hashes(out) == before and _debris(tmp_path) == []


def test_a_killed_writers_debris_is_reclaimed_by_the_next(tmp_path):
    out = _earlier(tmp_path)
    before = tree_hashes(out)
    proc, staging = _start_writer(out)
    proc.kill()
    proc.wait()
    assert tree_hashes(out) == before                        # SIGKILL: nothing ran, the earlier folder is whole
    assert _debris(tmp_path) == [".R.lock", staging.name]    # what a SIGKILL leaves (docs/architecture.md)
    with output_folder(out, True) as w:
        assert w.reclaimed == [staging]
        (w.path / "report.md").write_text("next")
    assert _files(out) == ["report.md"] and _debris(tmp_path) == []


def test_the_lock_file_survives_no_race_with_its_removal(tmp_path):
    """A writer that opened the lock file just before the holder removed it locks a fresh one (not the
    removed inode, which would let two writers in)."""
    first = FileLock(tmp_path / ".R.lock", unlink=True)
    assert first.try_acquire()
    stale = os.open(tmp_path / ".R.lock", os.O_RDONLY)     # a second writer's descriptor of the same file
    first.release()
    assert not (tmp_path / ".R.lock").exists()
    second = FileLock(tmp_path / ".R.lock", unlink=True)
    assert second.try_acquire()
    third = FileLock(tmp_path / ".R.lock", unlink=True)
    assert not third.try_acquire()                           # the file the second holds is the one named
    os.close(stale)
    second.release()


def test_an_output_file_is_renamed_into_place_or_left_alone(tmp_path):
    from plumbing.outdir import output_file

    lib = tmp_path / "LIB.npz"
    with output_file(lib, False) as w:
        assert w.path.name == "LIB.npz" and w.path.parent.name.startswith(".LIB.npz.staging-")
        w.path.write_bytes(b"first")
    assert lib.read_bytes() == b"first" and _debris(tmp_path) == []
    with pytest.raises(ValueError, match=r"--out .*LIB.npz exists; not overwriting it: .* --force"):
        output_file(lib, False).open()
    with pytest.raises(KeyboardInterrupt):
        with output_file(lib, True) as w:
            w.path.write_bytes(b"half")
            raise KeyboardInterrupt
    assert lib.read_bytes() == b"first" and _debris(tmp_path) == []
    with pytest.raises(ValueError, match="is a folder"):
        output_file(tmp_path, True).open()
