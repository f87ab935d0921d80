"""The `renderer demo` command: help, argument errors (exit 2, message names the argument)."""

import numpy as np
import pytest

from renderer.__main__ import main
from tests.support.cli import run_cli


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for opt in ("--device", "--out", "--cache-dir", "--rebuild", "--library", "--scope", "--tap-stop-time",
                "--record-velocities", "--sweep-amplitude"):
        assert opt in out


@pytest.mark.parametrize("argv, message", [
    (["--velocities-m-s", "0.1,abc"], "--velocities-m-s"),
    (["--grips-N", "-1"], "--grips-N"),
    (["--device", "bogus:thing"], "unknown device string"),
    (["--tap-stop-time", "0"], "tap_stop_time_s"),
    (["--record-velocities", "0.05"], "record_velocities_m_s"),
    (["--record-velocities", "0.05,x"], "--record-velocities"),
    (["--sweep-amplitude", "-0.1"], "sweep_amplitude_A"),
])
def test_bad_arguments_exit_2_naming_what(argv, message, tmp_path, capsys):
    code = main(["demo", "--out", str(tmp_path / "o"), "--cache-dir", str(tmp_path / "c")] + argv)
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "c").exists()  # nothing was built for a bad command line


def test_window_scope_draws_headless():
    """The live-scope window code path, drawn on the Agg canvas (no display here)."""
    import matplotlib

    matplotlib.use("Agg")
    from renderer.demo.hw_demo import WindowScope, make_scope

    scope = WindowScope()
    t = np.arange(400) / 1000.0
    scope.update(t, 1e-3 * np.cos(t * 20), 30 * np.sin(t * 700), 2, 5)
    assert scope.ax_a.get_title() == "taps 2/5"
    assert scope.la.get_xydata().shape == (400, 2)
    scope.close()
    assert make_scope("none") is None


def test_demo_refuses_an_out_holding_an_earlier_demo_unless_forced(tmp_path, capsys):
    """Auditor (demo_overwrite): a second demo replaced the user's summary.csv without asking."""
    import subprocess
    import sys

    mine = tmp_path / "myresults" / "summary.csv"
    mine.parent.mkdir()
    mine.write_text("rendering,my,precious,data\n")
    (tmp_path / "afile").write_text("x\n")

    def demo(out, *extra):
        return subprocess.run([sys.executable, "-m", "renderer", "demo", "--device", "sim", "--out", out,
                               "--cache-dir", "democache", "--velocities-m-s", "0.1", "--grips-N", "2", "--no-figures",
                               *extra], cwd=tmp_path, capture_output=True, text=True, timeout=600)

    res = demo("myresults")
    assert res.returncode == 2
    assert res.stderr.strip() == ("error: --out myresults already holds a demo's results (summary.csv); not "
                                  "overwriting them: choose another --out or pass --force to replace them")
    assert mine.read_text() == "rendering,my,precious,data\n"
    assert not (tmp_path / "democache").exists()                # refused before anything was built
    # the same refusal for an --out inside a file: the command in this process (the run above is the process)
    res = run_cli(capsys, "renderer", "demo", "--device", "sim", "--out", "afile/run", "--cache-dir", "democache",
                  "--velocities-m-s", "0.1", "--grips-N", "2", "--no-figures", cwd=tmp_path)
    assert res.returncode == 2 and "afile is a file, not a folder" in res.stderr
    assert "--force" in subprocess.run([sys.executable, "-m", "renderer", "demo", "--help"], capture_output=True,
                                       text=True, cwd=tmp_path).stdout


def test_demo_on_a_library_missing_some_unseen_speeds_completes(tmp_path, capsys):
    """``--record-velocities 0.1,0.2`` builds a library over 0.0982-0.1973 m/s: the issue's unseen speeds 0.065 and
    0.095 m/s are outside it. The demo stopped with ``error: speed 0.065 m/s is outside the library's
    velocities`` after building, and again on every rerun; now those speeds are left out (and named) and the
    refined library is scored at the one left (0.14 m/s's neighbour, 0.1477 m/s)."""
    import csv

    argv = ["demo", "--record-velocities", "0.1,0.2", "--velocities-m-s", "0.15", "--grips-N", "2",
            "--cache-dir", str(tmp_path / "c"), "--no-figures"]
    for run in ("built", "cached"):
        out = tmp_path / run
        assert main(argv + ["--out", str(out)]) == 0, capsys.readouterr().err
        assert "error:" not in capsys.readouterr().err
        with open(out / "fidelity.csv", newline="") as fh:
            rows = {r["id"]: r for r in csv.DictReader(fh)}
        rf = rows["hfam_refined_unseen"]
        assert "unseen speeds 0.1477 m/s" in rf["target"]
        assert "0.065, 0.095 m/s left out: outside the refined library's velocities 0.0982-0.1973 m/s" \
            in rf["measured_text"]
        assert 0.0 < float(rf["measured"]) < 2.0 and rf["holds"] in ("yes", "no")
