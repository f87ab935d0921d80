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

import argparse
import math
import sys

from plumbing.cliargs import add_renamed, with_examples
from plumbing.fileio import check_output_dir

TRANSIENTS = ("none", "pulse", "sinusoid", "hfam")


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
    import stimuli  # deferred: keeps `--help` fast (a command loads only what it runs)

    kwargs = {} if gain is None else {"gain": float(gain)}
    if kind == "pulse":
        return stimuli.Pulse(**kwargs)
    if kind == "sinusoid":
        return stimuli.DecayingSinusoid(**kwargs)
    if not library:
        raise ValueError("--transient hfam needs --library PATH (an HFAM library .npz, see `python -m stimuli`)")
    return stimuli.HfamLibrary.load(library, **kwargs)


def _positive(name):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{name} must be > 0, got {text!r}")
        return value
    return parse


def _velocities(text: str) -> list[float]:
    out = []
    for part in text.split(","):
        out.append(_positive("--velocity")(part.strip()))
    return out


def register(subparsers) -> None:
    """Add the ``run`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m renderer`` sub-command parsers.
    """
    p = subparsers.add_parser("run", help="render a virtual wall under a simulated or real user tapping",
                              description=__doc__.split("\n\n")[0] + " Outputs: events.csv, run.json, log.npz.")
    p.add_argument("--device", default="sim", help="device string: sim (default), sim:lti, sim:<file>, serial:<port>, hid:<vid>:<pid>")
    p.add_argument("--transient", default="none", choices=TRANSIENTS, help="contact transient (default none)")
    p.add_argument("--library", help="HFAM library file (needed for --transient hfam)")
    p.add_argument("--transient-gain", type=float, default=None,
                   help="gain of the transient (stimuli gain; default: Table 4.1 / the library's own)")
    add_renamed(p, "--stiffness-N-m", "--stiffness", dest="stiffness", type=float, default=None,
                   help="proportional stiffness k (N/m); default 680 or the config file's")
    add_renamed(p, "--damping-N-s-m", "--damping", dest="damping", type=float, default=None, help="virtual damping on entry (N s/m); default 0 or the config file's")
    p.add_argument("--config", help="renderer config/scene file (TOML or JSON, see docs/renderer.md); default: built-in settings")
    p.add_argument("--taps", type=int, default=10, help="sim: number of taps (default 10)")
    add_renamed(p, "--velocities-m-s", "--velocity", dest="velocity", type=_velocities, default=[0.1],
                   help="sim: tap speed in m/s (comma list: one per tap, cycled; default 0.1)")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0, help="sim: grip force in N (default 2)")
    p.add_argument("--sample", default="placeholder", help="sim: real sample under the stylus (default placeholder)")
    p.add_argument("--seed", type=int, default=0, help="sim: noise seed (default 0)")
    add_renamed(p, "--duration-s", "--duration", dest="duration", type=_positive("--duration"), default=None,
                   help="run length in s (hardware default: until Ctrl-C; sim default: until the taps are done)")
    p.add_argument("--realtime", action="store_true", help="sim: pace to wall-clock time (hardware always is)")
    p.add_argument("--in-process", action="store_true",
                   help="hardware: run the servo loop in this process instead of its own")
    p.add_argument("--out", required=True, help="output directory (new or empty)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds an earlier run")
    p.add_argument("--no-figure", dest="figure", action="store_false",
                   help="do not draw run.png/.svg (position, forces, acceleration, events, the wall) beside the data")
    with_examples(p, 'hfam-renderer run --device sim --transient pulse --stiffness-N-m 680 --taps 10 --velocities-m-s 0.1 --out runs/pulse', 'hfam-renderer run --device serial:/dev/ttyACM0 --transient hfam --library LIB.npz --duration-s 60 --out runs/hw')
    # run_command closes the device and every file and joins its threads before it returns
    p.set_defaults(func=run_command, fast_exit=True)


def _build_config(args):
    from .config import RendererConfig, load_config  # deferred: keeps `--help` fast (a command loads only what it runs)

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
    from plumbing.stopsignals import stop_on_signals  # deferred: keeps `--help` fast

    with stop_on_signals():  # from before the device is opened until its files are written
        return _run(args)


def _save_partial(result, out: str, why: str) -> None:
    """Save a partial run (if any) after a stop signal or Ctrl-C, and say so."""
    if result is not None:
        result.save(out)
        print(f"{why}: partial run saved to {out}", file=sys.stderr)


