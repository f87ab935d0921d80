"""One command-line grammar: unit-suffixed flags, old spellings still accepted with a notice, an example in every help."""

import argparse
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: (parser module, sub-command) pairs that follow the grammar (plumbing/cliargs.py)
COMMANDS = [("devices.cli_record_parser", "record"), ("devices.cli_identify_parser", "identify"), ("devices.cli_identify_parser", "fit"),
            ("devices.cli_hardware_parser", "emulate"), ("devices.cli_hardware_parser", "latency"), ("renderer.cli_run_parser", "run"),
            ("stimuli.cli_build_parser", "build-library"), ("stimuli.cli_show_parser", "show"), ("study.cli_run_parser", "run"),
            ("analysis.cli_report_parser", "report"), ("analysis.cli_synthetic_parser", "synthetic")]
#: a help text saying "in <unit>" means the flag must end in the unit's suffix
UNITS = [(r"\bin m/s\b", "-m-s"), (r"\bin N/m\b", "-N-m"), (r"\bin Hz\b", "-hz"), (r"\bin A\b", "-A"),
         (r"\bin N\b(?!/)", "-N"), (r"\bin s\b", "-s")]


def parser_of(module, command):
    top = argparse.ArgumentParser(prog="x")
    sub = top.add_subparsers(dest="command")
    importlib.import_module(module).register(sub)
    return sub.choices[command]


@pytest.mark.parametrize("module,command", COMMANDS)
def test_help_has_an_example_and_unit_suffixes(module, command):
    p = parser_of(module, command)
    text = p.format_help()
    assert "example" in (p.epilog or ""), f"{command}: --help has no example"
    assert re.search(r"(hfam-\w+|python -m \w+) " + re.escape(command), p.epilog), p.epilog
    for action in p._actions:
        name = action.option_strings[0] if action.option_strings else ""
        for pattern, suffix in UNITS:
            if name and re.search(pattern, action.help or "") and not name.endswith(suffix):
                if not (suffix == "-s" and name.endswith(("-ms", "-us"))):
                    pytest.fail(f"{command} {name}: its help says {pattern!r}, so it should end in {suffix}")
    assert "usage" in text


def _all_commands():
    """(module, command) of every sub-command in every package's ``__main__.COMMANDS`` table."""
    out = []
    for pkg in ("devices", "stimuli", "renderer", "study", "analysis"):
        for c in importlib.import_module(f"{pkg}.__main__").COMMANDS:
            out.append((c.module, c.name))
    return out


@pytest.mark.parametrize("module,command", _all_commands())
def test_every_subcommand_help_ends_with_an_example(module, command):
    """Every sub-command of every package (not only the listed ones): --help ends with examples of itself, and
    a flag whose help says "in <unit>" carries the unit's suffix."""
    test_help_has_an_example_and_unit_suffixes(module, command)
    p = parser_of(module, command)
    text = p.format_help()
    assert "``" not in text and "::" not in text and ":func:" not in text, f"{command}: reStructuredText in --help"
    n = len(re.findall(r"^examples?:", text, re.M)) + len(re.findall(r"(hfam-\w+|python -m \w+) " + re.escape(command)
                                                                   + r" .*::", text))
    assert n == 1, f"{command}: examples printed {n} times"


def test_linearity_and_validate_follow_the_grammar(capsys):
    p = parser_of("devices.cli_linearity_parser", "linearity")
    new = p.parse_args(["--amplitudes-A", "0.2,1", "--grips-N", "1,3", "--band-hz", "20", "400"])
    assert capsys.readouterr().err == ""
    old = p.parse_args(["--amplitudes", "0.2,1", "--grips", "1,3", "--band", "20", "400"])
    err = capsys.readouterr().err
    assert (old.amplitudes, old.grips, tuple(old.band)) == (new.amplitudes, new.grips, tuple(new.band)) == \
        ((0.2, 1.0), (1.0, 3.0), (20.0, 400.0))
    assert "use --amplitudes-A" in err and "use --grips-N" in err and "use --band-hz" in err
    p = parser_of("devices.cli_validate_parser", "validate")
    new = p.parse_args(["m", "--grip-N", "3", "--amplitude-A", "0.5", "--amplitudes-A", "0.2,0.7"])
    old = p.parse_args(["m", "--grip", "3", "--amplitude", "0.5", "--amplitudes", "0.2,0.7"])
    assert (old.grip, old.amplitude, old.amplitudes) == (new.grip, new.amplitude, new.amplitudes) == (3.0, 0.5, (0.2, 0.7))
    assert "use --grip-N" in capsys.readouterr().err
    assert "--grip " not in p.format_help() and "--amplitudes " not in p.format_help()


