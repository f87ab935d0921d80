"""Hardware mode of ``python -m renderer demo``: a person taps each rendering, one at a time.

The same comparison as the sim demo (section 4.5.5), with a person instead of
the simulated hand: first the real wood-on-foam sample (motor off), then each
virtual rendering over the placeholder. Each rendering's taps run in a servo
process of their own (the loop never shares an interpreter lock with the
scope or the prompts); the child copies every tick's time,
position and acceleration into a shared-memory ring that the parent shows as
a live scope: a matplotlib window when a display is available
(``$DISPLAY``/``$WAYLAND_DISPLAY`` and an interactive backend), otherwise a
one-line text scope. Each virtual tap is compared with the real tap whose
incoming velocity is closest (within 25 %); ``summary.csv`` then has one row
per tap (velocity and grip as measured).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from devices.registry import make_device
from plumbing.outdir import output_folder
from plumbing.stopsignals import Terminated, stop_on_signals
from stimuli import HfamLibrary

from ..config import RendererConfig
from ..process import SPAWN, end_child, servo_process, shared_sync
from . import figures as figs
from . import metrics as dm
from . import runs
from .hw_servo import MAX_EVENTS, RING, tap_child
from .report import DEMO_PRODUCTS, write_summary

MATCH_TOLERANCE = 0.25  # relative incoming-velocity difference allowed between a tap and its real reference
SPARK = " ▁▂▃▄▅▆▇█"


class TextScope:
    """One self-overwriting line: taps so far, position and a sparkline of the last 60 ms of acceleration."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stdout
        self.lines = 0

    def update(self, t: np.ndarray, x: np.ndarray, a: np.ndarray, n_events: int, n_taps: int) -> None:
        """Redraw the one-line scope: taps so far, time (s), position (mm) and a sparkline of |a| (m/s^2)."""
        if a.size == 0:
            return
        tail = np.abs(a[-min(a.size, 60):])
        top = max(float(tail.max()), 1e-9)
        spark = "".join(SPARK[min(8, int(8 * v / top + 0.5))] for v in tail[::2])
        self.stream.write(f"\r  taps {n_events}/{n_taps}  t {t[-1]:6.2f} s  position {x[-1] * 1e3:7.2f} mm  "
                          f"|a| {spark} {top:6.1f} m/s^2 ")
        self.stream.flush()
        self.lines += 1

    def close(self) -> None:
        """End the scope's line."""
        self.stream.write("\n")
        self.stream.flush()


class WindowScope:
    """A matplotlib window with the last ~0.4 s of handle acceleration and position."""

    def __init__(self):
        plt.ion()
        self.plt = plt
        self.fig, (self.ax_a, self.ax_x) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5))
        (self.la,) = self.ax_a.plot([], [], lw=0.8)
        (self.lx,) = self.ax_x.plot([], [], lw=0.8, color="C1")
        self.ax_a.set_ylabel("accel (m/s$^2$)")
        self.ax_x.set_ylabel("position (mm)")
        self.ax_x.set_xlabel("time (s)")
        self.fig.show()

    def update(self, t, x, a, n_events, n_taps) -> None:
        """Redraw the window with the last samples: time ``t`` (s), position ``x`` (m), acceleration ``a`` (m/s^2)."""
        if a.size < 2:
            return
        self.la.set_data(t, a)
        self.lx.set_data(t, x * 1e3)
        for ax, y in ((self.ax_a, a), (self.ax_x, x * 1e3)):
            ax.set_xlim(t[0], t[-1])
            lim = max(float(np.max(np.abs(y))), 1e-6) * 1.1
            ax.set_ylim(-lim if ax is self.ax_a else float(np.min(y)) - 0.1, lim)
        self.ax_a.set_title(f"taps {n_events}/{n_taps}")
        self.fig.canvas.draw_idle()
        self.fig.canvas.flush_events()

    def close(self) -> None:
        """Close the scope window."""
        self.plt.close(self.fig)


