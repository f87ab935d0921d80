"""``renderer timing-check``: a cyclictest-like check of this machine as the servo loop would run.

The check runs the servo loop itself (``renderer.ServoLoop``, same pacing and law) in its own process with the
real-time policy (``renderer.process.run_in_process``, ``plumbing.rtpolicy``), the motor disabled, for
``duration_s``; by default on :class:`QuietDevice` (a device that answers at once and holds still, so what is
measured is the machine: scheduling, wake-ups, the loop's own cost), or through a real device (the study checks
its hardware link this way: zero current, and the link's round trip and gaps join the verdict). Optional
synthetic load: ``load_cores`` processes busy-looping at normal priority beside it, unpinned (the worst case a
browser or a compiler would give). The verdict is :func:`renderer.timing_verdict.verdict`.
"""

from __future__ import annotations

import os
import subprocess
import sys

from devices.base import Device, DeviceInfo, DeviceState

from .config import RendererConfig
from .process import run_in_process
from .timing_verdict import DEFAULT_THRESHOLDS, TimingThresholds, period_figures, verdict

#: a check's device when none is named: the loop alone on this machine
QUIET_DEVICE = "quiet"
#: the bounds of a check (its log is preallocated: ~112 bytes a tick, kept in the servo process and sent back
#: whole): the highest servo rate (Hz, ten times the thesis's 10 kHz), the longest check (s), and the most ticks
#: of one check (rate x duration: 5 min at 10 kHz, about 340 MB of log), the most busy-loop processes
MAX_RATE_HZ = 100_000.0
MAX_DURATION_S = 3600.0
MAX_TICKS = 3_000_000
MAX_LOAD_CORES = 64
#: a busy-loop load process: killed by the kernel (SIGKILL) when the thread that started it dies, however it
#: dies (``prctl(PR_SET_PDEATHSIG)``, as :func:`plumbing.pools.worker_dies_with_parent`), and gone at once if
#: that happened before it asked; then it ignores Ctrl-C (the check stops it) and spins
LOAD_CODE = ("import ctypes, os, signal, sys\n"
             "ctypes.CDLL(None).prctl(1, int(signal.SIGKILL), 0, 0, 0)\n"
             "if os.getppid() != int(sys.argv[1]):\n"
             "    sys.exit(0)\n"
             "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
             "while True:\n"
             "    pass\n")


def check_size(duration_s: float, rate_hz: float, load_cores: int, flags=("--duration-s", "--rate-hz",
                                                                          "--load-cores")) -> None:
    """Refuse a check whose time or memory would be unbounded (``--rate-hz 1e9`` once had the kernel's OOM
    killer take the process), naming the flag and the bound.

    Raises
    ------
    ValueError
        A value outside :data:`MAX_RATE_HZ`, :data:`MAX_DURATION_S`, :data:`MAX_LOAD_CORES`, or more than
        :data:`MAX_TICKS` ticks in all.
    """
    duration_flag, rate_flag, load_flag = flags
    if not 0 < rate_hz <= MAX_RATE_HZ:
        raise ValueError(f"{rate_flag} must be > 0 and at most {MAX_RATE_HZ:g} Hz, got {rate_hz:g}")
    if not 0 < duration_s <= MAX_DURATION_S:
        raise ValueError(f"{duration_flag} must be > 0 and at most {MAX_DURATION_S:g} s, got {duration_s:g}")
    if not 0 <= load_cores <= MAX_LOAD_CORES:
        raise ValueError(f"{load_flag} must be 0..{MAX_LOAD_CORES}, got {load_cores}")
    ticks = (duration_s + 1.0) * rate_hz
    if ticks > MAX_TICKS:
        raise ValueError(f"{duration_flag} x {rate_flag} must be at most {MAX_TICKS} ticks (the check's log is kept "
                         f"whole: {MAX_TICKS / 10000.0 / 60.0:g} min at 10 kHz), got {duration_s:g} s at "
                         f"{rate_hz:g} Hz; run a shorter check, or several")


