"""``python -m renderer teleop`` and ``teleop-sweep``: the commands (parsers in :mod:`renderer.teleop.cli_teleop`).

``teleop`` runs one session (default: the simulated operator taps ten times) and writes a run folder
(traces.csv, run.json, a Figure 5.10-style figure). ``teleop-sweep`` runs blind-randomised taps over
lambda for position-force with and without cancellation and with each stabiliser of section 5.4,
and writes Figure 5.11 (settling time vs lambda with fits), the table of the largest stable lambda per
controller and the energy of F_f above 50 Hz. Definitions: docs/teleop.md.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import platform
import random
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy

import figstyle
from devices.model import load_model
from devices.registry import make_device
from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import CimmModel, Testbed, get_environment
from plumbing.fileio import atomic_write_text, check_output_dir
from plumbing.outdir import output_folder
from plumbing.progress import Progress
from plumbing.stopsignals import stop_on_signals

from .calibration import feedback_limit_speed
from .hfam import accel_match, accel_match_target, design_hfam, figure_45, identify_master_hha
from .models import cimm_params, underestimation_check
from .options import SWEEP_CONDITIONS, parse_lambdas
from .serial_master import run_serial_session
from .session import (PRESS_DEPTH_M, SERVO_BANDWIDTH_HZ, TeleopConfig, default_path, resolve_gains, run_session,
                      session_metrics)

TRACE_COLUMNS = ("t_s", "x_m_m", "x_s_m", "x_c_m", "F_e_N", "F_f_N", "x_hat_mi_hf_m", "a_m_m_s2", "a_s_m_s2",
                 "i_m_A", "i_s_A", "contact", "x_tip_m", "x_path_m", "i_hfam_A", "F_e_true_N", "x_m_true_m")

HOLDS_CONTACT = ("settles", "buzzes")
# pd+hfam is section 4.3.1's architecture: bilateral PD plus the acceleration-matching channel, nothing else. The
# position-command low-pass K_mu (40 Hz) and the master-PD low-pass (150 Hz) it once had by default were tuned
# against an earlier 600 N/m slave; with the rule's 8 Hz servos they lowered the match over three operators
# (correlation 0.843-0.885 against 0.884-0.912) and added bounces (docs/teleop.md). Both remain options.



def software_versions() -> dict:
    """Versions written into run.json."""

    try:
        version = importlib.metadata.version("hfam-haptics")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    return {"hfam-haptics": version, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__}


def staged_folder(out, command: str):
    """The output folder ``out`` of a teleoperation command, opened for writing beside it and swapped in whole
    when the ``with`` block ends without an exception (:func:`plumbing.outdir.output_folder`): a run that is
    stopped (Ctrl-C, SIGTERM) or fails leaves no half-written folder. An existing non-empty ``out`` is refused
    (these commands have no ``--force``)."""
    path = Path(out)
    check_output_dir(path)  # a file, or a folder below a file: refused before anything runs
    if path.exists() and any(path.iterdir()):
        raise ValueError(f"output folder {path} exists and is not empty (choose another --out)")
    return output_folder(path, False, command=command).open()


def build_testbed(args) -> Testbed:
    """Testbed from command-line arguments."""
    P = default_params()
    if not (math.isfinite(args.backlash_mm) and 0.0 <= args.backlash_mm < 5.0):
        raise ValueError(f"--backlash-mm must be in [0, 5), got {args.backlash_mm!r}")
    _check_servo_options(args)
    return Testbed(P, P, environment=get_environment(args.environment), servo_rate_hz=args.rate_hz,
                   backlash_m=args.backlash_mm * 1e-3, slave_handle_damping_N_s_m=args.slave_handle_damping)


def _check_servo_options(args) -> None:
    """``--servo-bandwidth-hz`` (> 0) and ``--slave-handle-damping-N-s-m`` (>= 0), named in the error."""
    if not (math.isfinite(args.servo_bandwidth_hz) and args.servo_bandwidth_hz > 0):
        raise ValueError(f"--servo-bandwidth-hz must be a positive number, got {args.servo_bandwidth_hz!r}")
    if not (math.isfinite(args.slave_handle_damping) and args.slave_handle_damping >= 0):
        raise ValueError(f"--slave-handle-damping-N-s-m must be a number >= 0, got {args.slave_handle_damping!r}")


def build_hfam(args, tb: Testbed, out: Path):
    """HFAM filter from H_ha: ``--hha-model FILE`` or the comprehensive identification of the master."""

    if args.hha_model:
        model = load_model(args.hha_model)
        print(f"H_ha: {args.hha_model}")
    else:
        print("identifying H_ha of the master held by the operator (swept sine, ETFE, fit; about 5 s)...", flush=True)
        model = identify_master_hha(tb.master, tb.servo_rate_hz, operator=tb.operator)
        model.save(out / "H_ha_model.json")
    hf = design_hfam(model, tb.servo_rate_hz, max_current_A=args.hfam_max_current)
    c = hf.check
    print(f"HFAM inverse: Tustin vs continuous over {c['band_hz'][0]:.0f}-{c['band_hz'][1]:.0f} Hz: "
          f"max {c['max_mag_error_db']:.2f} dB, {c['max_phase_error_deg']:.1f} deg; "
          f"{c['reflected_rhp_zeros']} right-half-plane zero(s) reflected")
    return hf


def build_cimm(args) -> CimmModel:
    """CIMM model from the configured source (``--cimm-model``), never the simulator's parameters."""
    params, source = cimm_params(args.cimm_model)
    return CimmModel(params, washout_hz=args.washout_hz, source=source)


