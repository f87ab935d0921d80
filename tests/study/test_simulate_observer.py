"""``python -m study simulate-observer``: the files it writes and what they hold, the precision table of
``--repeat``, the figures in the project style, refusals and one-line errors naming the flag."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import figstyle
from study.__main__ import main
from psychophysics.methods import method_from_state
from psychophysics.observer import ObserverParams
from tests.support.cli import run_cli


@pytest.fixture
def checked(monkeypatch):
    """Record each figure's legend overlaps and unit-less axes before figstyle.save writes it."""
    seen = []
    orig = figstyle.save

    def spy(fig, path, data=None, **kw):
        seen.append({"path": Path(path), "overlaps": figstyle.legend_overlaps(fig),
                     "units": figstyle.unlabelled_axes(fig)})
        return orig(fig, path, data, **kw)

    monkeypatch.setattr(figstyle, "save", spy)
    return seen


def rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_one_run_writes_estimate_track_and_figure(tmp_path, checked, capsys):
    out = tmp_path / "sim"
    assert main(["simulate-observer", "--method", "quest+", "--threshold", "0.5", "--trials", "30", "--seed", "3",
                 "--out", str(out)]) == 0
    est = json.loads((out / "estimate.json").read_text())
    track = rows(out / "trials.csv")
    assert len(track) == 30 and [int(r["trial"]) for r in track] == list(range(1, 31))
    # the first intensity is in the track and in the estimate; the defaults are the documented ones
    assert float(track[0]["intensity"]) == est["first_intensity"]
    assert est["observer"] == {"threshold": 0.5, "slope": 3.5, "lapse": 0.02, "guess": 0.5, "function": "weibull"}
    assert est["method_config"]["intensities"] == {"min": 0.05, "max": 5.0, "n": 41, "spacing": "log10"}
    assert est["reference"] == 0.5 and 0.25 < est["threshold"] < 1.0
    assert est["error_pct"] == pytest.approx(100 * (est["threshold"] / 0.5 - 1))
    # the track replays to the same estimate (trials.csv holds everything the method saw)
    state = {"method": "quest+", "config": est["method_config"],
             "history": [[float(r["intensity"]), r["correct"] == "1"] for r in track]}
    replayed = method_from_state(state).estimate()
    assert replayed["threshold"] == est["threshold"] and replayed["threshold_ci"] == est["threshold_ci"]
    # reversals marked in the track are direction changes of the intensities
    xs = [float(r["intensity"]) for r in track]
    for i, r in enumerate(track[:-1]):
        if r["reversal"] == "1":
            prev = next(xs[j] for j in range(i - 1, -1, -1) if xs[j] != xs[i])
            assert (xs[i] - prev) * (xs[i + 1] - xs[i]) < 0
    assert sum(r["reversal"] == "1" for r in track) == est["reversals"]
    for ext in ("png", "svg", "plot.csv"):
        assert (out / f"staircase.{ext}").stat().st_size > 500
    plotted = rows(out / "staircase.plot.csv")
    assert [float(r["intensity"]) for r in plotted] == xs
    assert [c["overlaps"] for c in checked] == [[]] and [c["units"] for c in checked] == [[]]
    assert "threshold estimate" in capsys.readouterr().out


