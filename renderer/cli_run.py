"""``python -m renderer run``: render a virtual wall under a (simulated or real) user tapping.

Example::

    python -m renderer run --device sim --transient hfam --library lib.npz \\
        --stiffness 680 --taps 10 --velocity 0.1 --grip 2 --out runs/hfam

On a sim device the simulated hand taps ``--taps`` times at ``--velocity``
(TapTrajectory) and the run ends when it is done. On hardware the run lasts
``--duration`` seconds (or until Ctrl-C) in its own process
(renderer.process). Writes ``events.csv``, ``run.json`` and ``log.npz`` into
``--out`` (formats in docs/renderer.md) and prints a short table.
"""

from __future__ import annotations

import sys
from pathlib import Path

import stimuli
from devices.limits import check_grips, check_tap_speeds
from devices.registry import make_device
from devices.sim import TapTrajectory
from plumbing import provenance
from plumbing.outdir import output_folder
from plumbing.stopsignals import Terminated, stop_on_signals

from . import sim_aot
from .cli_run_parser import TRANSIENTS
from .config import RendererConfig, check_run_size, load_config
from .loop import ServoLoop
from plumbing.rtpolicy import warn_once

#: what a run folder holds (a folder of these alone, without the output marker, is an older version's run,
#: which --force replaces)
RUN_FILES = ("events.csv", "log.npz", "run.json", "run.png", "run.svg", "run.plot.csv")


def make_transient(kind: str, library: str | None = None, gain: float | None = None):
    """Build a stimuli transient (Table 4.1 defaults) or None; imported lazily.

    Raises
    ------
    ValueError
        Unknown kind, or ``hfam`` without a library path.
    """
    if kind not in TRANSIENTS:
        raise ValueError(f"--transient must be one of {', '.join(TRANSIENTS)}, got {kind!r}")
    if kind == "none":
        return None

    kwargs = {} if gain is None else {"gain": float(gain)}
    if kind == "pulse":
        return stimuli.Pulse(**kwargs)
    if kind == "sinusoid":
        return stimuli.DecayingSinusoid(**kwargs)
    if not library:
        raise ValueError("--transient hfam needs --library PATH (an HFAM library .npz, see `python -m stimuli`)")
    return stimuli.HfamLibrary.load(library, **kwargs)


#: a simulated tap whose measured incoming speed is off its planned speed by more than this share is said
SPEED_TOLERANCE = 0.15


def tap_speed_warnings(events, planned_m_s) -> list[str]:
    """Warnings for simulated taps whose measured incoming speed missed the planned one (cycled over the taps).

    The simulated hand plans each tap's approach speed, but the speed measured at contact (what the wall and the
    transient saw) can fall short of it, e.g. the slower taps of an alternating 0.2/0.3 m/s plan reached
    0.13 m/s: a run that meant 0.2 m/s and got 0.13 m/s must say so.
    """
    out = []
    for k, ev in enumerate(events):
        want = planned_m_s[k % len(planned_m_s)]
        got = ev.incoming_velocity_m_s
        if abs(got - want) > SPEED_TOLERANCE * want:
            out.append(f"tap {k + 1} reached {got:.3g} m/s at contact, planned {want:g} m/s ({100 * (got / want - 1):+.0f} %)")
    return out


def _warn_outside_library(transient, velocities_m_s) -> None:
    """Say so (one ``warning:`` line on stderr) when a tap speed lies outside an HFAM library's velocities: its
    transient is then extrapolated from the nearest recordings (capped by the library's extrapolation limit), not
    measured (thesis section 4.4)."""
    vs = getattr(transient, "velocities_m_s", None)
    if vs is None or not len(vs):
        return
    lo, hi = float(vs[0]), float(vs[-1])
    out = [v for v in velocities_m_s if not lo <= v <= hi]
    if out:
        print(f"warning: --velocities-m-s {', '.join(f'{v:g}' for v in out)} m/s outside the HFAM library's "
              f"{lo:g}-{hi:g} m/s: the transient is extrapolated (capped at {transient.max_extrapolation:g}x), not "
              "from a recording", file=sys.stderr)


def _build_config(args):
    overrides = {}
    if args.stiffness is not None:
        overrides["stiffness_N_m"] = float(args.stiffness)
    if args.damping is not None:
        overrides["damping_N_s_m"] = float(args.damping)
    if args.config:
        return load_config(args.config, **overrides)
    try:
        return RendererConfig(**overrides)
    except ValueError as exc:
        raise ValueError(f"command line: {exc}") from None


def run_command(args) -> int:
    """The ``run`` command: render the wall (and transient) under the tapping hand and write events.csv, run.json, log.npz; returns the exit code.

    SIGTERM and SIGHUP stop the run as Ctrl-C does (the output is zeroed, the partial run saved) and the
    command returns 128 + the signal's number (143, 129); Ctrl-C returns 130 (docs/renderer.md, Safety).
    """

    with stop_on_signals():  # from before the device is opened until its files are written
        return _run(args)