def _teleop_config(args) -> TeleopConfig:
    """Controller settings from the ``teleop`` arguments (K_mu and the master-PD low-pass off unless given)."""
    k_mu = args.k_mu_hz if args.k_mu_hz is not None else 0.0
    mpd = args.master_pd_lowpass_hz if args.master_pd_lowpass_hz is not None else 0.0
    _check_servo_options(args)
    return TeleopConfig(controller=args.controller, mu=args.mu, lam=args.lam, b_Ns_m=args.b, k_mu_hz=k_mu,
                        k_lambda_hz=args.k_lambda_hz, master_pd_lowpass_hz=mpd,
                        servo_bandwidth_hz=args.servo_bandwidth_hz)


def _write_traces(out: Path, res) -> None:
    """``traces.csv``: the session's trace columns (``TRACE_COLUMNS``), cut at a fault."""
    n = len(res.traces) if not res.fault else res.fault_tick + 1
    np.savetxt(out / "traces.csv", res.traces[:n], delimiter=",", header=",".join(TRACE_COLUMNS), comments="",
               fmt="%.9g")


def _cimm_record(cimm: CimmModel | None, check: dict | None) -> dict | None:
    """The CIMM model's entry of run.json (None without cancellation)."""
    if cimm is None:
        return None
    return {"source": cimm.source, "step_s": cimm.step_s, "washout_hz": cimm.washout_hz, "k_u_N_m": cimm.k_u_N_m,
            "q_u_N_m5": cimm.q_u_N_m5, "b_u_Ns_m": cimm.b_u_Ns_m, "underestimation_check": check}


