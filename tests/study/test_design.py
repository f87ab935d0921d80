"""Counterbalancing: Williams designs balanced for first-order carry-over (checked by counting) for 2-12
conditions, Latin squares for any n, the assignment from a participant list and ``python -m study design``."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from plumbing.studyfiles import parse_design
from study.__main__ import main
from study.design.assign import assign, order_for, read_participants
from study.design.latin import carryover_counts, latin_square, position_counts, williams_design


@pytest.mark.parametrize("n", range(2, 13))
def test_williams_designs_balance_position_and_first_order_carryover(n):
    orders = williams_design(n)
    assert len(orders) == (n if n % 2 == 0 else 2 * n)
    reps = len(orders) // n
    assert all(sorted(row) == list(range(n)) for row in orders)            # every order presents every condition
    pos = position_counts(orders, n)
    assert np.all(pos == reps)                                              # each condition reps times per position
    carry = carryover_counts(orders, n)
    assert np.all(np.diag(carry) == 0)                                      # never a condition after itself
    off = carry[~np.eye(n, dtype=bool)]
    assert np.all(off == reps), carry                                       # every ordered pair equally often


def test_one_square_is_not_balanced_for_odd_n_but_its_mirror_makes_it():
    """The reason for the two-square construction: the first n orders of an odd design leave some ordered pairs
    twice and others never (for 3 conditions: 0 -> 1 twice, 1 -> 0 never)."""
    for n in (3, 5, 7):
        first = williams_design(n)[:n]
        off = carryover_counts(first, n)[~np.eye(n, dtype=bool)]
        assert off.min() == 0 and off.max() == 2


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 13, 30])
def test_latin_squares_for_any_n(n):
    square = latin_square(n)
    assert len(square) == n
    assert all(sorted(r) == list(range(n)) for r in square)                  # rows: orders of the conditions
    assert np.all(position_counts(square, n) == 1)                            # each condition once per position


def test_assignment_in_complete_blocks_keeps_the_balance():
    people = [f"P{k:02d}" for k in range(12)]
    out = assign(people, ["soft", "firm", "hard"], "williams", seed=4)
    assert out["complete_blocks"] == 2 and out["incomplete"] == 0 and out["balanced"]
    carry = np.array(out["carryover_counts"])
    assert np.all(carry[~np.eye(3, dtype=bool)] == 4) and np.all(np.array(out["position_counts"]) == 4)
    assert [r["participant"] for r in out["rows"]] == people
    # each block of six uses every sequence once, and the seed decides the mapping
    assert sorted(r["sequence"] for r in out["rows"][:6]) == list(range(1, 7))
    assert assign(people, ["soft", "firm", "hard"], "williams", seed=5)["rows"] != out["rows"]
    assert assign(people, ["soft", "firm", "hard"], "williams", seed=4) == out
    partial = assign(people[:7], ["soft", "firm", "hard"], "williams", seed=4)
    assert partial["incomplete"] == 1 and partial["balanced"]


def test_the_command_writes_the_table_a_session_reads(tmp_path, capsys):
    plist = tmp_path / "participants.tsv"
    plist.write_text("participant_id\tage\n" + "".join(f"S{k}\t2{k}\n" for k in range(1, 6)))
    assert main(["design", "--participants", str(plist), "--conditions", "soft,firm,hard,pulse",
                 "--out", str(tmp_path / "D")]) == 0
    cap = capsys.readouterr()
    assert "warning: 5 participants are not a multiple of the design's 4 sequences" in cap.err
    text = (tmp_path / "D" / "design.csv").read_text()
    rows = parse_design(text, "design.csv")
    assert [r["participant"] for r in rows] == ["S1", "S2", "S3", "S4", "S5"]
    assert len({tuple(r["order"]) for r in rows[:4]}) == 4
    record = json.loads((tmp_path / "D" / "design.json").read_text())
    assert record["balanced"] and record["design"] == "williams" and record["participants"] == 5
    assert "| S3 |" in (tmp_path / "D" / "design.md").read_text()
    seq, order = order_for(tmp_path / "D" / "design.csv", "S3", ["pulse", "hard", "firm", "soft"], "protocol.toml")
    assert order == rows[2]["order"] and seq == rows[2]["sequence"]
    with pytest.raises(ValueError, match="subject 'S9' is not in the design"):
        order_for(tmp_path / "D" / "design.csv", "S9", ["pulse", "hard", "firm", "soft"], "protocol.toml")
    # a second run without --force is refused and changes nothing
    assert main(["design", "--participants", str(plist), "--conditions", "a,b", "--out", str(tmp_path / "D")]) == 2
    assert "error:" in capsys.readouterr().err and (tmp_path / "D" / "design.csv").read_text() == text


@pytest.mark.parametrize("content, conditions, message", [
    ("S1\nS/2\n", "a,b", "line 2: subject id 'S/2' is not allowed"),
    ("S1\nS2\nS1\n", "a,b", "line 3: participant 'S1' is listed twice (first on line 1)"),
    ("# nobody\n\n", "a,b", "no participant ids"),
    ("S1\n", "a;x,b", "condition name 'a;x' holds one of"),
    ("S1\n", "a,b,a", "a condition is named twice"),
])
def test_bad_input_is_one_error_line_and_writes_nothing(tmp_path, capsys, content, conditions, message):
    plist = tmp_path / "p.txt"
    plist.write_text(content)
    assert main(["design", "--participants", str(plist), "--conditions", conditions, "--out", str(tmp_path / "D")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "D").exists() and not list(tmp_path.glob(".D*"))


def test_a_participant_list_with_comments():
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "p.txt"
        p.write_text("# lab A\nP01\n\nP02  # second\n")
        assert read_participants(p) == ["P01", "P02"]
