"""3-DOF device adapters on their emulators: force->state transaction time per tick (median, p99) and rate.

Each adapter (devices/hardware/{haply,falcon,woodenhaptics,forcedimension,openhaptics}) is opened on its
built-in emulator (the Touch on the fake HD library when ``$HFAM_OPENHAPTICS_LIB`` names one) and runs
``read(); command_force()`` as fast as it goes for 3000 ticks; the figures are the adapter's own link
statistics (``link_stats()``: the same numbers ``renderer run`` writes to run.json). The emulators run in
this process (the Inverse3's behind a real pty, in a thread), so the figures include their share of the GIL.
"""

from __future__ import annotations

import os
import time

from devices.registry import make_device

DEVICES = ("inverse3:emulator", "falcon:emulator", "woodenhaptics:emulator", "dhd:emulator")


def _one(spec: str, n: int = 3000) -> dict:
    dev = make_device(spec + ("&" if "?" in spec else "?") + "axes=3")
    with dev:
        for _ in range(200):
            dev.read()
            dev.command_force(0.0, 0.0, 0.2)
        dev.restart_link_timing()
        t0 = time.perf_counter()
        for _ in range(n):
            dev.read()
            dev.command_force(0.0, 0.0, 0.2)
        elapsed = time.perf_counter() - t0
        link = dev.link_stats()
    return {"rate_hz": n / elapsed, "median_us": link["rtt_median_s"] * 1e6, "p99_us": link["rtt_p99_s"] * 1e6,
            "losses": link["losses"]}


def main() -> None:
    specs = list(DEVICES)
    if os.environ.get("HFAM_OPENHAPTICS_LIB"):
        specs.append("touch:Default Device")
    for spec in specs:
        r = _one(spec)
        print(f"   {spec:<26} transaction median {r['median_us']:7.1f} us, p99 {r['p99_us']:7.1f} us; "
              f"{r['rate_hz']:7.0f} ticks/s unpaced; {r['losses']} lost", flush=True)


if __name__ == "__main__":
    main()
