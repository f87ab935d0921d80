"""Where system parts are looked up (plumbing/sysdeps.py), in each HFAM_DEPS mode."""

import shutil
from pathlib import Path

from plumbing import sysdeps


def test_provision_mode_takes_the_machine_compiler_but_no_system_copy_of_a_provisioned_part(monkeypatch):
    monkeypatch.setenv("HFAM_DEPS", "provision")
    # cc and make belong to the machine (never provisioned): still found on the system
    assert sysdeps.tool("cc") == shutil.which("cc") is not None
    assert sysdeps.tool("make") == shutil.which("make") is not None
    # a provisioned part is taken from .deps only, never from /usr/bin
    for name in ("espeak-ng", "avr-gcc", "simavr"):
        p = sysdeps.tool(name)
        assert p is None or Path(p).parent == sysdeps.bin_dir(), (name, p)


def test_system_mode_ignores_deps(monkeypatch):
    monkeypatch.setenv("HFAM_DEPS", "system")
    for name in ("cc", "espeak-ng", "avr-gcc"):
        p = sysdeps.tool(name)
        assert p is None or Path(p).parent != sysdeps.bin_dir(), (name, p)
        assert p == shutil.which(name, path=sysdeps._system_path()), name
