"""fw-sim: simavr's speed bare and in the harness (x real time), and a 10 s lockstep streaming run over it.

Whether fw-sim can keep real time on one core or must run in lockstep. Figures:
``bare``: the firmware ELF on libsimavr with nothing attached (MCU cycles per CPU second / 16 MHz);
``harness``: the fw-sim harness (paddle physics every 10 us, interrupt and tick instrumentation per
instruction), no host attached, per CPU second and per wall second; ``lockstep``: ``renderer``'s servo
loop streaming for 10 s of device time at the lockstep rate (1 kHz), with watchdog stops and overruns.
Medians of ``REPEATS`` runs. The machine's load is whatever it is: the wall-clock figures show it.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from devices.firmware import fw_sim
from devices.registry import make_device
from renderer.config import RendererConfig
from renderer.loop import ServoLoop

REPEATS = 3
SIM_S = 2.0

# the firmware on libsimavr with no hooks: what simavr itself costs (the harness's overhead is the rest)
BARE_C = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "sim_avr.h"
#include "sim_elf.h"
int main(int argc, char **argv) {
    elf_firmware_t fw; memset(&fw, 0, sizeof fw);
    if (argc < 3 || elf_read_firmware(argv[1], &fw)) return 2;
    avr_t *avr = avr_make_mcu_by_name("atmega328p");
    avr_init(avr);
    fw.frequency = 16000000; avr_load_firmware(avr, &fw); avr->frequency = 16000000;
    unsigned long long n = strtoull(argv[2], NULL, 0);
    struct timespec a, b; clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
    while (avr->cycle < n) { int s = avr_run(avr); if (s == cpu_Done || s == cpu_Crashed) return 3; }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
    printf("%llu %.6f\n", (unsigned long long)avr->cycle, (b.tv_sec - a.tv_sec) + (b.tv_nsec - a.tv_nsec) * 1e-9);
    return 0;
}
"""


def _bare(b: fw_sim.Build, tmp: Path) -> float:
    """simavr alone: x real time per CPU second."""
    src, exe = tmp / "bare.c", tmp / "bare"
    if not exe.exists():
        src.write_text(BARE_C)
        cflags, ldflags = fw_sim.simavr_flags()
        subprocess.run([fw_sim.tool("cc"), "-O2", *cflags, "-o", str(exe), str(src), *ldflags], check=True,
                       capture_output=True)
    out = subprocess.run([str(exe), str(b.elf), str(int(SIM_S * fw_sim.F_CPU_HZ))], check=True, capture_output=True,
                         text=True).stdout.splitlines()[-1].split()  # libsimavr prints "Loaded ..." first
    return int(out[0]) / float(out[1]) / fw_sim.F_CPU_HZ


def _harness(b: fw_sim.Build, tmp: Path) -> tuple[float, float]:
    """The fw-sim harness with no host: x real time per CPU second and per wall second."""
    stats = tmp / "stats.json"
    cmd = fw_sim._harness_cmd(b, stats, pace="fast", max_sim_s=SIM_S)
    t0, c0 = time.perf_counter(), os.times()
    subprocess.run(cmd, check=True, capture_output=True, timeout=600)
    wall, c1 = time.perf_counter() - t0, os.times()
    cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
    sim_s = json.loads(stats.read_text())["sim_time_s"]
    return sim_s / cpu, sim_s / wall


def _lockstep(duration_s: float = 10.0) -> dict:
    """A streaming run of ``duration_s`` device seconds over fw-sim in lockstep."""
    with make_device("fw-sim") as dev:
        res = ServoLoop(dev, RendererConfig()).run(duration_s=duration_s)
        link, handle = dev.link_stats(), dev.handle
    ls = handle.final_stats["lockstep"]  # written as the harness stopped
    tm = res.timing
    return {"stop": res.stop_reason, "ticks": tm["ticks"], "device_s": tm["sim_time_s"], "wall_s": tm["wall_time_s"],
            "x_real_time": tm["realtime_factor"], "overruns": tm["overruns"], "watchdog_trips": link["watchdog_trips"],
            "events": len(res.events), "late_replies": ls["late_replies"], "harness_waits": ls["waits"],
            "harness_wait_wall_s": ls["wait_wall_s"], "lockstep_timeouts": ls["timeouts"]}


def main() -> None:
    """Print the medians (see the module doc)."""
    b = fw_sim.build()
    with tempfile.TemporaryDirectory(prefix="bench-fw-sim-") as tmp:
        bare = [_bare(b, Path(tmp)) for _ in range(REPEATS)]
        harness = [_harness(b, Path(tmp)) for _ in range(REPEATS)]
    med = statistics.median
    cpu, wall = med(h[0] for h in harness), med(h[1] for h in harness)
    print(f"   simavr bare: {med(bare):.2f}x real time per CPU second ({med(bare) * 16:.0f} M cycles/s; "
          f"runs {', '.join(f'{v:.2f}' for v in bare)})")
    print(f"   fw-sim harness, no host: {cpu:.2f}x real time per CPU second, {wall:.2f}x per wall second "
          f"(harness overhead {med(bare) / cpu:.1f}x simavr alone)")
    runs = [_lockstep() for _ in range(REPEATS)]
    for r in runs:
        print(f"   lockstep 10 s streaming run: stop {r['stop']}, {r['ticks']} ticks, {r['device_s']:.3f} s device time "
              f"in {r['wall_s']:.1f} s wall ({r['x_real_time']:.2f}x), overruns {r['overruns']}, watchdog trips "
              f"{r['watchdog_trips']}, lockstep timeouts {r['lockstep_timeouts']}, {r['events']} events, "
              f"{r['late_replies']} late replies")
    print(f"   lockstep median: {med(r['wall_s'] for r in runs):.1f} s wall for 10 s of device time "
          f"({med(r['x_real_time'] for r in runs):.2f}x real time); watchdog stops "
          f"{sum(r['stop'] != 'duration' for r in runs)} of {len(runs)} runs")
