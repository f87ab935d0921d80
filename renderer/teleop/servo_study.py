"""Servo-bandwidth study: do section 5.7's targets hold at any natural frequency of the servo rule?

The servo rule (docs/teleop.md, "Gains") puts every joystick servo's natural frequency at the user's
motion-control bandwidth, 8 Hz (damping ratio 0.7). The thesis gives no gains for section 5.7's slave; its one
value for a slave PD is section 4.3.1's, on the Phantom testbed: the HFAM high-pass is "a second-order linear
filter with a bandwidth of 22 hertz, well matched to the second-order low-pass behavior of the slave's PD
controller and significantly above the range of human intention". Humans "cannot move or position their
fingertips at frequencies above eight to ten hertz" (section 1.1).

:func:`servo_study` measures section 5.7's targets at each natural frequency of a grid spanning both
(6-22 Hz by default). At each it first re-identifies the slave's unheld-handle damping on the natural impact
(:func:`renderer.teleop.calibration.calibrate_slave_handle_damping`: a lambda = 0 tap settles in 40 ms), so every
point is the testbed as the project would build it had the rule chosen that frequency; then it runs the
blind-randomised sweep of Figure 5.10 (no backlash) and of Figure 5.11 (its condition: the backlash, and "a
simpler, less-accurate model" for the cancellation, :func:`figure_5_11_model`), and bilateral PD taps on wood. It never changes the model: the default stays the rule's 8 Hz whatever the table shows. Its purpose
is the issue's "If a target cannot be met without fitting, say which and show why with measurements": a target
that no point of the grid meets cannot be met by choosing the servo bandwidth either.

Compute and present are separate (:func:`servo_study` / :func:`study_table`); the command is
``python -m renderer teleop-servo-study`` (:func:`run_servo_study`).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from devices.sim.params import default_params
from devices.sim.teleop import BACKLASH_FIG_5_11_M, ENVIRONMENTS, CimmModel, Testbed
from plumbing.fileio import atomic_write_text
from plumbing.progress import Progress

from .calibration import CALIBRATION_SPEEDS_M_S, calibrate_slave_handle_damping, natural_impact_settling_s
from .commands import build_cimm, largest_stable, software_versions, sweep, staged_folder
from .models import simpler_params
from .session import (GRACE_S, TeleopConfig, classify_contact, default_path, joystick_mass_kg, run_session,
                      servo_gains, session_metrics)

#: the grid: the rule's 8 Hz, the 8-10 Hz of human motion, and up to section 4.3.1's 22 Hz slave PD
STUDY_BANDWIDTHS_HZ = (6.0, 8.0, 10.0, 12.6, 16.0, 20.0, 22.0)
#: Figure 5.10's four columns, and the natural impact (lambda = 0) and section 5.8's lambda = 15
FIG_5_10_LAMBDAS = (0.0, 1.0, 3.0, 6.0, 10.0, 15.0)
#: Figure 5.11 (backlash): fine enough to place a limit within 2-3.5 or 4-6
FIG_5_11_LAMBDAS = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0, 8.0, 10.0)
#: damping interval searched at every frequency (N s/m): the natural impact settles in 40 ms with 2.4-3.1 N s/m at
#: 6-8 Hz and 1.3-2.4 N s/m at 12.6-22 Hz; at 10 Hz in no less than 46 ms at 6 N s/m (43 ms at 12 N s/m): not
#: identifiable there
STUDY_DAMPING_BRACKET = (0.0, 6.0)
#: bilateral PD taps on wood per point ("at most one bounce per tap")
PD_TAPS = 3
CONDITIONS = ("pf", "pf+cimm")

#: section 5.7's targets checked at every point: key -> the target in words
TARGETS = {
    "pf_1_settles": "Fig. 5.10: pf, lambda = 1 settles in 40-60 ms",
    "pf_3_buzzes": "Fig. 5.10: pf, lambda = 3 holds contact and buzzes > 100 ms",
    "pf_6_make_break": "Fig. 5.10: pf, lambda = 6 makes and breaks",
    "cimm_10_settles": "Fig. 5.10: pf+cimm, lambda = 10 settles within 60 ms",
    "cimm_stable_15": "Sec. 5.8: pf+cimm stable to lambda = 15, settling within 1.3x its lambda = 1 value",
    "fig511_pf": "Fig. 5.11 (backlash): pf's largest stable lambda 2-3.5",
    "fig511_cimm": "Fig. 5.11 (backlash): pf+cimm's largest stable lambda 4-6",
    "pd_one_bounce": "Bilateral PD on wood: at most one bounce per tap",
}


@dataclass(frozen=True)
class TargetCheck:
    """One target at one servo bandwidth.

    Attributes
    ----------
    key : str
        Key of ``TARGETS``.
    met : bool
    measured : str
        What was measured, e.g. ``"2m 44 ms / 3m 61 ms"`` (per tap: contact losses, class initial, settling).
    """

    key: str
    met: bool
    measured: str


@dataclass(frozen=True)
class ServoPoint:
    """The testbed at one natural frequency of the servo rule, and its targets.

    Attributes
    ----------
    servo_bandwidth_hz : float
        Natural frequency of the rule (Hz; damping ratio 0.7).
    kp_s_N_m, kd_s_Ns_m : float
        The slave gains the rule gives there.
    damping_N_s_m : float
        Slave unheld-handle damping identified on the natural impact at this servo (N s/m; nan if the 50 ms
        natural impact is not reachable within ``STUDY_DAMPING_BRACKET``, and then nothing else was run).
    natural_settling_s : float
        Mean natural-impact settling time at that damping (s).
    rows, backlash_rows : tuple of dict
        The sweep's trials without backlash (``FIG_5_10_LAMBDAS``) and with Figure 5.11's backlash
        (``FIG_5_11_LAMBDAS``), as :func:`renderer.teleop.commands.sweep` returns them.
    pd_losses : tuple of int
        Contact losses per tap of bilateral PD on wood (``PD_TAPS`` taps).
    checks : tuple of TargetCheck
        One per ``TARGETS`` key, in its order.
    """

    servo_bandwidth_hz: float
    kp_s_N_m: float
    kd_s_Ns_m: float
    damping_N_s_m: float
    natural_settling_s: float
    rows: tuple
    backlash_rows: tuple
    pd_losses: tuple
    checks: tuple

    @property
    def met(self) -> int:
        """Number of targets met."""
        return sum(c.met for c in self.checks)


def _taps(rows, cond: str, lam: float) -> list[dict]:
    return sorted((r for r in rows if r["condition"] == cond and r["lambda"] == lam), key=lambda r: r["speed_m_s"])


def _describe(taps: list[dict]) -> str:
    """Per tap: contact losses, the class's initial (s / b / m), settling ms (inf: never within the window)."""
    out = []
    for r in taps:
        s = r["settling_s"]
        ms = f"{s * 1e3:.0f} ms" if math.isfinite(s) else "inf"
        out.append(f"{r['contact_losses']}{r['contact_class'][0]} {ms}")
    return " / ".join(out)


