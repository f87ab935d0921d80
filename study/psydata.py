"""trials.csv of a psychophysics session (issue 34): one row per trial, in the contract's columns.

The subject folder, its lock, ``session.json``, ``schedule.jsonl`` and the trace files are the realism
study's (:class:`study.data.SessionStore`); only trials.csv's columns differ (:data:`PSY_COLUMNS`, docs/study.md
"Psychophysics sessions"). A row is appended, flushed and fsynced before the next trial starts; on ``--resume``
a last line torn by a crash is kept in ``trials.csv.torn`` and truncated away, as for the realism study.
"""

from __future__ import annotations

import json
import os

from .data import crash_point, cut_torn_tail

def read_psy_trials(store) -> list[dict]:
    """The trials on disk, in order (``store``: :class:`study.data.SessionStore` of the subject, whose
    ``rows`` is :data:`plumbing.studyfiles.FORCED_CHOICE`)."""
    return store.read_trials()


def append_psy_trial(store, row: dict) -> None:
    """Append one trial row to the subject's trials.csv, flush and fsync it (on disk when this returns)."""
    store.append_trial(row)


def state_path(store):
    """``DATA/<subject>/staircase_state.jsonl``: one line per trial of an adaptive session."""
    return store.dir / "staircase_state.jsonl"


def append_state(store, line: dict) -> None:
    """Append one trial's staircase state (a JSON line), flush and fsync it."""
    with open(state_path(store), "a", encoding="utf-8") as fh:
        fh.write(json.dumps(line) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    crash_point(f"staircase state written: trial {line['trial']}")


def repair_states(store) -> int:
    """Count the whole state lines on disk (``--resume``); a last line torn by a crash is moved to
    ``staircase_state.jsonl.torn`` (the resumed session rewrites it from the trials), with a note.

    Returns
    -------
    int
        Whole lines (trials whose state is on disk).
    """
    path = state_path(store)
    if not path.exists():
        return 0
    data = path.read_bytes()
    lines = data.split(b"\n")
    whole = 0
    for line in lines[:-1]:
        try:
            json.loads(line)
        except ValueError:
            break
        whole += 1
    keep = b"".join(ln + b"\n" for ln in lines[:whole])
    if keep != data:
        cut_torn_tail(path, data, len(keep), whole + 1, then="it will be written again from trials.csv; kept it in")
    return whole