def test_old_spellings_still_work_with_a_notice(capsys):
    p = parser_of("renderer.cli_run_parser", "run")
    new = p.parse_args(["--velocities-m-s", "0.1,0.2", "--grip-N", "3", "--out", "o"])
    assert capsys.readouterr().err == ""
    old = p.parse_args(["--velocity", "0.1,0.2", "--grip", "3", "--out", "o"])
    err = capsys.readouterr().err
    assert (old.velocity, old.grip) == (new.velocity, new.grip) == ([0.1, 0.2], 3.0)
    assert "warning: --velocity is deprecated; use --velocities-m-s" in err and "--grip-N" in err
    p = parser_of("devices.cli_identify_parser", "identify")
    assert p.parse_args(["--grip", "0,10", "--out", "o"]).grip == p.parse_args(["--grips-N", "0,10", "--out", "o"]).grip
    assert "use --grips-N" in capsys.readouterr().err
    assert "--grip " not in p.format_help() and "--grips-N" in p.format_help()   # old spellings are not advertised


def test_benchmarks_help_lists_them():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "--help"], cwd=ROOT, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    for p in (ROOT / "benchmarks").glob("bench_*.py"):
        assert f"  {p.stem.removeprefix('bench_')} " in out.stdout


def test_benchmarks_pass_what_follows_one_name_to_that_benchmark(capsys):
    from benchmarks.__main__ import main as bench

    with pytest.raises(SystemExit) as out:                 # its own parser, which takes sizes as arguments
        bench(["analysis", "--help"])
    assert out.value.code == 0 and "--warm-bytecode" in capsys.readouterr().out
    with pytest.raises(SystemExit) as out:                 # a positional argument reaches it too
        bench(["analysis", "many"])
    assert out.value.code == 2 and "invalid int value: 'many'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as out:
        bench(["analysis", "10000", "--repeats", "0"])
    assert out.value.code == 2 and "--repeats and every size must be >= 1" in capsys.readouterr().err
    assert bench(["study", "--subjects", "3"]) == 2         # one whose main takes nothing: refused before it runs
    assert "benchmark study takes no options or arguments, got --subjects 3" in capsys.readouterr().err
    assert bench(["teleop", "nope"]) == 2 and "takes no options" in capsys.readouterr().err
    assert bench(["nope"]) == 2 and "unknown benchmark(s) ['nope']" in capsys.readouterr().err


@pytest.mark.parametrize("module, command, argv, flag", [
    ("renderer.cli_run_parser", "run", ["--velocities-m-s", "0.1,-2", "--out", "o"], "--velocities-m-s"),
    ("renderer.cli_run_parser", "run", ["--duration-s", "0", "--out", "o"], "--duration-s"),
    ("devices.cli_identify_parser", "identify", ["--delay-s", "soon", "--out", "o"], "--delay-s"),
])
def test_a_bad_value_of_a_renamed_flag_names_the_flag_as_written_today(module, command, argv, flag, capsys):
    p = parser_of(module, command)
    with pytest.raises(SystemExit):
        p.parse_args(argv)
    err = capsys.readouterr().err
    assert f"{flag} must be" in err or f"{flag}: " in err
    old = flag.rsplit("-", 1)[0] if flag != "--velocities-m-s" else "--velocity"
    assert f"{old} must" not in err and f"{old}:" not in err.replace(f"{flag}:", "")


def test_timing_check_help_promises_only_what_out_writes():
    text = " ".join(parser_of("renderer.cli_timing_check_parser", "timing-check").format_help().split())
    assert "to this JSON file; no plot is drawn" in text and "figures" not in text
