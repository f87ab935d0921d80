"""Every size a user can type is bounded, with one ``error:`` line naming the flag or key and the bound, before
anything is made: an [experiment] table's levels, trials per level, planned trials, staircases, a staircase's
``max_trials`` and its QUEST+/Psi grids; a protocol nested too deeply; ``simulate-observer --trials/--repeat``;
a psychometric CSV with too many distinct intensities.

Once: ``trials_per_level = 1e9``, a QUEST+ grid of 10^6 intensities, 10^5 levels, ``--trials 1e8`` or
``--repeat 1e8`` and a CSV of 10^6 intensities were MemoryError tracebacks (or a machine brought down); a JSON
protocol nested 10^5 deep was a RecursionError traceback.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.__main__ import main as analysis_main
from study.__main__ import main
from tests.support.kills import QUICK
from tests.support.study import write

DETECT = 'kind = "detection"\nsample = "pulse_firm"\n'
QUEST = DETECT + 'method = "quest+"\n[experiment.staircases.Q]\nthresholds = {min = 0.5, max = 20.0, n = 20}\n' \
                 'slopes = [3.5]\n'


def _run(tmp_path: Path, protocol_path: Path, capsys) -> str:
    capsys.readouterr()
    code = main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "B1",
                 "--out", str(tmp_path / "DATA"), "--protocol", str(protocol_path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err[:400]
    assert not (tmp_path / "DATA" / "B1").exists()                  # nothing made
    return err


@pytest.mark.parametrize("table, says", [
    (DETECT + "levels = [1.0, 2.0]\ntrials_per_level = 1000000000",
     "trials_per_level must be an integer 1..1000, got 1000000000"),
    (DETECT + "levels = [" + ", ".join(f"{1 + i * 1e-5:.5f}" for i in range(100_000)) + "]",
     "levels lists 100000 values; at most 100"),
    (DETECT + "levels = [" + ", ".join(str(1.0 + i / 100) for i in range(20)) + "]\ntrials_per_level = 600",
     "plans 12000 trials; at most 10000 in one session"),
    (QUEST + "intensities = {min = 0.5, max = 20.0, n = 1000000, spacing = \"log10\"}",
     "staircases.Q.intensities has 1000000 points; at most 1000"),
    (DETECT + 'method = "quest+"\n[experiment.staircases.R]\nmax_trials = 40\n'
              'intensities = {min = 0.5, max = 20.0, n = 1000, spacing = "log10"}\n'
              'thresholds = {min = 0.5, max = 20.0, n = 1000}\nslopes = {min = 1.0, max = 5.0, n = 10}',
     "staircases.R: its grids (intensities x thresholds x slopes) make 10000000 cells; at most 4000000"),
    (DETECT + 'method = "updown"\n' + "".join(f"[experiment.staircases.S{i}]\nstart = 2.0\nstep_down = [0.3]\n"
                                               f"max_trials = 3\n" for i in range(21)),
     "staircases lists 21 staircases; at most 20"),
    (DETECT + 'method = "updown"\n[experiment.staircases.A]\nstart = 2.0\nstep_down = [0.3]\n'
              "max_trials = 100000000", "staircases.A.max_trials = 100000000; at most 2000"),
])
def test_an_experiment_size_beyond_its_bound_is_one_error_line(tmp_path, capsys, table, says):
    err = _run(tmp_path, write(tmp_path / "p.toml", QUICK + "[experiment]\n" + table + "\n"), capsys)
    assert says in err, err[:400]


def test_a_protocol_nested_too_deeply_is_one_error_line(tmp_path, capsys):
    deep = tmp_path / "p.json"
    deep.write_text('{"tap_window_s": 0.6, "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    err = _run(tmp_path, deep, capsys)
    assert f"{deep}: cannot parse (nested too deeply" in err


@pytest.mark.parametrize("flags, says", [
    (["--trials", "100000000"], "error: --trials must be an integer 1..10000, got 100000000"),
    (["--repeat", "100000000"], "error: --repeat must be an integer 1..10000, got 100000000"),
    (["--trials", "10000", "--repeat", "10000"],
     "error: --trials x --repeat must be at most 2000000 trials in all, got 10000 x 10000 = 100000000"),
])
def test_simulate_observer_sizes_are_bounded(tmp_path, capsys, flags, says):
    out = tmp_path / "SIM"
    assert main(["simulate-observer", "--method", "quest+", "--threshold", "1", "--out", str(out), *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith(says) and err.count("\n") == 1, err
    assert not out.exists()


def test_a_psychometric_csv_of_too_many_intensities_is_one_error_line(tmp_path, capsys):
    data = tmp_path / "many.csv"
    data.write_text("intensity,correct\n" + "".join(f"{1 + i * 1e-6!r},{i % 2}\n" for i in range(10_001)))
    out = tmp_path / "FIT"
    assert analysis_main(["psychometric", str(data), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {data}: 10001 distinct intensities; a fit takes at most 10000") and \
        err.count("\n") == 1, err
    assert not out.exists()
