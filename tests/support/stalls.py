"""Telling a loaded machine's stall from a fault, for the tests of real-time sessions on the emulated devices.

A shared 2-core machine running two suites can keep a process (or one of its threads) off the CPU for tens or
hundreds of milliseconds. The device then holds the last force while the emulated hand moves on, and the safety
rules rightly act: the passivity observer stops the wall, or a driver declares a silent device gone. Those rules
have their own tests; a test about a device path runs again when the run's own records show such a stall, and a
run without one must pass.
"""

from __future__ import annotations

import csv
import ctypes
import json
from pathlib import Path

import numpy as np

#: a tick period, link gap or device-thread period longer than this (us) is a stall of the machine
STALL_US = 20_000.0
#: a tap's incoming speed is fitted over the ticks just before contact: a tick this many periods late within
#: :data:`TAP_WINDOW_S` before the impact (6.65 ms at 1 kHz was seen: the position jumped 0.86 mm in one tick,
#: and the tap read 0.56 m/s for 0.1) measures the scheduler, not the hand
TAP_LATE_PERIODS = 3.0
TAP_WINDOW_S = 0.02


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
    """The fake HD library's scheduler thread went longer than :data:`STALL_US` between two ticks."""
    return lib is not None and fake_hd_stats(lib)[1] * 1e-3 > STALL_US


def tap_across_stall(t_s, event_t_s, fs_hz: float) -> bool:
    """A tap whose speed was measured across a late tick: within :data:`TAP_WINDOW_S` before an impact at
    ``event_t_s`` (s), two successive ticks of ``t_s`` (s) more than :data:`TAP_LATE_PERIODS` periods apart."""
    t = np.asarray(t_s, dtype=float)
    late_s = TAP_LATE_PERIODS / float(fs_hz)
    for te in np.atleast_1d(np.asarray(event_t_s, dtype=float)):
        seg = t[(t >= te - TAP_WINDOW_S) & (t <= te)]
        if seg.size >= 2 and float(np.diff(seg).max()) > late_s:
            return True
    return False


def run_stalled(out: Path, lib: str | None = None) -> bool:
    """A ``renderer run`` folder's records show a stall: a tick period or link gap longer than :data:`STALL_US`
    (``run.json``), a tap measured across a late tick (:func:`tap_across_stall`, ``log.npz`` and
    ``events.csv``), or, on the Touch, the fake HD library's scheduler thread (:func:`fake_hd_stalled`)."""
    if not (out / "run.json").is_file():
        return fake_hd_stalled(lib)
    run = json.loads((out / "run.json").read_text())
    gap_s = (run.get("link") or {}).get("longest_gap_s") or 0.0
    if float(run.get("period_max_us") or 0.0) > STALL_US or gap_s * 1e6 > STALL_US or fake_hd_stalled(lib):
        return True
    if (out / "log.npz").is_file() and (out / "events.csv").is_file():
        with open(out / "events.csv") as fh:
            events = [float(e["t_s"]) for e in csv.DictReader(fh)]
        with np.load(out / "log.npz") as z:
            return bool(events) and tap_across_stall(z["t_s"], events, float(run["rate_hz"]))
    return False


def session_stalled(folder: Path, lib: str | None = None) -> bool:
    """A study session folder's tapping windows show a stall: a trace whose longest tick period exceeds
    :data:`STALL_US`, a tap measured across a late tick (:func:`tap_across_stall`), or, on the Touch, the fake HD library's scheduler thread (:func:`fake_hd_stalled`)."""
    for f in sorted((folder / "traces").glob("*.npz")):
        with np.load(f) as z:
            if "timing_period_max_us" in z and float(z["timing_period_max_us"]) > STALL_US:
                return True
            if "event_t_s" in z and tap_across_stall(z["t_s"], z["event_t_s"], float(z["fs_hz"])):
                return True
    return fake_hd_stalled(lib)
