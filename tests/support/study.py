"""Shared helpers for the study tests (sessions are short: 1 s tapping windows, so a session takes seconds)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from study.__main__ import main

QUICK_PROTOCOL = """
tap_window_s = 1.0
familiarization_window_s = 1.0
homing_after_s = 0.8
homing_before_max_s = 0.2
"""

MISTAKES = """
p_reject = 0.15
p_overpower = 0.15
p_hard_tap = 0.4
familiarization_taps_min = 2
familiarization_taps_max = 4
"""


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def run_study(*args) -> int:
    args = [str(a) for a in args]
    if "--resume" in args:   # device and participant come from the session
        return main(["run", "--quiet", *args])
    return main(["run", "--device", "sim", "--participant", "simulated", "--quiet", *args])


def quick_args(tmp: Path, subject: str, seed: int, *extra, mistakes: bool = False) -> list:
    proto = write(tmp / "quick_protocol.toml", QUICK_PROTOCOL)
    args = ["--subject", subject, "--seed", seed, "--out", tmp / "DATA", "--protocol", proto, *extra]
    if mistakes:
        args += ["--participant-config", write(tmp / "mistakes.toml", MISTAKES)]
    return args


def read_rows(folder: Path) -> list[dict]:
    with open(folder / "trials.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def read_session(folder: Path) -> dict:
    return json.loads((folder / "session.json").read_text())