def run_teleop(args) -> int:
    """The ``teleop`` command."""
    if args.taps < 1:
        raise ValueError(f"--taps must be >= 1, got {args.taps}")
    if args.master != "sim":
        return run_teleop_master(args)
    tb = build_testbed(args)
    cfg = resolve_gains(_teleop_config(args), tb)   # run.json records the derived gains
    folder = staged_folder(args.out, "renderer teleop")
    with folder:
        out = folder.path
        hfam = None
        if args.controller == "pd+hfam":
            hfam = build_hfam(args, tb, out)
        cimm = build_cimm(args) if args.controller == "pf+cimm" else None
        check = None
        if cimm is not None:
            check = underestimation_check(cimm, tb.master)
            print(f"CIMM model: {cimm.source}")
            print(check["warning"] or f"CIMM model underestimates induced motion below 8 Hz "
                  f"(max ratio {check['max_ratio']:.2f}): no positive feedback (eq. 5.14)")
        path, crossings = default_path(tb.servo_rate_hz, args.mu, n_taps=args.taps, speed_m_s=args.speed)
        t0 = time.perf_counter()
        stroke = None
        if args.environment == "texture":
            stroke = np.cumsum(np.where(path < 0.5e-3 / args.mu, 0.02, 0.0)) / tb.servo_rate_hz  # 20 mm/s in contact
        res = run_session(tb, cfg, path, cimm=cimm, hfam=hfam, impact_ticks=crossings, stroke_m=stroke)
        wall = time.perf_counter() - t0
        metrics = session_metrics(res)
        _write_traces(out, res)
        taps = [None if m is None else {"impact_s": m.impact_s, "settling_s": m.settling_s if math.isfinite(m.settling_s)
                                        else None, "quasi_static_N": m.quasi_static_N, "contact_breaks": m.breaks,
                                        "contact_losses": m.contact_losses, "contact_class": m.contact_class,
                                        "stable": m.stable, "F_f_energy_above_50Hz": m.hf_energy_fraction}
                for m in metrics]
        unstable = sum(1 for m in metrics if m is not None and not m.stable)
        run = {"command": "teleop", "argv": sys.argv[1:], "controller": cfg.__dict__,
               "testbed": {"environment": tb.environment.__dict__, "operator": tb.operator.__dict__,
                           "sensors": tb.sensors.__dict__, "servo_rate_hz": tb.servo_rate_hz,
                           "substep_s": tb.substep_s, "master": tb.master.name, "slave": tb.slave.name,
                           "backlash_m": tb.backlash_m, "slave_handle_damping_N_s_m": tb.slave_handle_damping_N_s_m},
               "cimm_model": _cimm_record(cimm, check),
               "versions": software_versions(), "duration_s": len(path) / tb.servo_rate_hz,
               "wall_s": wall, "clip_counts": res.counts, "fault": res.fault, "fault_tick": res.fault_tick,
               "unstable_taps": unstable, "taps": taps}
        if cfg.controller.startswith("pd"):
            match = accel_match(res.col(K.O_AS), res.col(K.O_AM), tb.servo_rate_hz)
            run["accel_match_22_1000Hz"] = match
            # eq. 4.4: the master's high-passed acceleration against the smoothed, high-passed tip acceleration it
            # must replicate, and what the smoothing itself takes out
            run["accel_match_eq_4_4"] = accel_match_target(res.col(K.O_AS), res.col(K.O_AM), tb.servo_rate_hz)
            if hfam is not None:
                run["hfam"] = {"check": hfam.check, "max_current_A": hfam.max_current_A, "gain": hfam.gain}
            print(f"master handle vs slave tip (22-1000 Hz, delay {match['delay_s'] * 1e3:.1f} ms removed): "
                  f"correlation {match['correlation']:.2f}, NRMSE {match['nrmse']:.2f}, RMS ratio {match['rms_ratio']:.2f}")
            if not args.no_figures:
                figure_45(res.col(K.O_AS), res.col(K.O_AM), tb.servo_rate_hz, match["delay_samples"],
                          out / "figure_4_5.png", f"{cfg.controller}, {args.environment}")
        atomic_write_text(out / "run.json", json.dumps(run, indent=1, default=str))
        if not args.no_figures:
            figure_510(res, out / "figure_5_10.png", f"{cfg.controller}, lambda = {cfg.lam:g}, mu = {cfg.mu:g}")
        settle = [t["settling_s"] for t in taps if t and t["settling_s"] is not None]
        print(f"{args.taps} taps, {len(path) / tb.servo_rate_hz:.1f} s simulated in {wall:.2f} s; unstable taps: "
              f"{unstable}; median settling {np.median(settle) * 1e3 if settle else float('nan'):.0f} ms; "
              f"master clip ticks {res.counts['master_clip_ticks']}; fault {res.fault}")
        print(f"wrote {folder.out}")
        return 0


