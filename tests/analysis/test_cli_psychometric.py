"""``python -m analysis psychometric`` (analysis.cli_psychometric, analysis.psychophysics): the command's files
for a plain CSV and a study folder, one error per bad input, groups and catch trials."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.__main__ import main
from analysis.psychophysics import POOLED, fit_groups, load_trials
from psychophysics import fitting as pm
from psychophysics.psychometric import psi

ROOT = Path(__file__).resolve().parents[2]
LEVELS = np.linspace(1.0, 8.0, 7)


def _simulate(rng, threshold, slope, guess, lapse, function="logistic", per_level=60, levels=LEVELS):
    x = np.repeat(levels, per_level)
    y = (rng.random(len(x)) < psi(x, threshold, slope, guess, lapse, function)).astype(int)
    return x, y


def _write_csv(path, rows, header=("subject", "condition", "intensity", "correct")):
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _rows(seed=3):
    rng = np.random.default_rng(seed)
    rows = []
    for subject in ("A", "B"):
        for condition, thr in (("hfam_firm", 4.0), ("pulse_firm", 5.5)):
            x, y = _simulate(rng, thr, 1.8, 0.5, 0.01, per_level=30)
            rows += [[subject, condition, a, b] for a, b in zip(x, y)]
    return rows


def test_command_fits_a_plain_csv_per_subject_condition_and_pooled(tmp_path, capsys):
    src = tmp_path / "trials.csv"
    _write_csv(src, _rows())
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "2", "--bootstrap", "200", "--out", str(out)]) == 0
    doc = json.loads((out / "fit.json").read_text())
    for key in ("threshold", "slope", "lapse", "threshold_ci"):
        assert key in doc
    assert len(doc["threshold_ci"]) == 2 and doc["threshold_ci"][0] < doc["threshold"] < doc["threshold_ci"][1]
    groups = {(g["subject"], g["condition"]): g for g in doc["groups"]}
    assert set(groups) == {(POOLED, "(all)"), (POOLED, "hfam_firm"), (POOLED, "pulse_firm"), ("A", "hfam_firm"),
                           ("B", "hfam_firm"), ("A", "pulse_firm"), ("B", "pulse_firm")}
    assert groups[(POOLED, "hfam_firm")]["threshold"] == pytest.approx(4.0, rel=0.15)
    assert groups[(POOLED, "pulse_firm")]["threshold"] == pytest.approx(5.5, rel=0.15)
    with (out / "fits.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 7 and float(rows[0]["threshold"]) == pytest.approx(doc["threshold"])
    assert (out / "fig_psychometric.png").stat().st_size > 0 and (out / "fig_psychometric.plot.csv").exists()
    assert "threshold" in capsys.readouterr().out
    # an earlier result is never replaced silently
    assert main(["psychometric", str(src), "--alternatives", "2", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err


def test_command_reads_a_study_folder_and_draws_staircase_tracks(tmp_path):
    data = tmp_path / "DATA"
    rng = np.random.default_rng(9)
    for subject in ("S01", "S02"):
        folder = data / subject
        folder.mkdir(parents=True)
        (folder / "session.json").write_text(json.dumps({
            "subject": subject, "experiment": {"kind": "detection", "alternatives": 2, "method": "updown"}}))
        x, rows = 2.0, []
        for t in range(1, 61):
            ok = int(rng.random() < psi(x, 1.0, 3.0, 0.5, 0.0))
            rows.append([t, "s1", x, ok, 0])
            x = max(0.1, x - 0.1) if ok else x + 0.2
        _write_csv(folder / "trials.csv", rows, ("trial", "staircase", "intensity", "correct", "is_catch"))
    out = tmp_path / "fits"
    assert main(["psychometric", str(data), "--bootstrap", "100", "--out", str(out)]) == 0
    doc = json.loads((out / "fit.json").read_text())
    assert doc["alternatives"] == 2 and doc["experiment"]["kind"] == "detection"
    assert doc["threshold"] == pytest.approx(1.0, rel=0.3)
    with (out / "fig_staircases.plot.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 120 and sum(int(r["reversal"]) for r in rows) >= 6


@pytest.mark.parametrize("cell, message", [("2", "correct must be 0 or 1, got '2'"),
                                           ("", "correct must be 0 or 1, got ''")])
def test_a_bad_correct_cell_is_one_error_naming_file_and_line(tmp_path, capsys, cell, message):
    src = tmp_path / "bad.csv"
    rows = _rows()[:20]
    rows[6][3] = cell
    _write_csv(src, rows)
    assert main(["psychometric", str(src), "--alternatives", "2", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{src}:8: {message}" in err and "Traceback" not in err
    assert not (tmp_path / "o" / "fit.json").exists()


def test_bad_inputs_get_one_clear_error(tmp_path, capsys):
    one_level = tmp_path / "one.csv"
    _write_csv(one_level, [["A", "c", 3.0, 1], ["A", "c", 3.0, 0]])
    assert main(["psychometric", str(one_level), "--alternatives", "2", "--out", str(tmp_path / "o1")]) == 2
    assert "two or more intensities" in capsys.readouterr().err
    src = tmp_path / "t.csv"
    _write_csv(src, _rows()[:40])
    assert main(["psychometric", str(src), "--out", str(tmp_path / "o2")]) == 2
    assert "--alternatives is required" in capsys.readouterr().err
    no_col = tmp_path / "nocol.csv"
    _write_csv(no_col, [["A", 1.0]], ("subject", "intensity"))
    assert main(["psychometric", str(no_col), "--alternatives", "2", "--out", str(tmp_path / "o3")]) == 2
    assert f"{no_col}:1: missing column(s) correct" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["psychometric", str(src), "--alternatives", "2", "--lapse", "0.6", "--out", str(tmp_path / "o4")])
    assert "--lapse: must be 'free' or a number in [0, 0.5)" in capsys.readouterr().err
    assert main(["psychometric", str(tmp_path / "missing.csv"), "--alternatives", "2",
                 "--out", str(tmp_path / "o5")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_help_loads_nothing_heavy():
    code = ("import sys\nfrom analysis.__main__ import main\ntry:\n    main(['psychometric', '--help'])\n"
            "except SystemExit:\n    pass\nprint(sorted(m for m in ('numpy', 'scipy', 'pandas', 'matplotlib') "
            "if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip().splitlines()[-1] == "[]", proc.stdout + proc.stderr


def test_fit_groups_excludes_catch_trials():
    rng = np.random.default_rng(1)
    x, y = _simulate(rng, 4.0, 2.0, 0.5, 0.0, per_level=40)
    trials_path = Path(__file__)  # any existing path for the sources field
    from analysis.psychophysics import Trials

    n = len(x)
    catch = np.zeros(n, dtype=bool)
    catch[:70] = True                       # the lowest levels' trials as catch trials, all answered wrong
    y_with_catch = np.where(catch, 0, y)
    t = Trials(subject=np.array([""] * n, dtype=object), condition=np.array([""] * n, dtype=object),
               staircase=np.array([""] * n, dtype=object), trial=np.arange(n), intensity=x,
               correct=y_with_catch.astype(np.int8), is_catch=catch, experiment={}, sources=(str(trials_path),))
    fits = fit_groups(t, alternatives=2, bootstrap=0)
    assert fits[0].fit.n_trials == n - 70
    direct = pm.fit(x[~catch], y[~catch], alternatives=2, bootstrap=0)
    assert fits[0].fit.threshold == pytest.approx(direct.threshold, rel=1e-9)
    with pytest.raises(FileNotFoundError):
        load_trials(trials_path.parent / "no-such-folder")


def test_spreadsheet_csvs_read_or_say_what_is_wrong(tmp_path):
    """A byte-order mark (a spreadsheet's "CSV UTF-8") is read; ';' separators and a duplicated column are one
    error that says so (they were "missing column intensity" and accepted)."""
    plain = tmp_path / "plain.csv"
    _write_csv(plain, _rows()[:40])
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = load_trials(plain), load_trials(bom)
    assert len(a) == len(b) == 40
    np.testing.assert_array_equal(a.intensity, b.intensity)
    np.testing.assert_array_equal(a.subject, b.subject)
    semi = tmp_path / "semi.csv"
    semi.write_text(plain.read_text().replace(",", ";"))
    with pytest.raises(ValueError, match=r"semi.csv:1: missing column\(s\) intensity, correct .*separated by ';', "
                                         "not commas"):
        load_trials(semi)
    twice = tmp_path / "twice.csv"
    _write_csv(twice, [r + [r[-1]] for r in _rows()[:4]], ("subject", "condition", "intensity", "correct", "correct"))
    with pytest.raises(ValueError, match=r"twice.csv:1: column\(s\) correct appear more than once"):
        load_trials(twice)
