"""The command tables of every package's ``__main__``: each entry is the module's own command, and
``python -m <package> --help`` lists them without importing any command module or heavy library."""

import argparse
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("devices", "renderer", "stimuli", "study", "analysis")


def _table(package):
    main = importlib.import_module(f"{package}.__main__")
    table = getattr(main, "COMMANDS", None)
    return [(c.name, c.module, c.help) for c in table] if table is not None else list(main.COMMAND_TABLE)


@pytest.mark.parametrize("package", PACKAGES)
def test_table_matches_the_modules(package):
    for name, module, help_text in _table(package):
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).register(sub)
        assert name in sub.choices, f"{module} does not register {name!r}"
        helps = {a.dest: a.help for a in sub._choices_actions}
        assert helps[name] == help_text, f"{package} {name}: table help differs from {module}'s"


@pytest.mark.parametrize("package", PACKAGES)
def test_help_imports_no_command_module(package):
    code = (f"import sys\nfrom {package}.__main__ import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(' '.join(sorted(sys.modules)))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    loaded = set(proc.stdout.split())
    commands = {module for _, module, _ in _table(package)}
    assert not commands & loaded
    heavy = {"scipy.signal", "matplotlib", "pandas", "numba"}
    assert not heavy & loaded