def _save_partial(result, folder, why: str) -> None:
    """Save a partial run (if any) after a stop signal, Ctrl-C or a failure, and say where.

    Into ``--out`` when it was new; beside it (``<out>.interrupted``) when it holds an earlier run, which
    a partial one does not replace (``folder``: the :class:`plumbing.outdir.OutputFolder` of ``--out``).
    Stopped before the loop had a result (a signal while it was being set up): nothing is kept, and the
    staging folder is discarded, so ``--out`` stays as it was (it used to be swapped in empty).
    """
    if result is None:
        folder.discard()
        return
    result.save(folder.path)
    if folder.replacing:
        kept = folder.set_aside("interrupted")
        print(f"{why}: partial run saved to {kept} ({folder.out} keeps the earlier run)", file=sys.stderr)
    else:
        print(f"{why}: partial run saved to {folder.commit()}", file=sys.stderr)


def _begin_stream(args, loop):
    """``renderer run --lsl`` (:mod:`renderer.cli_run_lsl` sets ``args.servo_stream``): the loop's ``until``
    callback that publishes its log and contacts; None without it."""
    stream = getattr(args, "servo_stream", None)
    if stream is not None:
        stream.begin(loop)
        stream.publisher.marker({"event": "run_start"})
    return stream


def _end_stream(args, loop, result) -> None:
    """After the run: the last ticks and contacts, the run's end, and the streams' record in run.json."""
    stream = getattr(args, "servo_stream", None)
    if stream is not None:
        stream.flush(loop)
        stream.publisher.marker({"event": "run_end", "stop_reason": result.stop_reason})
        result.timing["lsl"] = stream.publisher.close()


def _run(args) -> int:
    check_run_size(args.taps, args.duration)   # time and memory bounded: refused before anything is written
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir): a failed or
    # interrupted run leaves an earlier one as it was
    folder = output_folder(args.out, args.force, command="renderer run", own=RUN_FILES).open()
    with folder:
        return _run_into(args, folder)


def _run_into(args, folder) -> int:
    """The run, its files written into ``folder`` (an open :class:`plumbing.outdir.OutputFolder`)."""
    cfg = _build_config(args)
    transient = make_transient(args.transient, args.library, args.transient_gain)
    if cfg.effective_scene.needs_3d or args.device.startswith("sim:3d"):
        from . import cli_run3  # deferred: the 3-D loop's modules, 10 ms CPU that a 1-DOF run never pays

        return cli_run3.run_into(args, folder, cfg, transient)
    simulated = args.device.split(":", 1)[0] == "sim"
    if getattr(args, "servo_stream", None) is not None and not (simulated or args.in_process):
        raise ValueError("--lsl streams a hardware run with --in-process (the servo loop in this process)")
    if simulated:
        provenance.prefetch()  # run.json's versions and git state, while the simulation runs

        dev = make_device(args.device, seed=args.seed)
        with dev:
            if args.sample != "placeholder":
                dev.set_sample(args.sample)
            check_grips(dev.info, [args.grip], "--grip-N")       # 500 N on a 0-10 N sensor: refused
            check_tap_speeds(args.velocity, "--velocities-m-s")  # 5 m/s: not a hand's tap
            _warn_outside_library(transient, args.velocity)
            traj = TapTrajectory(args.velocity, n_taps=args.taps)
            dev.set_user(traj, grip_N=args.grip)
            loop = ServoLoop(dev, cfg, transient)
            if args.realtime:  # paced: SCHED_FIFO, mlockall, a core of its own around the ticks (plumbing.rtpolicy)
                loop.rt_request = {"core": None}
            # --duration-s: that long (the hand rests after its last tap); else the plan's length
            duration = args.duration if args.duration is not None else traj.duration_s
            stream = _begin_stream(args, loop)
            try:
                result = loop.run(duration_s=duration, realtime=args.realtime, until=stream)
                _end_stream(args, loop, result)
            except KeyboardInterrupt:
                _save_partial(loop.result, folder, "interrupted")
                return 130
            except Terminated as exc:
                _save_partial(loop.result, folder, str(exc))
                return exc.code
    elif args.in_process:
        dev = make_device(args.device)
        loop = None
        try:
            with dev:
                loop = ServoLoop(dev, cfg, transient)
                loop.rt_request = {"core": None}  # SCHED_FIFO and mlockall around the ticks (plumbing.rtpolicy)
                stream = _begin_stream(args, loop)
                try:
                    result = loop.run(duration_s=args.duration, realtime=True, until=stream)
                    _end_stream(args, loop, result)
                except KeyboardInterrupt:
                    result = loop.result
        except Terminated as exc:  # the output was zeroed by the loop and again on closing
            _save_partial(loop.result if loop is not None else None, folder, str(exc))
            return exc.code
    else:
        try:
            from . import process  # deferred: multiprocessing, 16 ms CPU of every simulated run; hardware only

            result = process.run_in_process(args.device, cfg, transient, duration_s=args.duration)
        except RuntimeError as exc:  # the servo process failed: keep what it logged before failing
            _save_partial(getattr(exc, "partial_result", None), folder, "failed")
            raise
        except Terminated as exc:  # the servo process zeroed and stopped first
            _save_partial(exc.partial_result, folder, str(exc))
            return exc.code
    result.save(folder.path)
    if (simulated or args.in_process) and result.timing.get("policy", {}).get("requested"):
        warn_once(result.timing["policy"])
    if args.figure:  # after the data are saved, in this process (never the servo's): matplotlib loads only here
        from .run_figure import save_run_figure  # deferred: matplotlib, 0.5 s CPU of every run that asks for no figure

        try:
            save_run_figure(result, folder.path)
        except (OSError, ValueError) as exc:   # the data matter more than their picture: the run is kept
            print(f"warning: the run's figure was not drawn ({exc})", file=sys.stderr)
    folder.commit()
    print(format_table(result))
    if simulated:
        missed = tap_speed_warnings(result.events, args.velocity)
        if missed:
            print(f"warning: {len(missed)} of {len(result.events)} taps missed their planned speed by more than "
                  f"{100 * SPEED_TOLERANCE:.0f} % (measured at contact; events.csv has each tap's speed): " + "; ".join(missed), file=sys.stderr)
    print(f"saved {args.out}/events.csv, run.json, log.npz")
    if args.figure and (Path(args.out) / "run.png").is_file():
        print(f"saved {args.out}/run.png, run.svg, run.plot.csv (the run drawn)")
    if simulated and not result.timing.get("aot"):
        if sim_aot.schedule_build():
            print("compiling the simulated loop ahead of time in the background (once, ~5 s): later simulated "
                  "runs start without numba (docs/renderer.md, 'Compiled ahead of time')", file=sys.stderr)
    return 0 if result.stop_reason in ("duration", "until", "stopped", "interrupted") else 1


