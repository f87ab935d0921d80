"""Condition orders assigned to participants from a design (:mod:`study.design.latin`), written before the
sessions so a lab sees who gets which order (``python -m study design``), and read by the kinds that present
conditions in blocks (``[experiment] design = "design.csv"``).

Assignment: the conditions are mapped to the design's symbols in a seeded random order (which condition is
"first" in the square is chance, not the order they were typed in); participants, in the order listed, take
the design's sequences in complete blocks, each block a seeded random permutation of all the sequences. With a
multiple of the number of sequences every sequence is used equally often and the design's balance holds;
otherwise the last block is incomplete, which :func:`assign` reports.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from plumbing.fileio import read_text_utf8
from plumbing.studyfiles import CONDITION_FORBIDDEN, DESIGN_CSV, format_design, parse_design

from ..session.store import check_subject_id
from .latin import carryover_counts, design, is_williams, position_counts


def read_participants(path) -> list[str]:
    """Participant ids from a file: one per line (blank lines and ``#`` comments skipped), or a CSV/TSV with a
    ``participant`` or ``participant_id`` column (a BIDS participants.tsv's ``sub-`` prefix is kept).

    Raises
    ------
    ValueError
        Naming the file and line: an id the study refuses, an id listed twice, no ids.
    """
    text = read_text_utf8(path, "participant list")
    lines = text.splitlines()
    first = lines[0].strip() if lines else ""
    ids, where = [], []
    delim = "\t" if "\t" in first else ","
    header = [h.strip() for h in first.split(delim)]
    column = next((c for c in ("participant", "participant_id") if c in header), None)
    if column is not None:
        reader = csv.DictReader(io.StringIO(text), delimiter=delim)
        for row in reader:
            ids.append((row.get(column) or "").strip())
            where.append(reader.line_num)
    else:
        for n, line in enumerate(lines, 1):
            line = line.split("#", 1)[0].strip()
            if line:
                ids.append(line)
                where.append(n)
    seen = {}
    for pid, line in zip(ids, where):
        try:
            check_subject_id(pid)
        except ValueError as exc:
            raise ValueError(f"{path} line {line}: {exc}") from None
        if pid in seen:
            raise ValueError(f"{path} line {line}: participant {pid!r} is listed twice (first on line {seen[pid]})")
        seen[pid] = line
    if not ids:
        raise ValueError(f"{path}: no participant ids (one per line, or a column 'participant')")
    return ids


def check_conditions(conditions, where: str = "--conditions") -> list[str]:
    """Condition names: at least one, distinct, none empty or holding ``; , "`` or a line break."""
    names = [c.strip() for c in conditions]
    if not names or not all(names):
        raise ValueError(f"{where}: give the conditions' names, comma-separated (none may be empty)")
    bad = [c for c in names if any(ch in c for ch in CONDITION_FORBIDDEN)]
    if bad:
        raise ValueError(f"{where}: condition name {bad[0]!r} holds one of ; , \" or a line break")
    if len(set(names)) != len(names):
        raise ValueError(f"{where}: a condition is named twice: {names}")
    return names


def assign(participants: list[str], conditions: list[str], kind: str = "williams", seed: int = 0) -> dict:
    """Each participant's order of conditions (module docstring).

    Returns
    -------
    dict
        ``rows`` (``participant``, ``sequence`` (1-based, the design's row), ``order``: condition names),
        ``sequences`` (every sequence's order), ``design``, ``conditions``, ``seed``, ``complete_blocks``,
        ``incomplete`` (participants in the last, incomplete block), ``balanced`` (whether the assigned orders
        balance position and, for a Williams design, first-order carry-over: checked by counting),
        ``position_counts`` and ``carryover_counts`` (of the assigned orders, by condition name order).
    """
    n = len(conditions)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 50, n]))
    symbols = [conditions[i] for i in rng.permutation(n)]
    sequences = [[symbols[c] for c in row] for row in design(kind, n)]
    rows, block = [], []
    for k, pid in enumerate(participants):
        if k % len(sequences) == 0:
            block = list(rng.permutation(len(sequences)))
        s = int(block[k % len(sequences)])
        rows.append({"participant": pid, "sequence": s + 1, "order": sequences[s]})
    index = {c: i for i, c in enumerate(conditions)}
    orders = [[index[c] for c in r["order"]] for r in rows]
    complete = len(rows) // len(sequences)
    whole = orders[:complete * len(sequences)]
    pos, carry = position_counts(orders, n), carryover_counts(orders, n)
    if kind == "williams":
        balanced = bool(whole) and is_williams(whole, n)
    else:
        pw = position_counts(whole, n)
        balanced = bool(whole) and bool(np.all(pw == pw[0, 0]))
    return {"rows": rows, "sequences": sequences, "design": kind, "conditions": list(conditions),
            "seed": int(seed), "complete_blocks": complete, "incomplete": len(rows) - complete * len(sequences),
            "balanced": balanced, "position_counts": pos.tolist(), "carryover_counts": carry.tolist()}


def markdown(result: dict) -> str:
    """The assignment as a Markdown table for the lab (participant, sequence, condition at each position)."""
    n = len(result["conditions"])
    lines = [f"# Condition orders: {result['design']} design, {n} conditions, seed {result['seed']}", "",
             "| participant | sequence | " + " | ".join(f"{p + 1}." for p in range(n)) + " |",
             "|---|---|" + "---|" * n]
    for r in result["rows"]:
        lines.append(f"| {r['participant']} | {r['sequence']} | " + " | ".join(r["order"]) + " |")
    lines.append("")
    if result["incomplete"]:
        lines.append(f"The last {result['incomplete']} participant(s) form an incomplete block: order is balanced "
                     f"only over the first {result['complete_blocks'] * len(result['sequences'])}.")
    return "\n".join(lines) + "\n"


def order_for(path, subject: str, conditions: list[str], where: str) -> tuple[int, list[str]]:
    """The sequence number and order of conditions the design file at ``path`` assigns to ``subject``.

    Raises
    ------
    ValueError
        The file is unreadable or damaged, lists other conditions, or not the subject (naming ``where`` and the
        file).
    """
    text = read_text_utf8(path, "design")
    rows = parse_design(text, path)
    if sorted(rows[0]["order"]) != sorted(conditions):
        raise ValueError(f"{where}: design {path} orders the conditions {sorted(rows[0]['order'])}, but the "
                         f"experiment has {sorted(conditions)}")
    for r in rows:
        if r["participant"] == subject:
            return r["sequence"], r["order"]
    raise ValueError(f"{where}: subject {subject!r} is not in the design {path} (add the participant and run "
                     f"python -m study design again, or give the order with `order`)")


__all__ = ["DESIGN_CSV", "assign", "check_conditions", "format_design", "markdown", "order_for", "read_participants"]
