"""Hardware path over a real pty: streaming command->state round trip and rate, on-device telemetry rate.

The firmware emulator runs in a child process (its own core, like a
microcontroller); the host is SerialDevice. Targets: streaming
>= 1 kHz with p99 round trip < 1 ms.
"""

from __future__ import annotations

import os
import time

from devices.cli_hardware import measure_latency, percentiles_us, realtime_priority
from devices.firmware.emulator import start_emulator
from devices.hardware import wire_protocol as P
from devices.hardware.serial_device import SerialDevice
from stimuli.transients import Pulse


def _streaming(n: int = 5000, process: bool = True, rt_priority: int | None = None) -> dict:
    port, handle = start_emulator("streaming", process=process, rt_priority=rt_priority)
    try:
        with SerialDevice(port) as dev, realtime_priority(rt_priority) as note:
            return {"sched": note, **measure_latency(dev, n=n, warmup=500)}
    finally:
        handle.stop()


def _paced_1khz(duration_s: float = 2.0, rt_priority: int | None = None) -> dict:
    """A host loop paced at 1 kHz (sleep then spin): achieved rate and round trips."""
    port, handle = start_emulator("streaming", process=True, rt_priority=rt_priority)
    try:
        with SerialDevice(port) as dev, realtime_priority(rt_priority) as note:
            period = 1e-3
            n = int(duration_s / period)
            rtt = []
            dev.read()
            t_next = time.perf_counter()
            t0 = t_next
            for _ in range(n):
                t_next += period
                while True:
                    left = t_next - time.perf_counter()
                    if left <= 0:
                        break
                    if left > 3e-4:
                        time.sleep(left - 2.5e-4)
                t1 = time.perf_counter()
                dev.command(0.0)
                dev.read()
                rtt.append(time.perf_counter() - t1)
            rate_hz = n / (time.perf_counter() - t0)
            return {"sched": note, "rate_hz": rate_hz, **percentiles_us(rtt)}
    finally:
        handle.stop()


def _on_device(duration_s: float = 2.0, pace: str = "realtime") -> dict:
    port, handle = start_emulator("on-device", process=True, pace=pace)
    try:
        with SerialDevice(port, mode="on-device") as dev:  # native USB (INFO): a frame every tick
            dev.configure_rendering({"height_m": 0.0, "stiffness_N_m": 680.0, "damping_N_s_m": 0.0,
                                     "rearm_margin_m": 0.002},
                                    {"continuous_A": 1.26, "peak_A": 4.0, "amplifier_A": 4.0}, Pulse())
            n = 0
            t0 = time.perf_counter()
            first = dev.read().t_s
            while time.perf_counter() - t0 < duration_s:
                last = dev.read().t_s
                n += 1
            wall = time.perf_counter() - t0
            events = dev.pop_events()
            stats = dev.link_stats()
        return {"telemetry_hz": n / wall, "device_s_per_wall_s": (last - first) / wall, "events": len(events),
                "seq_gaps": stats["seq_gaps"]}
    finally:
        handle.stop()


def _codec(n: int = 50_000) -> tuple[float, float]:
    """Host cost per frame (us): parse + CRC + decode of a STATE frame, encode of a CURRENT frame."""
    frame = P.encode_frame(P.STATE, 1, P.encode_state(1, 2, 3, 4, 0, 5, 6))
    parser = P.FrameParser()
    t0 = time.perf_counter()
    for _ in range(n):
        P.decode_state(parser.feed(frame)[0].payload)
    t1 = time.perf_counter()
    for k in range(n):
        P.encode_frame(P.CURRENT, k & 0xFF, P.encode_current(0.5))
    t2 = time.perf_counter()
    return (t1 - t0) / n * 1e6, (t2 - t1) / n * 1e6


def main() -> None:
    parse_us, encode_us = _codec()
    print(f"host codec: parse + CRC + decode STATE {parse_us:.2f} us/frame, encode CURRENT {encode_us:.2f} us/frame")

    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (p99 is sensitive to other processes)")
    for process, rt in ((True, None), (True, 20), (False, None)):
        s = _streaming(process=process, rt_priority=rt)
        where = "emulator in a child process" if process else "emulator in a thread of the host process"
        print(f"streaming, free-running, {where}, {s['sched']} ({s['n']} round trips): "
              f"rate {s['rate_hz']:.0f} Hz, round trip "
              f"median {s['median_us']:.0f} us, p99 {s['p99_us']:.0f} us, max {s['max_us']:.0f} us "
              f"[target >= 1000 Hz, p99 < 1000 us]")
        print(f"  ping (no physics): median {s['ping']['median_us']:.0f} us, p99 {s['ping']['p99_us']:.0f} us")
    for rt in (None, 20):
        p = _paced_1khz(rt_priority=rt)
        print(f"streaming, paced at 1 kHz, {p['sched']}: achieved {p['rate_hz']:.1f} Hz, round trip median "
              f"{p['median_us']:.0f} us, p99 {p['p99_us']:.0f} us")
    for pace, what in (("realtime", "real time"), ("host", "paced by the host, as the tests run it")):
        o = _on_device(pace=pace)
        print(f"on-device rendering (emulated firmware at 10 kHz, {what}): telemetry {o['telemetry_hz']:.0f} Hz, "
              f"device time / wall time {o['device_s_per_wall_s']:.3f}, {o['events']} contact events, "
              f"{o['seq_gaps']} lost frames")


if __name__ == "__main__":
    main()
