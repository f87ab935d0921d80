"""Shared set-ups of the 3-DOF adapters' contract tests (built once per session)."""

import subprocess
from pathlib import Path

import pytest

from plumbing import sysdeps

from tests.support.needs import need

HERE = Path(__file__).resolve().parent / "contract"


@pytest.fixture(scope="session")
def modem_shim(tmp_path_factory) -> Path:
    """modem_lines_shim.so (pseudo-terminal modem lines for a preloaded vendor library), compiled once."""
    need("cc")
    out = tmp_path_factory.mktemp("shim") / "modem_lines_shim.so"
    r = subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-o", str(out), str(HERE / "modem_lines_shim.c"), "-ldl"],
                       capture_output=True, text=True, timeout=60, env=sysdeps.tool_env())
    assert r.returncode == 0, r.stderr
    return out