def _all(taps: list[dict], pred) -> bool:
    return bool(taps) and all(pred(r) for r in taps)


def from_impact(rows) -> list[dict]:
    """Sweep rows re-classified counting every contact loss from the impact on, the impact's own bounce included.

    The classification before the project counted only the losses after the impact's bounce (``GRACE_S``, 30 ms;
    :func:`renderer.teleop.session.classify_contact`); this variant is kept to show what the count changes: the
    slave's natural impact (lambda = 0, no feedback loop, so nothing that could be unstable) bounces 1-3 times
    within those 30 ms on the rule's 8 Hz servo, which the count from the impact on classes as make-break.

    Parameters
    ----------
    rows : sequence of dict
        :func:`renderer.teleop.commands.sweep` rows (``contact_losses``: every loss from the impact on).

    Returns
    -------
    list of dict
        Copies with ``contact_class`` re-computed from ``contact_losses``; rows without contact unchanged.
    """
    out = []
    for r in rows:
        r = dict(r)
        if r["contact_losses"] >= 0:
            r["contact_class"] = classify_contact(r["contact_losses"], r["settling_s"])
        out.append(r)
    return out


def check_targets(rows, backlash_rows, pd_losses) -> tuple[TargetCheck, ...]:
    """Section 5.7's targets (``TARGETS``) on one point's sweeps.

    Parameters
    ----------
    rows : sequence of dict
        Sweep trials without backlash, at least at lambda 1, 3, 6, 10 and 15 for ``pf`` and ``pf+cimm``.
    backlash_rows : sequence of dict
        Sweep trials with Figure 5.11's backlash.
    pd_losses : sequence of int
        Contact losses per tap of bilateral PD on wood.

    Returns
    -------
    tuple of TargetCheck
        In ``TARGETS`` order. "Settles", "buzzes", "make-break" and "holds contact" are the sweep's contact
        classes (:func:`renderer.teleop.session.classify_contact`), every tap of the cell.
    """
    def settles_within(lo_s, hi_s):
        return lambda r: r["contact_class"] == "settles" and lo_s <= r["settling_s"] <= hi_s

    pf1, pf3, pf6 = _taps(rows, "pf", 1.0), _taps(rows, "pf", 3.0), _taps(rows, "pf", 6.0)
    c1, c10, c15 = _taps(rows, "pf+cimm", 1.0), _taps(rows, "pf+cimm", 10.0), _taps(rows, "pf+cimm", 15.0)
    stable_cimm = largest_stable(list(rows), "pf+cimm")
    s1 = np.mean([r["settling_s"] for r in c1]) if c1 else math.nan
    s15 = np.mean([r["settling_s"] for r in c15]) if c15 else math.nan
    ratio = float(s15 / s1) if math.isfinite(s15) and s1 > 0 else math.inf
    lim_pf = largest_stable(list(backlash_rows), "pf")
    lim_cimm = largest_stable(list(backlash_rows), "pf+cimm")
    checks = [
        TargetCheck("pf_1_settles", _all(pf1, settles_within(0.040, 0.060)), _describe(pf1)),
        TargetCheck("pf_3_buzzes", _all(pf3, lambda r: r["contact_class"] == "buzzes"), _describe(pf3)),
        TargetCheck("pf_6_make_break", _all(pf6, lambda r: r["contact_class"] == "make-break"), _describe(pf6)),
        TargetCheck("cimm_10_settles", _all(c10, settles_within(0.0, 0.060)), _describe(c10)),
        TargetCheck("cimm_stable_15", stable_cimm >= 15.0 and ratio <= 1.3,
                    f"holds contact to {stable_cimm:g}; settling at 15 / at 1: {ratio:.2f}x"),
        TargetCheck("fig511_pf", 2.0 <= lim_pf <= 3.5, f"{lim_pf:g}"),
        TargetCheck("fig511_cimm", 4.0 <= lim_cimm <= 6.0, f"{lim_cimm:g}"),
        TargetCheck("pd_one_bounce", bool(pd_losses) and max(pd_losses) <= 1,
                    "/".join(str(n) for n in pd_losses)),
    ]
    return tuple(checks)