def run_teleop_master(args) -> int:
    """The ``teleop`` command with ``--master DEVICE``: a real master over its link drives the simulated slave.

    The session runs :func:`renderer.teleop.serial_master.run_serial_session` for ``--duration-s`` at the
    master's servo rate and writes ``traces.csv``, ``run.json`` (with the achieved rate, round-trip
    p50/p99, late ticks, whether and when the link was lost) and Figure 5.10. Position-force
    controllers only (pf, pf+cimm): PD and HFAM need the master's motor loop on the host side.

    Returns
    -------
    int
        0; 1 if the link was lost or the loop faulted (the output was zeroed either way).

    SIGTERM/SIGHUP stop the session like Ctrl-C: :class:`plumbing.stopsignals.Terminated` propagates (exit
    status 128 + the signal's number) after closing the master has zeroed its output.
    """

    if args.controller not in ("pf", "pf+cimm"):
        raise ValueError(f"--master {args.master}: only the position-force controllers (pf, pf+cimm) run "
                         f"with a real master, not {args.controller!r}")
    if not (math.isfinite(args.duration_s) and args.duration_s > 0):
        raise ValueError(f"--duration-s must be > 0, got {args.duration_s!r}")
    if args.controller == "pf+cimm" and not args.cimm_model:
        # the default model describes the simulated master held by the simulated operator: against another
        # master and hand it may overestimate low-frequency induced motion, which is positive feedback
        # (eq. 5.14; the emulated master with the stand-in diverged at lambda 0.5 where pf ran at 1)
        raise ValueError(f"--master {args.master} with pf+cimm needs --cimm-model FILE: the model of this "
                         "master as you hold it (e.g. the model.json of `devices successive` on it)")
    cfg = _teleop_config(args)
    if not (math.isfinite(args.backlash_mm) and 0.0 <= args.backlash_mm < 5.0):
        raise ValueError(f"--backlash-mm must be in [0, 5), got {args.backlash_mm!r}")
    cimm = build_cimm(args) if args.controller == "pf+cimm" else None
    folder = staged_folder(args.out, "renderer teleop")
    with folder:
        out = folder.path
        dev = make_device(args.master)
        with stop_on_signals(), dev:  # a stop signal raises in the session: closing the master zeroes it
            P = default_params()
            # the simulated slave takes --backlash-mm as in the all-sim session (the real master's own play is its own)
            tb = Testbed(P, P, environment=get_environment(args.environment), servo_rate_hz=dev.info.servo_rate_hz,
                         slave_handle_damping_N_s_m=args.slave_handle_damping, backlash_m=args.backlash_mm * 1e-3)
            cfg = resolve_gains(cfg, tb)
            check = None
            if cimm is not None:
                # the check needs the true master; here only the simulated Table 3.1 one is at hand, so it is
                # reported as a reference, not as a verdict on this device
                check = underestimation_check(cimm, tb.master)
                check["reference"] = "the simulated Table 3.1 master, not the device on the link"
                print(f"CIMM model: {cimm.source}; its underestimation check (eq. 5.14) can only be made against "
                      f"the simulated master: {check['warning'] or 'it underestimates that one below 8 Hz'}")
            print(f"master {dev.info.name} at {tb.servo_rate_hz:g} Hz; slave and {args.environment} simulated; "
                  f"{args.duration_s:g} s ...", flush=True)
            res, timing = run_serial_session(dev, tb, cfg, args.duration_s, cimm=cimm)
        _write_traces(out, res)
        run = {"command": "teleop", "argv": sys.argv[1:], "master": args.master, "controller": cfg.__dict__,
               "testbed": {"environment": tb.environment.__dict__, "sensors": tb.sensors.__dict__,
                           "servo_rate_hz": tb.servo_rate_hz, "slave": tb.slave.name, "backlash_m": tb.backlash_m,
                           "slave_handle_damping_N_s_m": tb.slave_handle_damping_N_s_m},
               "cimm_model": _cimm_record(cimm, check),
               "versions": software_versions(), "duration_s": args.duration_s, "link": timing,
               "clip_counts": res.counts, "fault": res.fault, "fault_tick": res.fault_tick}
        atomic_write_text(out / "run.json", json.dumps(run, indent=1, default=str))
        if not args.no_figures:
            figure_510(res, out / "figure_5_10.png", f"{cfg.controller} with master {args.master}, "
                       f"lambda = {cfg.lam:g}, mu = {cfg.mu:g}")
        p99 = timing["round_trip_p99_ms"]
        print(f"{timing['ticks']} ticks at {timing['rate_hz']:.0f} Hz achieved; round trip p50/p99 "
              f"{timing['round_trip_p50_ms'] or float('nan'):.2f}/{p99 if p99 is not None else float('nan'):.2f} ms; "
              f"late ticks {timing['late_ticks']}; peak slave force {float(np.max(res.col(K.O_FE), initial=0.0)):.2f} N; "
              f"fault {res.fault}")
        if timing["link_lost_tick"] is not None:
            print(f"error: the master link was lost at tick {timing['link_lost_tick']}: master output zero, slave "
                  f"held; data so far in {folder.out}", file=sys.stderr)
        print(f"wrote {folder.out}")
        return 1 if (timing["link_lost_tick"] is not None or res.fault) else 0


def figure_510(res, path: Path, title: str) -> None:
    """Figure 5.10-style plot of the first tap: F_f and x_c (and x_m, x_hat_mi,hf with cancellation), in the
    project style (figstyle: PNG, SVG and the plotted numbers as ``.plot.csv``, written into the run's folder)."""

    tr = res.traces if not res.fault else res.traces[:res.fault_tick + 1]
    fe = tr[:, K.O_FE]
    hit = np.flatnonzero(fe > 0.05)
    i0 = int(hit[0]) if len(hit) else 0
    a, b = max(0, i0 - int(0.02 * res.fs_hz)), min(len(tr), i0 + int(0.2 * res.fs_hz))
    t = (tr[a:b, K.O_T] - tr[i0, K.O_T]) * 1e3
    data = {"t_ms": t, "F_f_N": tr[a:b, K.O_FF], "x_c_mm": tr[a:b, K.O_XC] * 1e3}
    with figstyle.style() as plt:
        fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=figstyle.figsize("column", height_in=3.8),
                                       layout="constrained")
        ax1.plot(t, tr[a:b, K.O_FF], label="F_f")
        ax1.set_ylabel("F_f (N)")
        ax2.plot(t, tr[a:b, K.O_XC] * 1e3, label="x_c")
        if np.any(tr[a:b, K.O_XHAT] != 0):
            ax2.plot(t, tr[a:b, K.O_XM] * 1e3, label="x_m", alpha=0.7)
            ax2.plot(t, tr[a:b, K.O_XHAT] * 1e3, label="x_hat_mi,hf", alpha=0.7)
            data.update(x_m_mm=tr[a:b, K.O_XM] * 1e3, x_hat_mi_hf_mm=tr[a:b, K.O_XHAT] * 1e3)
        ax2.set_ylabel("position (mm)")
        ax2.set_xlabel("time after contact (ms)")
        fig.legend(handles=ax2.lines, loc="outside lower center", ncol=len(ax2.lines), fontsize=6)
        fig.suptitle(title, fontsize=8)
        figstyle.save(fig, path, data, force=True)   # the run's own folder (checked with --force before)


