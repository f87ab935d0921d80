"""Names from users that a spreadsheet would run as a formula (staircase labels beginning with ``=`` or ``@``; a
subject or condition in another program's CSV) are written to the session's own trials.csv with a quote first,
read back as named by ``--resume`` (its row checks) and by the analysis, and the fit's tables never hold a
formula cell. (A subject id of a session cannot begin with one of these characters: its id is refused.)

Once: they were written unescaped into trials.csv, fits.csv and the plot CSVs.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

import study.session.store
from analysis.__main__ import main as analysis_main
from analysis.psychophysics import load_trials
from study.__main__ import main
from tests.support.kills import QUICK
from tests.support.study import write

LABEL = "=HYPERLINK(\"http://e.example\",\"x\")"
SUBJECT = "S1"
PROTOCOL = QUICK + f"""
[experiment]
kind = "detection"
sample = "pulse_firm"
method = "updown"

[experiment.staircases.'{LABEL}']
start = 4.0
step_down = [0.3]
max_trials = 4

[experiment.staircases."@B"]
start = 3.0
step_down = [0.3]
max_trials = 4
"""


def _cells(path: Path) -> list:
    with open(path, newline="") as fh:
        return [c for row in csv.reader(fh) for c in row]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A session stopped after three trials, then resumed to its end."""
    root = tmp_path_factory.mktemp("formula")
    proto = write(root / "p.toml", PROTOCOL)
    args = ["run", "--device", "sim", "--participant", "simulated", "--quiet", f"--subject={SUBJECT}", "--seed", "5",
            "--out", str(root / "DATA"), "--protocol", str(proto)]
    real, count = study.session.store.crash_point, {"n": 0}

    def stop_after_three(label: str) -> None:
        real(label)
        if label.startswith("staircase state written"):
            count["n"] += 1
            if count["n"] == 3:
                raise KeyboardInterrupt
    study.session.store.crash_point = stop_after_three
    try:
        main(args)
    finally:
        study.session.store.crash_point = real
    folder = root / "DATA" / SUBJECT
    assert json.loads((folder / "session.json").read_text())["finished_at"] is None
    assert main(["run", "--quiet", f"--subject={SUBJECT}", "--out", str(root / "DATA"), "--resume"]) == 0
    return folder


def test_trials_csv_quotes_the_names_and_resume_reads_them_back(session):
    cells = _cells(session / "trials.csv")
    assert not [c for c in cells if c[:1] in ("=", "+", "@") or (c[:1] == "-" and not c[1:2].isdigit())]
    with open(session / "trials.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 8                                           # 3 before the stop, 5 after --resume
    assert {r["subject"] for r in rows} == {SUBJECT}
    assert {r["staircase"] for r in rows} == {"'" + LABEL, "'@B"}
    assert json.loads((session / "session.json").read_text())["finished_at"]


def test_the_analysis_reads_the_names_as_named_and_writes_no_formula(session, tmp_path):
    trials = load_trials(session)
    assert set(trials.subject) == {SUBJECT} and set(trials.staircase) == {LABEL, "@B"}
    out = tmp_path / "FIT"
    assert analysis_main(["psychometric", str(session), "--out", str(out)]) == 0
    written = sorted(out.rglob("*.csv"))
    assert written
    for path in written:
        bad = [c for c in _cells(path) if c[:1] in ("=", "+", "@")
               or (c[:1] == "-" and not c[1:2].isdigit() and c[1:2] != ".")]
        assert not bad, (path.name, bad[:3])


def test_names_in_another_programs_csv_never_reach_the_fit_tables_as_formulas(tmp_path):
    data = tmp_path / "other.csv"
    lines = ["subject,condition,intensity,correct"]
    for i in range(120):
        x = 0.5 + (i % 6) * 0.5
        lines.append(f"{'=cmd|calc' if i % 2 else '+S2'},@cond,{x},{int(i % 5 != 0 or x > 2)}")
    data.write_text("\n".join(lines) + "\n")
    out = tmp_path / "FIT"
    assert analysis_main(["psychometric", str(data), "--alternatives", "2", "--out", str(out)]) == 0
    cells = [c for p in sorted(out.rglob("*.csv")) for c in _cells(p)]
    assert "'=cmd|calc" in cells and "'@cond" in cells
    assert not [c for c in cells if c[:1] in ("=", "+", "@")]