def pd_losses_on_wood(servo_bandwidth_hz: float, damping_N_s_m: float, *, taps: int = PD_TAPS,
                      base: Testbed | None = None, count_from_impact: bool = False) -> tuple[int, ...]:
    """Contact losses per tap of bilateral PD on wood (the operator's default path, ``taps`` taps at 0.1 m/s).

    Parameters
    ----------
    servo_bandwidth_hz : float
        Natural frequency of the rule for both servos (Hz).
    damping_N_s_m : float
        Slave unheld-handle damping (N s/m).
    taps : int
    base : Testbed or None
        Default: Table 3.1 master and slave; the environment is replaced by wood.
    count_from_impact : bool
        Count every loss from the impact on (``TapMetrics.contact_losses``) instead of those later than
        ``GRACE_S`` after it (``TapMetrics.breaks``, the project's count).

    Returns
    -------
    tuple of int
        One count per tap (-1 for a tap that never touched).
    """
    P = default_params()
    tb = replace(base or Testbed(P, P), environment=ENVIRONMENTS["wood"], slave_handle_damping_N_s_m=damping_N_s_m,
                 backlash_m=0.0)
    path, cr = default_path(tb.servo_rate_hz, 1.0, n_taps=taps)
    res = run_session(tb, TeleopConfig(controller="pd", servo_bandwidth_hz=servo_bandwidth_hz), path, impact_ticks=cr)
    return tuple(-1 if m is None else (m.contact_losses if count_from_impact else m.breaks)
                 for m in session_metrics(res))


def figure_5_11_model(cimm: CimmModel) -> CimmModel:
    """The cancellation's model in Figure 5.11's condition: "the tests shown in Figure 5.11 were performed with a
    simpler, less-accurate model of the human-master dynamics" (section 5.7.2). ``cimm`` with its master's linkage
    made linear (:func:`renderer.teleop.models.simpler_params`); user model, step and washout unchanged."""
    params, source = simpler_params(cimm.params, cimm.source)
    return replace(cimm, params=params, source=source)