def test_repeat_tabulates_precision_against_trials(tmp_path, checked):
    out = tmp_path / "plan"
    assert main(["simulate-observer", "--method", "updown", "--threshold", "120", "--slope", "2.5", "--trials", "40",
                 "--repeat", "12", "--seed", "5", "--out", str(out)]) == 0
    runs = rows(out / "runs.csv")
    prec = rows(out / "precision.csv")
    assert [int(r["seed"]) for r in runs] == list(range(5, 17))
    assert [int(r["trials"]) for r in prec] == [10, 20, 30, 40]
    # the last row is the runs' final estimates: recompute it from runs.csv
    err = np.array([float(r["error_log10"]) for r in runs])
    last = prec[-1]
    assert float(last["median_abs_error_pct"]) == pytest.approx(100 * np.median(np.abs(10 ** err - 1)), rel=1e-12)
    assert float(last["within_20pct"]) == pytest.approx(np.mean(np.abs(10 ** err - 1) <= 0.2))
    assert float(last["rms_log10"]) == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-12)
    # the reference of a 1-up-2-down is the observer's 70.7 % point (below the Weibull threshold in 2AFC with a
    # 2 % lapse: F there is (0.707 - 0.5) / 0.48 = 0.43)
    est = json.loads((out / "estimate.json").read_text())
    assert est["reference"] == pytest.approx(ObserverParams(120.0, 2.5, 0.02, 0.5).intensity_at(0.5 ** 0.5), rel=1e-12)
    assert 100 < est["reference"] < 120 and "0.7071" in est["reference_is"]
    assert est["repeat"]["runs"] == 12
    assert len(rows(out / "trials.csv")) == 12 * 40
    assert {c["path"].name for c in checked} == {"staircase.png", "precision.png"}
    assert all(c["overlaps"] == [] and c["units"] == [] for c in checked)


def test_same_seed_same_bytes_and_force_replaces_products(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        assert main(["simulate-observer", "--method", "psi", "--threshold", "2", "--trials", "15", "--repeat", "2",
                     "--out", str(out)]) == 0
    for name in ("estimate.json", "trials.csv", "precision.csv", "runs.csv"):
        assert (a / name).read_bytes() != b"" and (a / name).read_bytes() == (b / name).read_bytes()
    # a second run into a non-empty folder is refused; --force replaces, and removes the old precision files
    before = (a / "estimate.json").read_bytes()
    assert main(["simulate-observer", "--method", "psi", "--threshold", "2", "--out", str(a)]) == 2
    assert f"--out {a} already holds earlier results (estimate.json," in capsys.readouterr().err
    assert (a / "estimate.json").read_bytes() == before
    assert main(["simulate-observer", "--method", "weighted", "--threshold", "2", "--trials", "10", "--out", str(a),
                 "--force"]) == 0
    assert not (a / "precision.csv").exists() and not (a / "runs.csv").exists()
    assert json.loads((a / "estimate.json").read_text())["method"] == "weighted"


@pytest.mark.parametrize(("flags", "message"), [
    (["--lapse", "0.5"], "error: --lapse must be in [0, 0.5)"),
    (["--alternatives", "1"], "error: --alternatives must be an integer >= 2, got 1"),
    (["--threshold", "-1"], "error: --threshold must be > 0.0, got -1.0"),
    (["--slope", "0"], "error: --slope must be > 0.0, got 0.0"),
    (["--intensity-min", "5", "--intensity-max", "4"], "error: --intensity-max must be > --intensity-min"),
    (["--trials", "0"], "error: --trials must be an integer 1..10000, got 0"),
])
def test_bad_flags_give_one_error_line_naming_the_flag(tmp_path, capsys, flags, message):
    """In the test's process (tests/support/cli.py): a raw exception would escape ``main`` here."""
    base = ["--method", "quest+", "--threshold", "1", "--out", str(tmp_path / "x")]
    args = base + flags if "--threshold" not in flags else ["--method", "quest+", "--out", str(tmp_path / "x")] + flags
    proc = run_cli(capsys, "study", "simulate-observer", *args)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(message) and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "x").exists()


def test_printed_truth_says_which_point_it_is(tmp_path, capsys):
    """An up-down staircase's truth is its target point (2-down 1-up: 70.7 % correct), not the threshold."""
    assert main(["simulate-observer", "--method", "updown", "--threshold", "0.5", "--trials", "20",
                 "--out", str(tmp_path / "u")]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    est = json.loads((tmp_path / "u" / "estimate.json").read_text())
    assert f"(true 70.7 % correct point {est['reference']:.4g})" in line and est["reference"] != 0.5
    assert main(["simulate-observer", "--method", "quest+", "--threshold", "0.5", "--trials", "10",
                 "--out", str(tmp_path / "q")]) == 0
    assert "(true threshold 0.5)" in capsys.readouterr().out
