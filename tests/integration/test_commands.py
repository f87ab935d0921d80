"""The command tables of every package's ``__main__``: each entry is its parser module's own command,
``python -m <package> --help`` lists them without importing any command module or heavy library, and a
command's ``--help`` imports its parser but not its body (``plumbing.dispatch.Body``)."""

import argparse
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from plumbing.dispatch import Body

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("devices", "renderer", "stimuli", "study", "analysis")


def _table(package):
    main = importlib.import_module(f"{package}.__main__")
    return [(c.name, c.module, c.help) for c in main.COMMANDS]


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


COMMAND_HELPS = [(package, name) for package in PACKAGES for name, _, _ in _table(package)]


def _body(package, command) -> str:
    """The module of the body that ``command``'s parser names (a :class:`plumbing.dispatch.Body`)."""
    module = next(m for name, m, _ in _table(package) if name == command)
    sub = argparse.ArgumentParser().add_subparsers()
    importlib.import_module(module).register(sub)
    func = sub.choices[command].get_default("func")
    assert isinstance(func, Body), f"{package} {command}: its parser names {func!r}, not a Body"
    return func.module


@pytest.mark.parametrize(("package", "command"), COMMAND_HELPS)
def test_command_help_loads_no_heavy_library(package, command):
    """``python -m <package> <command> --help`` builds its parser without numba, scipy, pandas, statsmodels or
    matplotlib (each costs 0.3-1 s of start-up): a module the parser needs that imports one of them at its top
    shows up here, not only as a slower benchmark."""
    code = (f"import sys\nfrom {package}.__main__ import main\n"
            f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
            "print('MODULES', ' '.join(sorted(sys.modules)))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout
    loaded = set(proc.stdout.rpartition("MODULES ")[2].split())
    assert "argparse" in loaded and len(loaded) > 50  # the module list was read
    heavy = sorted(m for m in loaded if m.split(".")[0] in {"numba", "scipy", "pandas", "statsmodels", "matplotlib"})
    assert not heavy, f"{package} {command} --help imports {heavy[:5]}"
    body = _body(package, command)
    assert body not in loaded, f"{package} {command} --help imports its body {body}"