def study_point(servo_bandwidth_hz: float, cimm: CimmModel, *, taps: int = 2, seed: int = 1,
                base: Testbed | None = None, damping_N_s_m: float | None = None,
                count_from_impact: bool = False) -> ServoPoint:
    """The testbed at one servo natural frequency: identify the slave handle's damping, sweep, check the targets.

    Parameters
    ----------
    servo_bandwidth_hz : float
        Natural frequency of the servo rule (Hz), for every servo.
    cimm : CimmModel
        The cancellation's model of the master (Figure 5.11's sweep uses :func:`figure_5_11_model` of it).
    taps : int
        Taps per condition and lambda (speeds 0.08-0.12 m/s).
    seed : int
        Seed of the sweep's blind randomisation.
    base : Testbed or None
        Default: Table 3.1 master and slave on the hard surface, no backlash.
    damping_N_s_m : float or None
        None (default): identify the slave handle's damping on the natural impact at this servo; a number: use
        it as given (to separate the servo's effect from the identification's).
    count_from_impact : bool
        Classify the taps by :func:`from_impact` (every loss from the impact on) instead of the project's count
        of the losses later than 30 ms after it; the bilateral PD count likewise.

    Returns
    -------
    ServoPoint
    """
    P = default_params()
    tb0 = base or Testbed(P, P, environment=ENVIRONMENTS["hard"])
    cfg = TeleopConfig(controller="pf", servo_bandwidth_hz=servo_bandwidth_hz)
    kp, kd = servo_gains(joystick_mass_kg(tb0.slave), servo_bandwidth_hz)
    if damping_N_s_m is None:
        try:
            cal = calibrate_slave_handle_damping(testbed=tb0, config=cfg, bracket=STUDY_DAMPING_BRACKET)
        except ValueError as exc:
            # recorded, not raised: the rest of the grid is still worth measuring
            miss = tuple(TargetCheck(k, False, f"not identifiable: {exc}") for k in TARGETS)
            return ServoPoint(servo_bandwidth_hz, kp, kd, math.nan, math.nan, (), (), (), miss)
        damping, natural = cal.damping_N_s_m, cal.settling_s
    else:
        damping = float(damping_N_s_m)
        natural = float(np.mean(natural_impact_settling_s(damping, testbed=tb0, config=cfg)))
    tb = replace(tb0, slave_handle_damping_N_s_m=damping)
    rows = sweep(tb, cimm, FIG_5_10_LAMBDAS, CONDITIONS, taps=taps, seed=seed, servo_bandwidth_hz=servo_bandwidth_hz)
    brows = sweep(replace(tb, backlash_m=BACKLASH_FIG_5_11_M), figure_5_11_model(cimm), FIG_5_11_LAMBDAS, CONDITIONS,
                  taps=taps, seed=seed, servo_bandwidth_hz=servo_bandwidth_hz)
    pd = pd_losses_on_wood(servo_bandwidth_hz, damping, base=tb0, count_from_impact=count_from_impact)
    if count_from_impact:
        rows, brows = from_impact(rows), from_impact(brows)
    return ServoPoint(servo_bandwidth_hz, kp, kd, damping, natural, tuple(rows), tuple(brows), pd,
                      check_targets(rows, brows, pd))


def servo_study(cimm: CimmModel, bandwidths_hz=STUDY_BANDWIDTHS_HZ, *, taps: int = 2, seed: int = 1,
                base: Testbed | None = None, damping_N_s_m: float | None = None, count_from_impact: bool = False,
                progress=None) -> list[ServoPoint]:
    """:func:`study_point` at every natural frequency of ``bandwidths_hz`` (Hz), in order.

    ``progress(i, n)`` is called after each point. About 1-2 s per point on this machine.
    """
    out = []
    for i, f in enumerate(bandwidths_hz):
        out.append(study_point(float(f), cimm, taps=taps, seed=seed, base=base, damping_N_s_m=damping_N_s_m,
                               count_from_impact=count_from_impact))
        if progress is not None:
            progress(i + 1, len(bandwidths_hz))
    return out