def make_scope(kind: str):
    """``window`` (needs a display and an interactive backend), ``text``, ``none`` or ``auto``."""
    if kind == "none":
        return None
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if kind in ("window", "auto") and has_display:
        try:

            if matplotlib.get_backend().lower() == "agg":
                matplotlib.use("TkAgg")
            return WindowScope()
        except Exception as exc:  # no Tk, no X server reachable: fall back, say why
            if kind == "window":
                print(f"note: no scope window ({exc}); using the text scope")
    return TextScope()


def _show_ring(scope, ring, k: int, n_events: int, n_taps: int) -> None:
    """Pass the last (up to 600) ticks of the shared ring (``k`` ticks written so far) to the scope."""
    n = min(k, RING, 600)
    if n > 1:
        idx = (np.arange(k - n, k) % RING) * 3
        buf = np.frombuffer(ring, dtype=np.float64)
        scope.update(buf[idx], buf[idx + 1], buf[idx + 2], n_events, n_taps)


def tap_session(spec: str, cfg, transient, n_taps: int, timeout_s: float, scope=None, scope_period_s: float = 0.05):
    """Run one rendering while a person taps; returns the :class:`renderer.RunResult`.

    The servo loop runs in a spawned child; the parent only reads the shared
    ring for the scope. Ctrl-C stops the run cleanly (the child zeroes the device); so do SIGTERM and
    SIGHUP, after which :class:`plumbing.stopsignals.Terminated` is raised (``partial_result``: the run).
    """
    ring = SPAWN.RawArray("d", 3 * RING)
    ring_n = SPAWN.RawValue("q", 0)
    events = SPAWN.RawArray("d", 1 + 2 * MAX_EVENTS)
    stop = shared_sync(SPAWN.Event)
    cfg = cfg.replace(until_every=1)
    proc, parent, child = servo_process(tap_child, (spec, cfg, transient, n_taps, runs.POST_S, timeout_s, ring, ring_n,
                                                    events, stop, os.getpid()), "demo-servo")
    msg = None
    terminated = None
    with stop_on_signals():
        try:
            proc.start()
            child.close()
            while msg is None:
                if parent.poll(scope_period_s):
                    msg = _recv(parent)
                    break
                if not proc.is_alive():
                    if parent.poll(0.5):
                        msg = _recv(parent)
                    break
                if scope is not None:
                    _show_ring(scope, ring, ring_n.value, int(events[0]), n_taps)
        except (KeyboardInterrupt, Terminated) as exc:
            if isinstance(exc, Terminated):
                terminated = exc
            stop.set()
            if proc.pid is not None and parent.poll(5.0):
                msg = _recv(parent)
        finally:
            if scope is not None:  # the final state of the ring, so the scope ends on what happened last
                _show_ring(scope, ring, ring_n.value, int(events[0]), n_taps)
            if proc.pid is not None:  # wait, then SIGTERM (the child zeroes and stops), SIGKILL last
                end_child(proc, parent, want_message=False)
            if scope is not None and hasattr(scope, "close") and isinstance(scope, TextScope):
                scope.close()
    if terminated is not None:
        terminated.partial_result = msg[1] if msg is not None else None
        raise terminated
    if msg is None:
        raise RuntimeError(f"servo process exited (code {proc.exitcode}) without a result")
    status, result, text = msg
    if status != "ok":
        if text.startswith(("ValueError", "FileNotFoundError")):
            raise ValueError(text.split(": ", 1)[1])
        raise RuntimeError(f"servo process failed: {text}")
    return result


def _recv(conn):
    try:
        return conn.recv()
    except EOFError:  # the child died without a word; reported by the caller
        return None


def traces_from_result(rendering: str, result, fs_hz: float, force_per_amp_N_A: float) -> list:
    """One :class:`renderer.demo.runs.TapTrace` per contact event of a run (velocity and grip as measured)."""
    out = []
    t = result.log["t_s"]
    for ev in result.events:
        acc = dm.cut_window(t, result.log["accel_m_s2"], ev.t_s, fs_hz, runs.PRE_S, runs.POST_S)
        cur = dm.cut_window(t, result.log["current_A"], ev.t_s, fs_hz, runs.PRE_S, runs.POST_S)
        tr = dm.cut_window(t, result.log["force_transient_N"], ev.t_s, fs_hz, runs.PRE_S, runs.POST_S)
        out.append(runs.TapTrace(rendering, float(ev.incoming_velocity_m_s), float(ev.grip_N),
                                 float(ev.incoming_velocity_m_s), acc, cur, float(ev.max_penetration_m),
                                 bool(ev.clipped), transient_current=tr / force_per_amp_N_A))
    return out