def format_table(result) -> str:
    """A short human-readable summary: one row per event plus timing."""
    # every header names its unit; '#' counts events and 'clipped' is yes/no
    lines = [f"{'#':>3} {'t s':>8} {'v_in m/s':>9} {'grip N':>7} {'pen mm':>7} {'peak a m/s2':>11} {'clipped':>7}"]
    for k, ev in enumerate(result.events, 1):
        lines.append(f"{k:>3} {ev.t_s:8.3f} {ev.incoming_velocity_m_s:9.4f} {ev.grip_N:7.2f} "
                     f"{1000 * ev.max_penetration_m:7.3f} {ev.peak_accel_m_s2:11.1f} {'yes' if ev.clipped else 'no':>7}")
    tm = result.timing
    lines.append(f"transient {result.transient}; {len(result.events)} events; stop: {result.stop_reason}"
                 + (f" ({result.error})" if result.error else ""))
    head = (f"{tm['ticks']} ticks at {tm['rate_hz']:g} Hz, {tm['sim_time_s']:.3f} s in {tm['wall_time_s']:.3f} s wall "
            f"({tm['realtime_factor']:.1f}x real time)")
    if tm.get("compiled_sim"):
        how = "ahead of time" if tm.get("aot") else "JIT"
        lines.append(head + f"; law and simulated physics compiled together ({how}; no per-tick timing)")
    elif result.device.get("lockstep_ticks") and not tm.get("on_device"):
        # the device's clock waits for the host (fw-sim, docs/protocol.md "Lockstep"): wall-clock periods measure
        # the simulator's speed, not the loop's timing
        lines.append(head + f"; lockstep: paced on the device's clock ({result.device['lockstep_ticks']} device "
                     f"ticks per command), wall-clock period p50/max {tm['period_p50_us']:.1f}/"
                     f"{tm['period_max_us']:.1f} us (the simulator's speed); overruns {tm['overruns']}")
    else:
        lines.append(head + f"; period p50/p99/max {tm['period_p50_us']:.1f}/{tm['period_p99_us']:.1f}/"
                     f"{tm['period_max_us']:.1f} us; overruns {tm['overruns']}; compute p50/p99 "
                     f"{tm['compute_p50_us']:.2f}/{tm['compute_p99_us']:.2f} us")
    link = tm.get("link")
    if link:
        ms = (lambda v: "-" if v is None else f"{1000 * v:.2f}")
        lines.append(f"link: {link['frames_tx']} frames sent, {link['frames_rx']} received, {link['crc_errors']} CRC "
                     f"errors, {link.get('malformed_frames', 0)} malformed, {link['losses']} lost (longest run {link['max_consecutive_losses']}), longest gap "
                     f"{ms(link['longest_gap_s'])} ms, round trip median/p99/max {ms(link['rtt_median_s'])}/"
                     f"{ms(link['rtt_p99_s'])}/{ms(link['rtt_max_s'])} ms")
        if link.get("rearms"):   # a sampled transient rendered on the board: how old its velocity was when armed
            lines.append(f"re-armed transient: {link['rearms']} uploads, velocity age at commit median/max "
                         f"{ms(link.get('rearm_age_median_s'))}/{ms(link.get('rearm_age_max_s'))} ms")
    return "\n".join(lines)