def study_table(points: list[ServoPoint]) -> str:
    """Markdown: one column per servo bandwidth, one row per target (yes / no and what was measured)."""
    head = "| target | " + " | ".join(f"{p.servo_bandwidth_hz:g} Hz" for p in points) + " |"
    lines = [head, "|---" * (len(points) + 1) + "|"]
    lines.append("| slave gains (N/m, N s/m) | " + " | ".join(f"{p.kp_s_N_m:.0f}, {p.kd_s_Ns_m:.2f}" for p in points)
                 + " |")
    lines.append("| slave handle damping, identified on the natural impact (N s/m) | "
                 + " | ".join(f"{p.damping_N_s_m:.2f}" for p in points) + " |")
    lines.append("| natural impact (lambda = 0) per tap | "
                 + " | ".join(_describe(_taps(p.rows, "pf", 0.0)) or "-" for p in points) + " |")
    for k, text in TARGETS.items():
        cells = []
        for p in points:
            c = next(c for c in p.checks if c.key == k)
            cells.append(f"{'**yes**' if c.met else 'no'}: {c.measured}")
        lines.append(f"| {text} | " + " | ".join(cells) + " |")
    lines.append("| targets met | " + " | ".join(f"{p.met} of {len(TARGETS)}" for p in points) + " |")
    return "\n".join(lines) + "\n"


def parse_bandwidths(text: str) -> list[float]:
    """``--servo-bandwidth-hz`` of the study: a comma list of natural frequencies (Hz), each finite and > 0."""
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--servo-bandwidth-hz: expected a comma list of frequencies in Hz, got {text!r}") from None
    if not vals or any(not (math.isfinite(v) and v > 0) for v in vals):
        raise ValueError(f"--servo-bandwidth-hz: every frequency must be finite and > 0 Hz, got {text!r}")
    return vals


def run_servo_study(args) -> int:
    """The ``teleop-servo-study`` command: table.md, study.json and trials.csv in ``--out``."""
    bands = parse_bandwidths(args.servo_bandwidth_hz)
    if args.taps < 1:
        raise ValueError(f"--taps must be >= 1, got {args.taps}")
    fixed = args.fixed_slave_handle_damping
    if fixed is not None and not (math.isfinite(fixed) and fixed >= 0):
        raise ValueError(f"--fixed-slave-handle-damping-N-s-m must be a number >= 0, got {fixed!r}")
    cimm = build_cimm(args)
    folder = staged_folder(args.out, "renderer teleop-servo-study")
    with folder:
        out = folder.path
        bar = Progress(len(bands), "teleop-servo-study", unit="point")
        points = servo_study(cimm, bands, taps=args.taps, seed=args.seed, damping_N_s_m=fixed,
                             count_from_impact=args.count_from_impact,
                             progress=lambda i, n: bar.update(i))
        bar.close()
        table = study_table(points)
        atomic_write_text(out / "table.md", table)
        lines = ["servo_bandwidth_hz,backlash,condition,lambda,speed_m_s,settling_s,contact_class,contact_losses"]
        for p in points:
            for backlash, rows in ((0, p.rows), (1, p.backlash_rows)):
                for r in sorted(rows, key=lambda r: (r["condition"], r["lambda"], r["speed_m_s"])):
                    lines.append(f"{p.servo_bandwidth_hz:g},{backlash},{r['condition']},{r['lambda']:g},"
                                 f"{r['speed_m_s']:.3f},{r['settling_s']:.4f},{r['contact_class']},{r['contact_losses']}")
        atomic_write_text(out / "trials.csv", "\n".join(lines) + "\n")
        record = {"command": "teleop-servo-study", "argv": sys.argv[1:], "taps": args.taps, "seed": args.seed,
                  "speeds_m_s": list(CALIBRATION_SPEEDS_M_S), "fixed_slave_handle_damping_N_s_m": fixed,
                  "contact_losses_counted_from_s": 0.0 if args.count_from_impact else GRACE_S,
                  "backlash_m": BACKLASH_FIG_5_11_M, "cimm_model": cimm.source,
                  "figure_5_11_cimm_model": figure_5_11_model(cimm).source, "targets": TARGETS,
                  "points": [{"servo_bandwidth_hz": p.servo_bandwidth_hz, "kp_s_N_m": p.kp_s_N_m, "kd_s_Ns_m": p.kd_s_Ns_m,
                              "slave_handle_damping_N_s_m": p.damping_N_s_m, "natural_settling_s": p.natural_settling_s,
                              "pd_losses_on_wood": list(p.pd_losses), "targets_met": p.met,
                              "checks": [asdict(c) for c in p.checks]} for p in points],
                  "versions": software_versions()}
        atomic_write_text(out / "study.json", json.dumps(record, indent=1, default=str))
        print(table, end="")
        best = max(p.met for p in points) if points else 0
        print(f"most targets met at one servo bandwidth: {best} of {len(TARGETS)}")
        print(f"wrote {folder.out}")
        return 0
