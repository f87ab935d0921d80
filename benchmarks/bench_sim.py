"""Simulated device speed: servo ticks per second (all internal substeps) and the real-time factor.

Figures: for the nonlinear (Table 3.1) and the LTI (Phantom-like) models,
(a) the numba kernel called once per 10 kHz tick, (b) the full device path
``read()`` + ``command()`` as the renderer uses it. Medians of several runs;
the target is >= 50x real time for the nonlinear device on one core.
Rates are given from CPU time of this process (what one core delivers, robust
to other processes on a shared machine) and from wall-clock time.
"""

from __future__ import annotations

import statistics
import time

from devices.sim import SimDevice, TapTrajectory
from devices.sim import kernel as K

N_TICKS = 20000
REPEATS = 7


def _median_rate(fn) -> tuple[float, float]:
    """Median (CPU-time rate, wall-clock rate) in ticks/s."""
    cpu, wall = [], []
    for _ in range(REPEATS):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        c1, w1 = time.process_time(), time.perf_counter()
        cpu.append(N_TICKS / max(c1 - c0, 1e-9))
        wall.append(N_TICKS / (w1 - w0))
    return statistics.median(cpu), statistics.median(wall)


def main() -> dict:
    results = {}
    for spec, label in ((None, "nonlinear"), ("lti", "lti")):
        dev = SimDevice.from_spec(spec)
        dev.set_sample("wood_on_foam")
        dev.set_user(TapTrajectory([0.05, 0.1, 0.2], n_taps=30), grip_N=2.0)
        fs = dev.info.servo_rate_hz
        n_sub = int(dev._p[K.P_NSUB])
        tick, s, p, rs, traj, grip = K.tick, dev._s, dev._p, dev._rs, dev._traj, dev._grip

        def kernel_only():
            for k in range(N_TICKS):
                tick(s, p, rs, traj, grip, k, 0.1)

        def device_path():
            read, command = dev.read, dev.command
            for _ in range(N_TICKS):
                read()
                command(0.1)

        kernel_only()
        device_path()                                   # warm up (numba cache load)
        r_kernel, w_kernel = _median_rate(kernel_only)
        r_device, w_device = _median_rate(device_path)
        results[label] = {"kernel_ticks_per_s": r_kernel, "device_ticks_per_s": r_device,
                          "realtime_factor": r_device / fs, "us_per_tick": 1e6 / r_device,
                          "wall_device_ticks_per_s": w_device, "wall_realtime_factor": w_device / fs,
                          "substeps_per_tick": n_sub}
        print(f"   {label:9s}: kernel {r_kernel:,.0f} ticks/s, read()+command() {r_device:,.0f} ticks/s "
              f"= {r_device / fs:.0f}x real time at {fs:g} Hz ({1e6 / r_device:.2f} us/tick CPU; "
              f"{n_sub} substeps of {1e6 / fs / n_sub:.0f} us); wall clock {w_device:,.0f} ticks/s "
              f"= {w_device / fs:.0f}x", flush=True)
    ok = results["nonlinear"]["realtime_factor"] >= 50
    print(f"   nonlinear >= 50x real time (CPU time, one core, default person): {'yes' if ok else 'NO'}")
    results["tap_setup"] = tap_setup()
    return results


def tap_setup() -> dict:
    """Set-up cost of a simulated tapping hand per tap (target: linear in the number of taps).

    Times ``TapTrajectory(...)`` plus ``set_user`` (sampling the plan and the
    grip onto the 10 kHz grid) for 10 taps and for 400 taps (the set-up of
    ``renderer run --taps 10`` and ``--taps 400``), medians of 5, and prints
    the per-tap cost ratio (target <= 1, with 20 % allowance for timing noise).
    """
    dev = SimDevice()
    out = {}
    for n in (10, 400):
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            dev.set_user(TapTrajectory(0.1, n_taps=n), grip_N=2.0)
            times.append(time.perf_counter() - t0)
        out[n] = statistics.median(times) / n
    ratio = out[400] / out[10]
    print(f"   tap set-up: {out[10] * 1e3:.2f} ms/tap (10 taps), {out[400] * 1e3:.2f} ms/tap (400 taps): "
          f"ratio {ratio:.2f} (target <= 1.2: {'yes' if ratio <= 1.2 else 'NO'})")
    return {"s_per_tap_10": out[10], "s_per_tap_400": out[400], "ratio": ratio}


if __name__ == "__main__":
    main()