class QuietDevice(Device):
    """A streaming device that answers at once and holds still above the wall: the timing check's default.

    Parameters
    ----------
    rate_hz : float
        Its servo rate (Hz). Marked simulated, so the loop's watchdog counts a stall instead of stopping the
        check: the check reports the whole run.
    """

    def __init__(self, rate_hz: float = 10000.0) -> None:
        super().__init__()
        # Table 3.1's device (gear 15, 0.15 m handle, 2000 lines): only the limits matter, the motor is off
        self.info = DeviceInfo(name="timing-check", encoder_lines=2000, gear_ratio=15.0, handle_length_m=0.15,
                               torque_constant_Nm_A=0.0235, current_continuous_A=1.26, current_peak_A=4.0,
                               current_amplifier_A=4.0, servo_rate_hz=float(rate_hz), simulated=True)
        self._state = DeviceState(position_m=0.01, grip_N=2.0)
        self._dt = 1.0 / float(rate_hz)

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def read(self) -> DeviceState:
        """The same still state, its device time advanced one period per read."""
        self._state.t_s += self._dt
        return self._state

    def _send_current(self, current_A: float) -> None:
        pass


def quiet_device(rate_hz: float) -> QuietDevice:
    """A :class:`QuietDevice` (module-level, so the spawned servo process can unpickle the factory)."""
    return QuietDevice(rate_hz)


