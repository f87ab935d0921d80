"""Issue 39 part 3: ``make -C devices/firmware`` finds the provisioned AVR toolchain without ``.deps/bin`` on PATH."""

import shutil
import subprocess
from pathlib import Path

from plumbing import sysdeps

from tests.support.needs import need

FIRMWARE = Path(__file__).resolve().parents[3] / "devices" / "firmware"
PLAIN_PATH = "/usr/bin:/bin"   # what a new user's shell has: no .deps/bin


def _make(build, **env):
    return subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={build}", "all"], capture_output=True, text=True,
                          timeout=300, env={"PATH": PLAIN_PATH, "HOME": str(build), **env})


def test_make_finds_the_toolchain_where_sysdeps_does(tmp_path):
    need("avr-toolchain")
    r = _make(tmp_path)
    assert r.returncode == 0, r.stderr
    hexfile = (tmp_path / "hfam_fw.hex").read_text()
    assert hexfile.startswith(":") and hexfile.rstrip().endswith(":00000001FF")   # an Intel HEX image, ended
    used = sysdeps.tool("avr-gcc")
    assert used is not None and (used in r.stdout or shutil.which("avr-gcc", path=PLAIN_PATH))


def test_make_without_a_toolchain_says_how_to_get_one(tmp_path):
    if shutil.which("avr-gcc", path=PLAIN_PATH):   # installed system-wide: nothing is missing to report
        r = _make(tmp_path, HFAM_DEPS_DIR=str(tmp_path / "empty"))
        assert r.returncode == 0, r.stderr
        return
    r = _make(tmp_path, HFAM_DEPS_DIR=str(tmp_path / "empty"))
    assert r.returncode == 2
    assert "error: avr-gcc not found" in r.stderr and "python -m plumbing.provision" in r.stderr
    assert not (tmp_path / "hfam_fw.elf").exists()