def nearest_reference(v_in: float, real: list):
    """The real tap with the closest incoming velocity, if within ``MATCH_TOLERANCE``; else None."""
    if not real:
        return None
    best = min(real, key=lambda r: abs(r.v_in_m_s - v_in))
    return best if abs(best.v_in_m_s - v_in) <= MATCH_TOLERANCE * max(v_in, 1e-9) else None


def run_hardware_demo(args, prompt=input, say=print) -> int:
    """The hardware demo (see module doc); ``prompt``/``say`` are injectable for scripted tests.

    SIGTERM/SIGHUP end it like Ctrl-C (the output zeroed, the taps so far kept and summarised), and it
    returns 128 + the signal's number."""
    with stop_on_signals():
        # a person's taps are not repeatable: an earlier session's results are refused before the device
        # opens; the results are written beside --out and swapped in whole (plumbing.outdir)
        folder = output_folder(args.out, bool(getattr(args, "force", False)), products=DEMO_PRODUCTS,
                           results="a demo's results").open()
        with folder:
            return _hardware_demo(args, prompt, say, folder.path, folder.out)


def _hardware_demo(args, prompt, say, out: Path, shown: Path) -> int:
    """The demo's body: results written into ``out`` (the staging folder of ``shown``, the --out named
    in what is printed)."""
    spec = args.device
    n_taps = args.taps or 5
    timeout_s = float(getattr(args, "timeout", None) or 120.0)
    dev = make_device(spec)  # validates the string; opened by the servo process, not here
    with dev:
        info = dev.info
    fs = float(info.servo_rate_hz)
    library = HfamLibrary.load(args.library) if args.library else None
    if library is not None:
        library.check_device(info, fs)  # refuse before anyone taps
    wanted = set(getattr(args, "renderings", None) or ())
    # the person taps one real sample, wood on foam (the reference); the sim's other real samples are not here
    valid = [r.name for r in runs.RENDERINGS if not r.is_real or r is runs.REAL]
    unknown = wanted - set(valid)
    if unknown:
        raise ValueError(f"--renderings: unknown {', '.join(sorted(unknown))}; valid: {', '.join(valid)}")
    todo = [runs.REAL] + [r for r in runs.RENDERINGS if not r.is_real and r.transient != "hfam_fixed_grip"]
    todo = [r for r in todo if not wanted or r.name in wanted or r.is_real]
    skipped = [r.name for r in todo if r.transient == "hfam" and library is None]
    todo = [r for r in todo if r.name not in skipped]
    say(f"Hardware demo on {info.name} ({spec}), {fs:g} Hz: {n_taps} taps on each of "
        f"{', '.join(r.name for r in todo)}.")
    if skipped:
        say(f"note: no --library given: skipping {', '.join(skipped)}")
    scope = make_scope(getattr(args, "scope", "auto"))
    traces: dict = {}
    code = 0
    # rows of the log per second: the servo rate, or on-device the telemetry's (servo rate / decimation)
    log_fs = fs
    try:
        for i, r in enumerate(todo):
            where = ("Put the wood-on-foam sample under the stylus (the motor stays off)" if r.is_real else
                     "Put the virtual-sample placeholder under the stylus")
            answer = prompt(f"[{i + 1}/{len(todo)}] {r.label}. {where}, then tap {n_taps} times at different "
                            f"speeds. Enter: start, s: skip, q: quit > ").strip().lower()
            if answer == "q":
                break
            if answer == "s":
                continue
            cfg = RendererConfig(stiffness_N_m=r.stiffness_N_m if not r.is_real else 0.0,
                                 motor_enabled=not r.is_real, log_capacity_s=timeout_s + 1.0,
                                 **({"watchdog_overrun_s": args.watchdog_overrun_s}
                                    if getattr(args, "watchdog_overrun_s", None) else {}))
            transient = runs.make_transient(r, library)
            result = tap_session(spec, cfg, transient, n_taps, timeout_s, scope)
            log_fs = float(result.timing.get("log_rate_hz", fs))  # the same device string: the same for every run
            traces[r.name] = traces_from_result(r.name, result, log_fs, info.force_per_amp_N_A)
            tm = result.timing
            say(f"    {len(traces[r.name])} taps recorded (stop: {result.stop_reason}); {tm.get('ticks', 0)} ticks in "
                f"{tm.get('wall_time_s', math.nan):.1f} s, period p99 {tm.get('period_p99_us', math.nan):.0f} us, "
                f"overruns {tm.get('overruns', 0)}")
    except (KeyboardInterrupt, EOFError):  # Ctrl-C / Ctrl-D at a prompt: keep what was tapped so far
        say("\ninterrupted: saving the taps recorded so far")
    except Terminated as exc:  # SIGTERM/SIGHUP: the servo process zeroed and stopped; keep what was tapped
        say(f"\n{exc}: saving the taps recorded so far")
        code = exc.code
    finally:
        if scope is not None and not isinstance(scope, TextScope):
            scope.close()
    real = traces.get(runs.REAL.name, [])
    rows = []
    for name, taps in traces.items():
        for tp in taps:
            ref = nearest_reference(tp.v_in_m_s, [x for x in real if x is not tp])
            runs.add_metrics(tp, None if ref is None else ref.accel, log_fs)
            m = tp.metrics
            rows.append({"rendering": name, "velocity_m_s": round(tp.v_in_m_s, 4), "grip_N": round(tp.grip_N, 3),
                         "peak_accel_m_s2": m["peak_accel_m_s2"], "dominant_freq_hz": m["dominant_freq_hz"],
                         "penetration_mean_m": tp.penetration_m, "nrmse": m["nrmse"],
                         "correlation": m["correlation"], "clipped": int(tp.clipped)})
    write_summary(rows, out / "summary.csv")
    say("")
    say(f"{'rendering':22s} {'taps':>4} {'v_in m/s':>9} {'peak a m/s2':>11} {'f_dom Hz':>8} {'pen mm':>7} {'NRMSE':>6} "
        f"{'corr':>6} {'clipped':>7}")
    for name, taps in traces.items():
        sel = [x for x in rows if x["rendering"] == name]
        if not sel:
            say(f"{name:22s} {0:4d}  (no taps)")
            continue

        def m(key, sel=sel):
            vals = [x[key] for x in sel if isinstance(x[key], (int, float)) and math.isfinite(x[key])]
            return float(np.mean(vals)) if vals else math.nan

        say(f"{name:22s} {len(sel):4d} {m('velocity_m_s'):9.3f} {m('peak_accel_m_s2'):11.1f} "
            f"{m('dominant_freq_hz'):8.0f} {m('penetration_mean_m') * 1e3:7.2f} {m('nrmse'):6.3f} "
            f"{m('correlation'):6.3f} {sum(x['clipped'] for x in sel):4d}/{len(sel)}")
    say(f"NRMSE/correlation: each tap against the real tap of closest incoming velocity (within "
        f"{MATCH_TOLERANCE:.0%}), 20-1000 Hz (limited by Nyquist at {log_fs:g} Hz).")
    say(f"detail (one row per tap): {shown / 'summary.csv'}")
    if real and len(traces) > 1:
        v_target = 0.11
        panels = []
        for name, taps in traces.items():
            if taps:
                tp = min(taps, key=lambda x: abs(x.v_in_m_s - v_target))
                panels.append((f"{name} ({tp.v_in_m_s:.2f} m/s)", tp.accel))
        ref = min(real, key=lambda x: abs(x.v_in_m_s - v_target))
        panels = [(lab, ref.accel if lab.startswith(runs.REAL.name) else w) for lab, w in panels]
        p = figs.contact_figure(panels, ref.accel, log_fs, runs.PRE_S, round(ref.v_in_m_s, 3), ref.grip_N,
                                out / "fig_contact.png")
        say(f"figure contact  : {shown / p.name}")
    return code
