"""``python -m renderer run`` on a 3-D scene or a 3-DOF device: the body ``renderer.cli_run`` hands over to.

The simulated person (``sim:3d``) taps ``--tap-object`` (from above) or ``--tap-target-m`` along
``--tap-direction`` with ``--taps`` taps at ``--velocities-m-s``; a hardware device is rendered for
``--duration-s``. Writes ``events.csv`` (with the object, normal and endpoint of each contact),
``run.json`` and ``log.npz`` (``renderer.law3.LOG_COLUMNS``), and the figure (``renderer.run3_figure``).
"""

from __future__ import annotations

import sys

from devices.limits import check_grips, check_tap_speeds
from devices.registry import all_axes_options, make_device
from devices.sim import Sim3Device, TapTrajectory
from plumbing import provenance
from plumbing.stopsignals import Terminated

from . import sim_aot
from .loop3 import ServoLoop3, surface_point_above
from .scene3 import pack_scene


def tap_plan(dev, cfg, args):
    """The tapped point and direction of a ``sim:3d`` run (module doc); checks the scene first."""
    packed = pack_scene(cfg.effective_scene, cfg.stiffness_N_m, dev.info.specs())
    direction = tuple(args.tap_direction)
    if args.tap_target_m is not None:
        return tuple(args.tap_target_m), direction
    point, _, _ = surface_point_above(packed, args.tap_object)
    return point, direction


def run_into(args, folder, cfg, transient) -> int:
    """The 3-D run, its files written into ``folder``; returns the exit code (as ``renderer.cli_run``)."""
    simulated = args.device.split(":", 1)[0] == "sim"
    # a 3-DOF research device opens with its three axes here, not as the 1-DOF vertical view of a 1-DOF scene
    dev = make_device(args.device, seed=args.seed) if simulated else make_device(args.device,
                                                                                **all_axes_options(args.device))
    loop = ServoLoop3(dev, cfg, transient)
    if simulated:
        provenance.prefetch()
        check_grips(dev.info, [args.grip], "--grip-N")
        check_tap_speeds(args.velocity, "--velocities-m-s")
        traj = TapTrajectory(args.velocity, n_taps=args.taps)
        if isinstance(dev, Sim3Device):
            target, direction = tap_plan(dev, cfg, args)
            dev.set_user(traj, grip_N=args.grip, target_m=target, direction=direction)
        else:
            dev.set_user(traj, grip_N=args.grip)
        if args.sample != "placeholder":
            dev.set_sample(args.sample)
        duration = args.duration if args.duration is not None else traj.duration_s
    else:
        duration = args.duration
    loop.prepare()   # a bad scene is refused here, before the device is opened
    try:
        with dev:
            result = loop.run(duration_s=duration, realtime=args.realtime or not simulated)
    except KeyboardInterrupt:
        if loop.result is not None:
            loop.result.save(folder.path)
            folder.commit()
        return 130
    except Terminated as exc:
        if loop.result is not None:
            loop.result.save(folder.path)
            folder.commit()
        return exc.code
    result.save(folder.path)
    if args.figure:
        from .run3_figure import save_run3_figure  # deferred: matplotlib, 0.5 s CPU of every run with --no-figure

        try:
            save_run3_figure(result, folder.path)
        except (OSError, ValueError) as exc:
            print(f"warning: the run's figure was not drawn ({exc})", file=sys.stderr)
    folder.commit()
    print(format_table(result))
    print(f"saved {args.out}/events.csv, run.json, log.npz" + (", run.png, run.svg, run.plot.csv" if args.figure else ""))
    if simulated and result.timing.get("compiled_sim") and not result.timing.get("aot"):
        if sim_aot.schedule_build(sim_aot.LOOP3):
            print("compiling the simulated 3-D loop ahead of time in the background (once, ~20 s): later simulated "
                  "3-D runs start without numba (docs/renderer.md, 'Compiled ahead of time')", file=sys.stderr)
    return 0 if result.stop_reason in ("duration", "until", "stopped") else 1


def format_table(result) -> str:
    """One row per contact event (object, v_n, normal, depth) and the run's summary."""
    lines = [f"{'#':>3} {'t s':>8} {'object':>14} {'v_n m/s':>8} {'normal':>20} {'pen mm':>7} {'clipped':>7}"]
    for k, ev in enumerate(result.events, 1):
        n = f"({ev.normal_x:+.2f},{ev.normal_y:+.2f},{ev.normal_z:+.2f})"
        lines.append(f"{k:>3} {ev.t_s:8.3f} {ev.object[:14]:>14} {ev.incoming_velocity_m_s:8.4f} {n:>20} "
                     f"{1000 * ev.max_penetration_m:7.3f} {'yes' if ev.clipped else 'no':>7}")
    tm = result.timing
    lines.append(f"3-D renderer; {len(result.events)} events; stop: {result.stop_reason}"
                 + (f" ({result.error})" if result.error else ""))
    lines.append(f"{tm['ticks']} ticks at {tm['rate_hz']:g} Hz, {tm['sim_time_s']:.3f} s in {tm['wall_time_s']:.3f} s "
                 f"wall ({tm['realtime_factor']:.1f}x real time)")
    return "\n".join(lines)
