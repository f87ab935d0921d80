"""Telling a loaded machine's stall from a fault, for the tests of real-time sessions on the emulated devices.

A shared 2-core machine running two suites can keep a process (or one of its threads) off the CPU for tens or
hundreds of milliseconds. The device then holds the last force while the emulated hand moves on, and the safety
rules rightly act: the passivity observer stops the wall, or a driver declares a silent device gone. Those rules
have their own tests; a test about a device path runs again when the run's own records show such a stall, and a
run without one must pass.
"""

from __future__ import annotations

import ctypes

#: a tick period, link gap or device-thread period longer than this (us) is a stall of the machine
STALL_US = 20_000.0


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