def sweep(tb: Testbed, cimm: CimmModel, lambdas, conditions, *, taps: int = 2, mu: float = 1.0,
          seed: int = 1, progress=None, servo_bandwidth_hz: float = SERVO_BANDWIDTH_HZ,
          press_depths_m=(PRESS_DEPTH_M,), lambda_speed_m_s: float | None = None) -> list[dict]:
    """Blind-randomised lambda sweep: one single-tap session per (condition, lambda, press depth, tap), random order.

    ``servo_bandwidth_hz`` is the servo-gain rule's natural frequency (``TeleopConfig.servo_bandwidth_hz``).
    ``press_depths_m``: how far below the surface the operator presses (the thesis gives none; the default path's
    2 mm). ``lambda_speed_m_s``: Figure 5.11's protocol, "the force feedback gain, lambda, was varied inversely
    with incoming velocity to keep the total magnitude of the haptic feedback within the device's limits"
    (section 5.7.2): each lambda's taps come in at ``lambda_speed_m_s / lambda`` (m/s; clipped to
    :data:`INVERSE_SPEED_RANGE_M_S`, :func:`renderer.teleop.calibration.feedback_limit_speed` gives the
    device's), instead of the fixed 0.08-0.12 m/s.

    The analysis (:func:`session_metrics`) sees only force traces; the condition is attached after.

    Returns
    -------
    list of dict (condition, lambda, speed_m_s, press_depth_mm, settling_s, stable, breaks, contact_losses,
    contact_class, hf_energy_fraction)
    """
    speeds = np.linspace(0.08, 0.12, taps) if taps > 1 else np.array([0.1])
    trials = []
    for c in conditions:
        for lam in lambdas:
            if lambda_speed_m_s is not None and lam > 0:
                v = min(max(lambda_speed_m_s / lam, INVERSE_SPEED_RANGE_M_S[0]), INVERSE_SPEED_RANGE_M_S[1])
                lam_speeds = [v] * taps
            else:
                lam_speeds = list(speeds)
            trials += [(c, lam, float(v), float(d)) for d in press_depths_m for v in lam_speeds]
    random.Random(seed).shuffle(trials)
    rows = []
    for j, (cond, lam, v, depth) in enumerate(trials):
        controller, extra = SWEEP_CONDITIONS[cond]
        cfg = TeleopConfig(controller=controller, mu=mu, lam=lam, servo_bandwidth_hz=servo_bandwidth_hz, **extra)
        path, cr = default_path(tb.servo_rate_hz, mu, n_taps=1, speed_m_s=v, press_depth_m=depth)
        res = run_session(tb, cfg, path, cimm=cimm, impact_ticks=cr, seed=j + 1)
        m = session_metrics(res)[0]
        rows.append({"condition": cond, "lambda": lam, "speed_m_s": v, "press_depth_mm": depth * 1e3,
                     "settling_s": (m.settling_s if m else math.inf),
                     "stable": bool(m.stable) if m else False, "breaks": m.breaks if m else -1,
                     "contact_losses": m.contact_losses if m else -1,
                     "contact_class": m.contact_class if m else "no contact",
                     "quasi_static_N": m.quasi_static_N if m else float("nan"),
                     "oscillation_N": m.oscillation_N if m else float("nan"),
                     "hf_energy_fraction": m.hf_energy_fraction if m else float("nan")})
        if progress is not None:
            progress(j + 1, len(trials))
    return rows


#: the incoming speeds Figure 5.11's lambda-by-speed protocol may ask of the operator (m/s): the demo's slowest
#: tap to the device's rated speed
INVERSE_SPEED_RANGE_M_S = (0.02, 0.5)


