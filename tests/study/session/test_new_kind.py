"""docs/architecture.md's minimal experiment kind, as printed there, runs a whole session on the shared machinery
(views, store, loop, resume checks) next to the two kinds there are: a new kind is one module."""

import argparse
import json
import re
from pathlib import Path

import pytest

from study.cli_run_parser import register
from study.forcedchoice.kind import ForcedChoice
from study.ratings.kind import Ratings
from study.session.run import run_session

from tests.support.study import write

DOC = Path(__file__).resolve().parents[3] / "docs" / "architecture.md"
PROTOCOL = """tap_window_s = 0.6
homing_after_s = 0.3
homing_before_max_s = 0.1

[experiment]
kind = "yes-no"
samples = ["firm", "wood", "firm"]
"""


def _skeleton():
    section = DOC.read_text().split("### A new experiment kind", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    space: dict = {}
    exec(compile(code, str(DOC), "exec"), space)
    return space["YesNo"]


def _args(*argv):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    return parser.parse_args(["run", *map(str, argv)])


def test_the_documented_kind_runs_a_session_and_is_refused_a_second_start(tmp_path, capsys):
    kinds = (Ratings, ForcedChoice, _skeleton())
    proto = write(tmp_path / "yesno.toml", PROTOCOL)
    base = ["--subject", "Y1", "--out", tmp_path / "DATA"]
    args = _args("--device", "sim", "--participant", "simulated", "--seed", 3, "--protocol", proto, "--serve", *base)
    assert run_session(args, kinds) == 0
    out = capsys.readouterr().out
    assert "session Y1 complete: 3 trials" in out and "operator view: http://127.0.0.1:" in out
    folder = tmp_path / "DATA" / "Y1"
    rows = (folder / "trials.csv").read_text().splitlines()
    assert rows[0] == "subject,trial,attempt,sample,response,n_taps" and len(rows) == 4
    assert [r.split(",")[3:5] for r in rows[1:]] == [["firm", "2"], ["wood", "2"], ["firm", "2"]]
    session = json.loads((folder / "session.json").read_text())
    assert session["experiment"]["kind"] == "yes-no" and session["finished_at"]
    assert [s["name"] for s in session["catalog"]] == ["wood", "firm"]    # the catalog's order
    assert sorted(p.name for p in (folder / "traces").iterdir()) == [f"yesno_t00{k}_a01.npz" for k in (1, 2, 3)]
    events = [json.loads(ln)["event"] for ln in (folder / "schedule.jsonl").read_text().splitlines()]
    assert events == ["answered"] * 3
    # the shared checks hold for it too (the command prints them as one error line): a finished session is
    # not resumed, a subject not overwritten
    with pytest.raises(ValueError, match="already finished"):
        run_session(_args("--resume", *base), kinds)
    with pytest.raises(ValueError, match="already has data"):
        run_session(_args("--protocol", proto, *base), kinds)


def test_an_unknown_kind_names_every_kind_there_is(tmp_path):
    proto = write(tmp_path / "p.toml", PROTOCOL.replace('"yes-no"', '"ranking"'))
    args = _args("--subject", "Y2", "--out", tmp_path / "DATA", "--protocol", proto)
    with pytest.raises(ValueError) as exc:
        run_session(args, (Ratings, ForcedChoice, _skeleton()))
    assert str(exc.value) == (f"{proto}: [experiment] kind must be one of ['real-virtual-2afc', 'discrimination', "
                       "'detection', 'yes-no'], got 'ranking'")


def test_the_run_commands_kinds_load_as_listed_and_a_misnamed_one_is_refused():
    """``python -m study run`` names the kinds other than the rating study by their module (imported only for a
    session of theirs): each loads to its class, whose names are the listed ones."""
    from study import cli_run
    from study.adjustment.kind import Adjustment
    from study.magnitude.kind import Magnitude
    from study.session.kind import KindAt

    assert [k.load() for k in cli_run.KINDS] == [Ratings, ForcedChoice, Adjustment, Magnitude]
    assert [tuple(k.names) for k in cli_run.KINDS] == [tuple(k.load().names) for k in cli_run.KINDS]
    with pytest.raises(RuntimeError, match="listed as"):
        KindAt(("ranking",), "study.magnitude.kind", "Magnitude").load()