class _QuietFactory:
    """Picklable zero-argument factory of a :class:`QuietDevice` at a rate."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz

    def __call__(self) -> QuietDevice:
        return quiet_device(self.rate_hz)


def start_load(n: int) -> list:
    """Start ``n`` busy-looping Python processes at normal priority (unpinned), which die with this one
    (:data:`LOAD_CODE`); returns their Popen handles. Call it from the thread that outlives them (the main one)."""
    return [subprocess.Popen([sys.executable, "-c", LOAD_CODE, str(os.getpid())], stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(int(n))]


def stop_load(procs: list) -> None:
    """Kill the load processes started by :func:`start_load` (each by its own handle) and reap them."""
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        p.wait()


def run_check(duration_s: float = 30.0, rate_hz: float = 10000.0, load_cores: int = 0,
              device: str = QUIET_DEVICE, thresholds: TimingThresholds = DEFAULT_THRESHOLDS,
              realtime_policy: bool = True, watchdog_s: float | None = None) -> dict:
    """Run the check and return its record (what ``timing_check.json`` holds).

    Parameters
    ----------
    duration_s : float
        Length of the paced run (s).
    rate_hz : float
        Servo rate of the quiet device (Hz); a real device runs at its own rate.
    load_cores : int
        Busy-looping processes beside the loop (:func:`start_load`).
    device : str
        ``"quiet"`` (:class:`QuietDevice`) or a device string (``serial:...``): motor disabled, zero current.
    thresholds : TimingThresholds
    realtime_policy : bool
        Ask for the real-time policy, as the servo process does.
    watchdog_s : float, optional
        The loop's watchdog bound (``RendererConfig.watchdog_overrun_s``) for a real device: use the session's,
        so a stall that would stop the session stops the check. A check that does not run its whole length
        (watchdog, disconnect, ...) fails.

    Returns
    -------
    dict
        ``device``, ``duration_s``, ``rate_hz``, ``load_cores``, ``stop_reason``, ``policy`` (what the OS
        granted, plumbing.rtpolicy), ``figures`` (:func:`renderer.timing_verdict.period_figures`),
        ``link`` (a hardware link's statistics, or None), ``verdict``.
    """
    check_size(duration_s, rate_hz, load_cores, ("duration_s", "rate_hz", "load_cores"))
    quiet = device == QUIET_DEVICE
    extra = {} if watchdog_s is None else {"watchdog_overrun_s": float(watchdog_s)}
    cfg = RendererConfig(motor_enabled=False, stiffness_N_m=0.0, rate_hz=float(rate_hz) if quiet else None,
                         log_capacity_s=float(duration_s) + 1.0, **extra)
    loads = start_load(load_cores)
    try:
        result = run_in_process(_QuietFactory(rate_hz) if quiet else device, cfg, None, duration_s=duration_s,
                                realtime=True, realtime_policy=realtime_policy)
    finally:
        stop_load(loads)
    if result.stop_reason == "interrupted":   # Ctrl-C: no verdict (an interrupted check is neither pass nor fail)
        raise KeyboardInterrupt
    rate = float(result.timing["rate_hz"])
    figures = period_figures(result.log["wall_ns"], rate)
    link = result.timing.get("link")
    judged = verdict(figures, thresholds, link=link)
    if result.stop_reason != "duration":  # cut short (watchdog, disconnect): the session would be too
        judged["failed"].insert(0, f"the check stopped early: {result.stop_reason}"
                                   + (f" ({result.error})" if result.error else ""))
        judged["met"] = False
    return {"device": device, "duration_s": float(duration_s), "rate_hz": rate, "load_cores": int(load_cores),
            "stop_reason": result.stop_reason, "policy": result.timing.get("policy"), "figures": figures,
            "link": link, "verdict": judged}


def format_report(rec: dict) -> str:
    """The check's record as the lines ``timing-check`` prints: histogram, figures, policy, verdict."""
    f, pol, v = rec["figures"], rec.get("policy") or {}, rec["verdict"]
    lines = [f"timing check: {rec['device']} at {rec['rate_hz']:g} Hz for {rec['duration_s']:g} s, "
             f"{rec['load_cores']} busy load process(es); stop: {rec['stop_reason']}",
             f"policy: {pol.get('policy', '?')} priority {pol.get('priority', 0)}, mlockall "
             f"{'yes' if pol.get('mlockall') else 'no'}, CPU {pol.get('affinity')}, RT throttling "
             f"{pol.get('rt_runtime_us')}/{pol.get('rt_period_us')} us"
             + (f", spin {pol['spin_margin_us']:g} us" if "spin_margin_us" in pol else ""),
             "period error histogram (us):"]
    edges, counts = f["histogram"]["edges_us"], f["histogram"]["counts"]
    total = max(1, sum(counts))
    for k, c in enumerate(counts):
        hi = edges[k + 1]
        label = f"{edges[k]:>7g} - {hi:<7g}" if hi != "inf" else f"{edges[k]:>7g} +      "
        bar = "#" * int(round(40 * c / total))
        lines.append(f"  {label} {c:>9d} {bar}")
    lines.append(f"periods {f['periods']}: p50 {f['period_p50_us']:.1f} us; error p50/p99/p99.9/max "
                 f"{f['period_error_p50_us']:.1f}/{f['period_error_p99_us']:.1f}/{f['period_error_p999_us']:.1f}/"
                 f"{f['period_error_max_us']:.1f} us; longest period {f['period_max_us']:.1f} us; "
                 f"overruns {f['overruns']}")
    link = rec.get("link")
    if link:
        ms = (lambda x: "-" if x is None else f"{1000 * x:.2f}")
        lines.append(f"link: round trip median/p99/max {ms(link.get('rtt_median_s'))}/{ms(link.get('rtt_p99_s'))}/"
                     f"{ms(link.get('rtt_max_s'))} ms, longest gap {ms(link.get('longest_gap_s'))} ms, "
                     f"{link.get('losses', 0)} lost, {link.get('crc_errors', 0)} CRC errors")
    th = v["thresholds"]
    limits = (f"p99 <= {th['period_error_p99_us']:g} us, p99.9 <= {th['period_error_p999_us']:g} us, "
              f"no period > {th['max_period_ms']:g} ms")
    if v["met"] is None:
        lines.append(f"verdict: NOT JUDGED (too few periods) against {limits}")
    elif v["met"]:
        lines.append(f"verdict: PASS ({limits})")
    else:
        lines.append(f"verdict: FAIL: {'; '.join(v['failed'])}")
    return "\n".join(lines)