def largest_lambda(rows: list[dict], cond: str, classes=("settles",)) -> float:
    """Largest lambda of ``cond`` at which every tap, and every tap at every smaller lambda, is of one of
    ``classes`` (the contact classification, :func:`renderer.teleop.session.classify_contact`); 0 if none.

    ``("settles",)``: the largest lambda that settles; ``("settles", "buzzes")``: the largest that holds contact.
    """
    lams = sorted({r["lambda"] for r in rows if r["condition"] == cond})
    best = 0.0
    for lam in lams:
        if all(r["contact_class"] in classes for r in rows if r["condition"] == cond and r["lambda"] == lam):
            best = lam
        else:
            break
    return best


def largest_stable(rows: list[dict], cond: str) -> float:
    """Largest lambda of ``cond`` that holds contact (settles or buzzes) at every tap and every smaller lambda:
    the stability limit of Figure 5.11 ("cannot sustain a force reflection ratio above about 2.5")."""
    return largest_lambda(rows, cond, HOLDS_CONTACT)


def model_variants(cimm: CimmModel, error: float = 0.3) -> dict:
    """The CIMM model with +/- ``error`` in the user stiffness (k_u and q_u together) and the hand mass
    (the model's handle mass, which carries the hand's effective mass).

    Returns
    -------
    dict name -> CimmModel (including ``"nominal"``)
    """
    mh = cimm.params.mechanics["m_h_kg"]
    out = {"nominal": cimm}
    for sign, f in (("-", 1 - error), ("+", 1 + error)):
        out[f"user stiffness {sign}{error:.0%}"] = replace(cimm, k_u_N_m=cimm.k_u_N_m * f,
                                                          q_u_N_m5=cimm.q_u_N_m5 * f)
        out[f"hand mass {sign}{error:.0%}"] = replace(cimm, params=cimm.params.replace(
            mechanics={"m_h_kg": mh * f}))
    return out


def robustness(tb: Testbed, cimm: CimmModel, lambdas, *, taps: int = 2, mu: float = 1.0, seed: int = 1,
               error: float = 0.3, progress=None, servo_bandwidth_hz: float = SERVO_BANDWIDTH_HZ) -> dict:
    """``pf+cimm`` with each of :func:`model_variants` (the +/-30 % table); ``servo_bandwidth_hz`` as in
    :func:`sweep`.

    Returns
    -------
    dict name -> {"largest_stable_lambda": float, "largest_settling_lambda": float,
    "mean_contact_losses": float (per tap over the grid, after the impact's own 30 ms)}
    """
    out = {}
    for name, model in model_variants(cimm, error).items():
        rows = sweep(tb, model, lambdas, ["pf+cimm"], taps=taps, mu=mu, seed=seed, progress=progress,
                     servo_bandwidth_hz=servo_bandwidth_hz)
        out[name] = {"largest_stable_lambda": largest_stable(rows, "pf+cimm"),
                     "largest_settling_lambda": largest_lambda(rows, "pf+cimm", ("settles",)),
                     "mean_contact_losses": float(np.mean([r["breaks"] for r in rows]))}
    return out


def parse_press_depths(text: str | None) -> tuple:
    """``--press-depth-mm``: a comma list of press depths (mm) -> metres; None: the default path's 2 mm."""
    if text is None:
        return (PRESS_DEPTH_M,)
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--press-depth-mm: expected a comma list of depths in mm, got {text!r}") from None
    if not vals or any(not (math.isfinite(v) and 0.0 < v <= 20.0) for v in vals):
        raise ValueError(f"--press-depth-mm: every depth must be > 0 and <= 20 mm, got {text!r}")
    return tuple(v * 1e-3 for v in vals)