def _run(args) -> int:
    from devices.registry import make_device  # deferred: keeps `--help` fast (a command loads only what it runs)
    from plumbing.stopsignals import Terminated  # deferred: keeps `--help` fast (a command loads only what it runs)

    from .loop import ServoLoop  # deferred: keeps `--help` fast (a command loads only what it runs)

    if args.taps < 1:
        raise ValueError(f"--taps must be >= 1, got {args.taps}")
    check_output_dir(args.out, args.force)   # a file, a path below one or earlier results: refused before the run
    cfg = _build_config(args)
    transient = make_transient(args.transient, args.library, args.transient_gain)
    simulated = args.device.split(":", 1)[0] == "sim"
    if simulated:
        from plumbing import provenance  # deferred: keeps `--help` fast (a command loads only what it runs)
        from devices.sim import TapTrajectory  # deferred: keeps `--help` fast (a command loads only what it runs)

        provenance.prefetch()  # run.json's versions and git state, while the simulation runs

        dev = make_device(args.device, seed=args.seed)
        with dev:
            if args.sample != "placeholder":
                dev.set_sample(args.sample)
            traj = TapTrajectory(args.velocity, n_taps=args.taps)
            dev.set_user(traj, grip_N=args.grip)
            loop = ServoLoop(dev, cfg, transient)
            if args.realtime:  # paced: SCHED_FIFO, mlockall, a core of its own around the ticks (renderer.rtpolicy)
                loop.rt_request = {"core": None}
            # --duration-s: that long (the hand rests after its last tap); else the plan's length
            duration = args.duration if args.duration is not None else traj.duration_s
            try:
                result = loop.run(duration_s=duration, realtime=args.realtime)
            except KeyboardInterrupt:
                _save_partial(loop.result, args.out, "interrupted")
                return 130
            except Terminated as exc:
                _save_partial(loop.result, args.out, str(exc))
                return exc.code
    elif args.in_process:
        dev = make_device(args.device)
        loop = None
        try:
            with dev:
                loop = ServoLoop(dev, cfg, transient)
                loop.rt_request = {"core": None}  # SCHED_FIFO and mlockall around the ticks (renderer.rtpolicy)
                try:
                    result = loop.run(duration_s=args.duration, realtime=True)
                except KeyboardInterrupt:
                    result = loop.result
        except Terminated as exc:  # the output was zeroed by the loop and again on closing
            _save_partial(loop.result if loop is not None else None, args.out, str(exc))
            return exc.code
    else:
        from .process import run_in_process  # deferred: keeps `--help` fast (a command loads only what it runs)

        try:
            result = run_in_process(args.device, cfg, transient, duration_s=args.duration)
        except RuntimeError as exc:  # the servo process failed: keep what it logged before failing
            partial = getattr(exc, "partial_result", None)
            if partial is not None:
                partial.save(args.out)
                print(f"partial run saved to {args.out}", file=sys.stderr)
            raise
        except Terminated as exc:  # the servo process zeroed and stopped first
            _save_partial(exc.partial_result, args.out, str(exc))
            return exc.code
    result.save(args.out)
    if (simulated or args.in_process) and result.timing.get("policy", {}).get("requested"):
        from .rtpolicy import warn_once  # deferred: keeps `--help` fast (run_in_process warns by itself)

        warn_once(result.timing["policy"])
    print(format_table(result))
    print(f"saved {args.out}/events.csv, run.json, log.npz")
    if args.figure:  # after the data are safe, in this process (never the servo's): matplotlib loads only here
        from .run_figure import save_run_figure  # deferred: matplotlib (~0.5 s), not for --help or --no-figure

        save_run_figure(result, args.out)
        print(f"saved {args.out}/run.png, run.svg, run.plot.csv (the run drawn)")
    if simulated and not result.timing.get("aot"):
        from . import sim_aot  # deferred: keeps `--help` fast (a command loads only what it runs)

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
    else:
        lines.append(head + f"; period p50/p99/max {tm['period_p50_us']:.1f}/{tm['period_p99_us']:.1f}/"
                     f"{tm['period_max_us']:.1f} us; overruns {tm['overruns']}; compute p50/p99 "
                     f"{tm['compute_p50_us']:.2f}/{tm['compute_p99_us']:.2f} us")
    link = tm.get("link")
    if link:
        ms = (lambda v: "-" if v is None else f"{1000 * v:.2f}")
        lines.append(f"link: {link['frames_tx']} frames sent, {link['frames_rx']} received, {link['crc_errors']} CRC "
                     f"errors, {link['losses']} lost (longest run {link['max_consecutive_losses']}), longest gap "
                     f"{ms(link['longest_gap_s'])} ms, round trip median/p99/max {ms(link['rtt_median_s'])}/"
                     f"{ms(link['rtt_p99_s'])}/{ms(link['rtt_max_s'])} ms")
    return "\n".join(lines)
