"""Telling a loaded machine's stall from a fault, for the tests of real-time sessions on the emulated devices.

A shared 2-core machine running two suites can keep a process (or one of its threads) off the CPU for tens or
hundreds of milliseconds. The device then holds the last force while the emulated hand moves on, and the safety
rules rightly act: the passivity observer stops the wall, or a driver declares a silent device gone. Those rules
have their own tests; a test about a device path runs again when the run's own records show such a stall, and a
run without one must pass.
"""

from __future__ import annotations

import ctypes
import json
import re
from pathlib import Path

import numpy as np

#: a tick period, link gap or device-thread period longer than this (us) is a stall of the machine
STALL_US = 20_000.0

#: the fake HD library's scheduler thread runs every 1 ms (the Touch's servo rate): a period longer than this (us),
#: five of its ticks missed, is a stall of the machine. Its device holds the last force through it while the emulated
#: hand presses on, so a stall shorter than :data:`STALL_US` already feeds the wall energy (a Touch session stopped as
#: unstable with every period under 20 ms; its longest period in a session was 3-5 ms on a quiet machine, 4-11 ms
#: with one core busy)
FAKE_HD_STALL_US = 5_000.0

#: a servo loop's watchdog stop, as its error message names it (renderer.loop, renderer.loop3)
_WATCHDOG_STOP = re.compile(r"tick \d+ period (\d+) us exceeds the watchdog bound")


def fake_hd_stats(lib: str, reset: bool = False) -> list[float]:
    """The fake HD library's own counters (tests/devices/hardware/contract/fake_hd/fake_hd.c, ``fakehd_stats``):
    ticks, the longest period of its 1 kHz scheduler thread (ns), the longest callback (ns), slow periods, ...
    The driver loads the same file, so this is its copy's state; ``reset`` zeroes the maxima first."""
    hd = ctypes.CDLL(lib)
    if reset:
        hd.fakehd_reset_stats()
    out = (ctypes.c_double * 10)()
    hd.fakehd_stats(out)
    return list(out)


def fake_hd_stalled(lib: str | None) -> bool:
    """The fake HD library's scheduler thread went longer than :data:`FAKE_HD_STALL_US` between two ticks."""
    return lib is not None and fake_hd_stats(lib)[1] * 1e-3 > FAKE_HD_STALL_US


def run_stalled(out: Path, lib: str | None = None) -> bool:
    """A ``renderer run`` folder's records show a stall: a tick period or link gap longer than :data:`STALL_US`
    (``run.json``), or, on the Touch, the fake HD library's scheduler thread (:func:`fake_hd_stalled`). (A late
    tick just before a tap is no stall: the laws' velocity rings go by the sample's own time, ``renderer.ring``.)"""
    if not (out / "run.json").is_file():
        return fake_hd_stalled(lib)
    run = json.loads((out / "run.json").read_text())
    gap_s = (run.get("link") or {}).get("longest_gap_s") or 0.0
    return float(run.get("period_max_us") or 0.0) > STALL_US or gap_s * 1e6 > STALL_US or fake_hd_stalled(lib)


def watchdog_stalled(message: str) -> bool:
    """``message`` (a command's error output) names a servo loop's watchdog stop after a tick period longer than
    :data:`STALL_US`: the machine held the loop off the CPU, and the watchdog (tested apart) rightly stopped it."""
    m = _WATCHDOG_STOP.search(message)
    return m is not None and float(m.group(1)) > STALL_US


def session_stalled(folder: Path, lib: str | None = None, message: str = "") -> bool:
    """A study session folder's tapping windows show a stall: a trace whose longest tick period exceeds
    :data:`STALL_US`, or, on the Touch, the fake HD library's scheduler thread (:func:`fake_hd_stalled`); or the
    session's error ``message`` names a watchdog stop of such a period (:func:`watchdog_stalled`: the window it
    stopped is not recorded)."""
    if watchdog_stalled(message):
        return True
    for f in sorted((folder / "traces").glob("*.npz")):
        with np.load(f) as z:
            if "timing_period_max_us" in z and float(z["timing_period_max_us"]) > STALL_US:
                return True
    return fake_hd_stalled(lib)