def sweep_table(rows: list[dict], conds, depths_m) -> tuple[list[str], dict]:
    """The sweep's Markdown table (one line per condition and press depth) and its summary.

    Columns: the largest lambda that settles and that holds contact (the contact classes, counting the losses after
    the impact's own 30 ms), F_f's energy above 50 Hz at the latter, the mean contact losses per tap after the
    impact's bounce and from the impact on, and at lambda = 3 the static contact force against the oscillation
    it must outweigh (means over the taps)."""
    table = ["| controller | press depth (mm) | largest lambda that settles | largest lambda that holds contact | "
             "F_f energy above 50 Hz at that lambda | contact losses per tap after the impact's 30 ms (from the "
             "impact on) | lambda = 3: static contact force / oscillation (N) |",
             "|---|---|---|---|---|---|---|"]
    summary = {}
    for c in conds:
        for d in depths_m:
            sel = [r for r in rows if r["condition"] == c and abs(r["press_depth_mm"] - d * 1e3) < 1e-9]
            ls = largest_lambda(sel, c, ("settles",))
            lm = largest_stable(sel, c)
            hf = [r["hf_energy_fraction"] for r in sel if r["lambda"] == lm]
            breaks = float(np.mean([r["breaks"] for r in sel]))
            losses = float(np.mean([r["contact_losses"] for r in sel]))
            at3 = [r for r in sel if r["lambda"] == 3.0]
            f3 = (float(np.mean([r["quasi_static_N"] for r in at3])), float(np.mean([r["oscillation_N"] for r in at3]))) \
                if at3 else None
            key = f"{c} @ {d * 1e3:g} mm"
            summary[key] = {"condition": c, "press_depth_mm": d * 1e3, "largest_settling_lambda": ls,
                            "largest_contact_lambda": lm, "hf_energy_fraction": float(np.nanmean(hf)) if hf else None,
                            "mean_contact_losses_after_bounce": breaks, "mean_contact_losses": losses,
                            "lambda_3_static_N": f3[0] if f3 else None, "lambda_3_oscillation_N": f3[1] if f3 else None}
            table.append(f"| {c} | {d * 1e3:g} | {ls:g} | {lm:g} | "
                         f"{summary[key]['hf_energy_fraction'] if hf else float('nan'):.2f} | {breaks:.1f} ({losses:.1f}) | "
                         + (f"{f3[0]:.2f} / {f3[1]:.2f} |" if f3 else "- |"))
    return table, summary


def run_sweep(args) -> int:
    """The ``teleop-sweep`` command."""
    lambdas = parse_lambdas(args.lam)
    conds = [c.strip() for c in args.conditions.split(",") if c.strip()]
    for c in conds:
        if c not in SWEEP_CONDITIONS:
            raise ValueError(f"--conditions: unknown {c!r} (valid: {', '.join(SWEEP_CONDITIONS)})")
    if args.taps < 1:
        raise ValueError(f"--taps must be >= 1, got {args.taps}")
    depths = parse_press_depths(args.press_depth_mm)
    tb = build_testbed(args)
    cimm = build_cimm(args)
    check = underestimation_check(cimm, tb.master)
    if check["warning"]:
        print(check["warning"])
    lam_speed = feedback_limit_speed(tb) if args.lambda_by_speed else None
    folder = staged_folder(args.out, "renderer teleop-sweep")
    with folder:
        out = folder.path
        # a bar on a terminal, plain lines in a log (a tqdm bar wrote \r-separated redraws into a file)
        bar = Progress(len(conds) * len(lambdas) * args.taps * len(depths), "teleop-sweep", unit="tap")
        rows = sweep(tb, cimm, lambdas, conds, taps=args.taps, mu=args.mu, seed=args.seed,
                     progress=lambda i, n: bar.update(i), servo_bandwidth_hz=args.servo_bandwidth_hz,
                     press_depths_m=depths, lambda_speed_m_s=lam_speed)
        bar.close()
        lines = ["condition,lambda,speed_m_s,press_depth_mm,settling_s,contact_class,breaks,contact_losses,stable,"
                 "quasi_static_N,oscillation_N,hf_energy_fraction"]
        for r in sorted(rows, key=lambda r: (r["condition"], r["press_depth_mm"], r["lambda"], r["speed_m_s"])):
            lines.append(f"{r['condition']},{r['lambda']:g},{r['speed_m_s']:.3f},{r['press_depth_mm']:g},"
                         f"{r['settling_s']:.4f},{r['contact_class']},{r['breaks']},{r['contact_losses']},"
                         f"{int(r['stable'])},{r['quasi_static_N']:.3f},{r['oscillation_N']:.3f},"
                         f"{r['hf_energy_fraction']:.3f}")
        atomic_write_text(out / "trials.csv", "\n".join(lines) + "\n")
        table, summary = sweep_table(rows, conds, depths)
        atomic_write_text(out / "table.md", "\n".join(table) + "\n")
        atomic_write_text(out / "run.json", json.dumps({
            "command": "teleop-sweep", "argv": sys.argv[1:], "lambdas": lambdas, "conditions": conds,
            "taps": args.taps, "seed": args.seed, "mu": args.mu, "environment": args.environment,
            "press_depths_mm": [d * 1e3 for d in depths], "lambda_times_speed_m_s": lam_speed,
            "backlash_m": tb.backlash_m, "slave_handle_damping_N_s_m": tb.slave_handle_damping_N_s_m,
            "servo_bandwidth_hz": args.servo_bandwidth_hz,
            "cimm_model": {"source": cimm.source, "underestimation_check": check}, "summary": summary,
            "versions": software_versions()}, indent=1, default=str))
        figure_511(rows, conds, out / "figure_5_11.png")
        if lam_speed is not None:
            print(f"Figure 5.11's protocol: lambda x incoming speed = {lam_speed:.3f} m/s (the feedback at its "
                  f"{TeleopConfig().ff_max_N:.2f} N limit)")
        print("\n".join(table))
        if args.robustness:
            rob = robustness(tb, cimm, lambdas, taps=args.taps, mu=args.mu, seed=args.seed,
                             servo_bandwidth_hz=args.servo_bandwidth_hz)
            lines = ["| CIMM model | largest lambda that settles | largest lambda that holds contact | "
                     "contact losses per tap after the impact's 30 ms (mean over the grid) |", "|---|---|---|---|"]
            lines += [f"| {k} | {v['largest_settling_lambda']:g} | {v['largest_stable_lambda']:g} | "
                      f"{v['mean_contact_losses']:.1f} |" for k, v in rob.items()]
            atomic_write_text(out / "robustness.md", "\n".join(lines) + "\n")
            print("\n".join(lines))
        print(f"wrote {folder.out}")
        return 0


