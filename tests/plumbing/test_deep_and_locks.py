"""Files nested too deeply to read (a JSON list 10^5 levels deep) are one error naming the file, never a
RecursionError traceback, in every reader of a file a user gives; and a lock held by another process is
reported with the holder's pid as the kernel lists it, not the pid written in the lock file.
"""

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from plumbing.fileio import read_json_file
from plumbing.outdir import FileLock, lock_holder_pid
from plumbing.studyfiles import read_session_json
from plumbing.validation import load_dataclass_file
from renderer.config import load_config, load_scene
from stimuli.catalog import load_catalog

DEEP = "[" * 100_000 + "]" * 100_000


@dataclasses.dataclass(frozen=True)
class _Settings:
    x: float = 1.0


@pytest.mark.parametrize("reader", [
    lambda p: read_json_file(p, "settings"),
    read_session_json,
    lambda p: load_dataclass_file(p, _Settings, "settings"),
    load_config,
    load_scene,
], ids=["read_json_file", "read_session_json", "load_dataclass_file", "load_config", "load_scene"])
def test_a_file_nested_too_deeply_is_one_error(tmp_path, reader):
    path = tmp_path / "deep.json"
    path.write_text('{"x": ' + DEEP + "}")
    with pytest.raises(ValueError, match="nested too deeply") as info:
        reader(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_a_catalog_nested_too_deeply_is_one_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("x = " + DEEP + "\n")
    with pytest.raises(ValueError, match=f"{path}: invalid TOML \\(nested too deeply\\)"):
        load_catalog(path)


HOLDER = """
import sys, time
from plumbing.outdir import FileLock
lock = FileLock(sys.argv[1])
assert lock.try_acquire()
print("held", flush=True)
sys.stdin.readline()
"""


def test_a_lock_is_reported_with_the_kernels_holder_not_the_written_pid(tmp_path):
    path = tmp_path / ".lock"
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        path.write_text(json.dumps({"pid": 999_999, "host": "elsewhere"}))   # a stale or forged pid
        assert lock_holder_pid(path) == proc.pid
        said = FileLock.holder(path)
        assert said.startswith(f"pid {proc.pid} on host ") and "999999" not in said
        assert not FileLock(path).try_acquire()
    finally:
        proc.stdin.close()
        proc.wait(timeout=60)
    assert lock_holder_pid(path) is None                                     # released with its process
    assert FileLock.holder(path) == "pid 999999 on host elsewhere (as written in the lock file)"