def _contact_class(r: dict) -> str:
    """A sweep row's contact class (rows without one, e.g. older callers: settles if stable, else make-break)."""
    return r.get("contact_class", "settles" if r.get("stable") else "make-break")


def figure_511(rows, conds, path: Path) -> None:
    """Figure 5.11: settling time vs lambda per condition, every tap with a finite settling time, marked by its
    contact class (o settles, ^ buzzes, x make-break), with quadratic fits over the taps that hold contact; taps
    that make and break contact or never settle in the window also in a strip above, one row per condition. Project style (figstyle: PNG, SVG,
    the rows as ``.plot.csv``)."""

    markers = {"settles": "o", "buzzes": "^", "make-break": "x", "no contact": "x"}
    with figstyle.style() as plt:
        fig, (top, ax) = plt.subplots(2, 1, sharex=True, figsize=figstyle.figsize("page", height_in=4.6),
                                      height_ratios=(max(1, len(conds)) * 0.25, 3.0), layout="constrained")
        handles = []
        for k, c in enumerate(conds):
            rs = [r for r in rows if r["condition"] == c]
            lam = np.array([r["lambda"] for r in rs], dtype=float)
            st = np.array([r["settling_s"] * 1e3 for r in rs], dtype=float)
            cls = np.array([_contact_class(r) for r in rs])
            fin = np.isfinite(st)
            color = None
            for name, mk in markers.items():
                sel = fin & (cls == name)
                if sel.any():
                    ln = ax.plot(lam[sel], st[sel], mk, ms=4, color=color, label=c)[0]
                    color = ln.get_color()
            if color is None:   # nothing finite: a colour for the strip and the legend all the same
                color = ax.plot([], [], "o", ms=4, label=c)[0].get_color()
            handles.append(plt.Line2D([], [], color=color, marker="o", ls="", ms=4, label=c))
            lost = ~fin | ~np.isin(cls, HOLDS_CONTACT)
            top.plot(lam[lost], np.full(lost.sum(), k), "x", color=color, ms=5)
            held = fin & np.isin(cls, HOLDS_CONTACT)
            if held.sum() >= 3 and len(set(lam[held])) >= 3:
                co = np.polyfit(lam[held], st[held], 2)
                xx = np.linspace(lam[held].min(), lam[held].max(), 50)
                ax.plot(xx, np.polyval(co, xx), "-", color=color, alpha=0.6)
        handles += [plt.Line2D([], [], color="0.4", marker=mk, ls="", ms=4, label=name)
                    for name, mk in list(markers.items())[:3]]
        top.set_yticks(range(len(conds)), list(conds))
        top.set_ylim(-0.6, len(conds) - 0.4)
        top.invert_yaxis()
        top.set_title("taps that make and break contact or never settle (x), per condition", fontsize=7, loc="left")
        ax.set_xlabel("force-feedback gain lambda (1; mu = 1)")
        ax.set_ylabel("settling time of the contact force (ms)")
        fig.legend(handles=handles, loc="outside right upper", title="condition / contact", fontsize=6,
                   title_fontsize=6)
        fig.suptitle("Settling time vs lambda (cf. thesis Figure 5.11)", fontsize=8)
        header = ["condition", "lambda", "settling_ms", "stable", "contact_class"]
        data = (header, [(r["condition"], r["lambda"], r["settling_s"] * 1e3, int(bool(r["stable"])),
                          _contact_class(r)) for r in rows])
        figstyle.save(fig, path, data, force=True)   # the sweep's own folder (checked with --force before)
