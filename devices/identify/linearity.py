"""Linearity and time-invariance report (thesis sec. 3.4.3, Figure 3.8): ETFEs of handle acceleration at
several current magnitudes, grips and workspace positions, with coherence; a verdict per condition pair
(how far apart in dB and degrees, over which band) and a plain-language conclusion."""

from __future__ import annotations

import textwrap
import time
from dataclasses import dataclass

import numpy as np

import figstyle

from ..base import Device
from .etfe import Etfe, etfe
from .record import record_condition
from .sweep import SweepConfig

# two conditions "agree" where they differ by at most this much (the accuracy of a good LTI fit)
AGREE_DB = 1.0
AGREE_DEG = 10.0
MIN_COHERENCE = 0.9


@dataclass(frozen=True)
class Condition:
    """One test condition: sweep amplitude (A), grip (N), workspace position (m, handle space)."""

    amplitude_A: float
    grip_N: float
    position_m: float = 0.0
    repeat: int = 0

    @property
    def label(self) -> str:
        """Human-readable condition, e.g. ``0.5 A, grip 2 N, x 0 mm``."""
        s = f"{self.amplitude_A:g} A, grip {self.grip_N:g} N, x {self.position_m * 1e3:g} mm"
        return s + (" (repeat)" if self.repeat else "")


def default_conditions(info, amplitudes_A=None, grips_N=(1.0, 2.0, 3.0), positions_m=(0.0, 0.02)):
    """Amplitudes (small, middle, near the continuous limit) at the middle grip and first position; the
    other grips and positions at the middle amplitude; the first condition repeated at the end."""
    cont = info.current_continuous_A
    amps = tuple(amplitudes_A) if amplitudes_A else (round(0.08 * cont, 3), round(0.4 * cont, 3),
                                                     round(0.95 * cont, 3))
    g0 = grips_N[len(grips_N) // 2]
    a_mid = amps[len(amps) // 2]
    conds = [Condition(a, g0, positions_m[0]) for a in amps]
    conds += [Condition(a_mid, g, positions_m[0]) for g in grips_N if g != g0]
    conds += [Condition(a_mid, g0, p) for p in positions_m[1:]]
    conds.append(Condition(amps[0], g0, positions_m[0], repeat=1))
    return conds


def measure(dev: Device, conditions, trials: int = 2, duration_s: float = 1.0, f_start_hz: float = 5.0,
            f_end_hz: float = 1000.0, log=None) -> list[Etfe]:
    """ETFE (acceleration, with coherence across ``trials``) per condition. On the sim the hand holds the
    handle at the condition's position; on hardware the operator is asked to."""
    out = []
    for k, c in enumerate(conditions):
        if log:
            log(f"[{k + 1}/{len(conditions)}] {c.label}")
        if getattr(dev, "set_user", None) is not None and dev.simulated:
            dev.set_user(float(c.position_m), grip_N=c.grip_N)
        elif log and c.position_m:
            log(f"move the handle to {c.position_m * 1e3:g} mm and hold it there")
        sweep = SweepConfig(amplitude_A=c.amplitude_A, f_start_hz=f_start_hz, f_end_hz=f_end_hz,
                            duration_s=duration_s, fs_hz=dev.info.servo_rate_hz, repetitions=2)
        recs = record_condition(dev, sweep, c.grip_N, trials)
        out.append(etfe(recs, "accel_m_s2", label=c.label, detrend="periodic"))
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of a boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def compare_pair(a: Etfe, b: Etfe, band_hz=(20.0, 500.0), min_coherence: float = MIN_COHERENCE,
                 agree_db: float = AGREE_DB, agree_deg: float = AGREE_DEG) -> dict:
    """How far apart two ETFEs are over a band, where both are coherent.

    Differences are smoothed over 1/6 octave (so single noisy bins do not decide); the band where they
    exceed ``agree_db`` or ``agree_deg`` is reported as ``[lo, hi]`` (None if they agree).

    Returns
    -------
    dict
        ``max_db``, ``rms_db``, ``max_deg``, ``rms_deg``, ``differs_hz`` ([lo, hi] or None), ``agree``
        (bool), ``coherent_fraction``.
    """
    sel = (a.f_hz >= band_hz[0]) & (a.f_hz <= band_hz[1])
    f = a.f_hz[sel]
    ok = (a.coherence[sel] >= min_coherence) & (b.coherence[sel] >= min_coherence)
    ddb = 20 * np.log10(np.abs(a.H[sel]) / np.abs(b.H[sel]))
    ddeg = np.degrees(np.angle(a.H[sel] / b.H[sel]))
    # 1/6-octave running mean over coherent bins
    sm_db = np.full(f.size, np.nan)
    sm_deg = np.full(f.size, np.nan)
    for i in range(f.size):
        w = ok & (f >= f[i] * 2 ** (-1 / 12)) & (f <= f[i] * 2 ** (1 / 12))
        if ok[i] and w.any():
            sm_db[i] = ddb[w].mean()
            sm_deg[i] = ddeg[w].mean()
    valid = np.isfinite(sm_db)
    if not valid.any():
        return {"max_db": float("nan"), "rms_db": float("nan"), "max_deg": float("nan"), "rms_deg": float("nan"),
                "differs_hz": None, "agree": False, "coherent_fraction": 0.0, "band_hz": list(band_hz)}
    bad = valid & ((np.abs(sm_db) > agree_db) | (np.abs(sm_deg) > agree_deg))
    differs = None
    if bad.any():
        runs = _runs(bad)
        lo, hi = runs[0][0], runs[-1][1] - 1
        differs = [float(f[lo]), float(f[hi])]
    return {"max_db": float(np.nanmax(np.abs(sm_db))), "rms_db": float(np.sqrt(np.nanmean(sm_db ** 2))),
            "max_deg": float(np.nanmax(np.abs(sm_deg))), "rms_deg": float(np.sqrt(np.nanmean(sm_deg ** 2))),
            "differs_hz": differs, "agree": not bad.any(), "coherent_fraction": float(ok.mean()),
            "band_hz": list(band_hz)}


def linearity_report(dev: Device, conditions=None, band_hz=(20.0, 500.0), trials: int = 2,
                     duration_s: float = 1.0, log=None) -> dict:
    """Measure every condition and judge every pair that differs in one factor only.

    Returns
    -------
    dict
        ``conditions`` (labels), ``pairs`` (factor, the two labels, :func:`compare_pair` fields, verdict
        text), ``verdicts`` per factor (``amplitude``, ``grip``, ``position``, ``time``: "same" or
        "differs"), ``linear`` (amplitude, position and time all agree), ``conclusion`` (plain language),
        ``curves`` (the ETFEs, for the figure).
    """
    t0 = time.perf_counter()
    conds = list(conditions) if conditions else default_conditions(dev.info)
    curves = measure(dev, conds, trials, duration_s, log=log)
    pairs = []
    for i in range(len(conds)):
        for j in range(i + 1, len(conds)):
            a, b = conds[i], conds[j]
            diff = [n for n, x, y in (("amplitude", a.amplitude_A, b.amplitude_A), ("grip", a.grip_N, b.grip_N),
                                      ("position", a.position_m, b.position_m)) if x != y]
            if len(diff) == 0 and a.repeat != b.repeat:
                factor = "time"
            elif len(diff) == 1 and a.repeat == b.repeat == 0:
                factor = diff[0]
            else:
                continue
            cmp = compare_pair(curves[i], curves[j], band_hz)
            if cmp["agree"]:
                text = (f"agree within {AGREE_DB:g} dB / {AGREE_DEG:g} deg over {band_hz[0]:g}-{band_hz[1]:g} Hz "
                        f"(max {cmp['max_db']:.2f} dB, {cmp['max_deg']:.1f} deg)")
            else:
                lo, hi = cmp["differs_hz"]
                text = (f"differ between {lo:.0f} and {hi:.0f} Hz: up to {cmp['max_db']:.1f} dB and "
                        f"{cmp['max_deg']:.0f} deg")
            pairs.append({"factor": factor, "a": a.label, "b": b.label, **cmp, "verdict": text})
    verdicts = {}
    for factor in ("amplitude", "grip", "position", "time"):
        ps = [p for p in pairs if p["factor"] == factor]
        if ps:
            verdicts[factor] = "same" if all(p["agree"] for p in ps) else "differs"
    linear = all(verdicts.get(f, "same") == "same" for f in ("amplitude", "position", "time"))
    conclusion = _conclusion(pairs, verdicts, band_hz)
    return {"device": dev.info.name, "conditions": [c.label for c in conds], "pairs": pairs, "verdicts": verdicts,
            "linear": linear, "conclusion": conclusion, "curves": curves, "band_hz": list(band_hz),
            "elapsed_s": time.perf_counter() - t0}


def _span(pairs, factor):
    ps = [p for p in pairs if p["factor"] == factor and not p["agree"]]
    return min(p["differs_hz"][0] for p in ps), max(p["differs_hz"][1] for p in ps), max(p["max_db"] for p in ps)


def _conclusion(pairs, verdicts, band_hz) -> str:
    lines = []
    if verdicts.get("amplitude") == "differs":
        lo, hi, db = _span(pairs, "amplitude")
        lines.append(f"amplitude-dependent between {lo:.0f} and {hi:.0f} Hz (up to {db:.1f} dB): the device is "
                     "nonlinear; use successive isolation (python -m devices identify --method successive) or "
                     "amplitude-matched models")
    if verdicts.get("position") == "differs":
        lo, hi, db = _span(pairs, "position")
        lines.append(f"position-dependent between {lo:.0f} and {hi:.0f} Hz (up to {db:.1f} dB): identify where "
                     "the device is used or model the configuration dependence")
    if verdicts.get("time") == "differs":
        lo, hi, db = _span(pairs, "time")
        lines.append(f"not time-invariant: the repeated condition moved between {lo:.0f} and {hi:.0f} Hz (up to "
                     f"{db:.1f} dB; warm-up, drift or a changed grasp)")
    if verdicts.get("grip") == "differs":
        lo, hi, db = _span(pairs, "grip")
        lines.append(f"grip-dependent between {lo:.0f} and {hi:.0f} Hz (up to {db:.1f} dB), as expected from the "
                     "user's impedance (sec. 3.4.6): use a grip-dependent model set")
    if not any(verdicts.get(f) == "differs" for f in ("amplitude", "position", "time")):
        lines.insert(0, f"linear and time-invariant over {band_hz[0]:g}-{band_hz[1]:g} Hz: the ETFEs at different "
                        f"current magnitudes{', positions' if 'position' in verdicts else ''} and over time agree "
                        f"within {AGREE_DB:g} dB / {AGREE_DEG:g} deg; an LTI model from comprehensive evaluation "
                        "suffices")
    return "\n".join(lines)


def format_linearity(report: dict) -> str:
    """Plain-text report: one line per pair, then the conclusion."""
    lines = [f"linearity and time invariance of {report['device']} ({len(report['conditions'])} conditions, "
             f"{report['band_hz'][0]:g}-{report['band_hz'][1]:g} Hz, coherence >= {MIN_COHERENCE:g})"]
    for p in report["pairs"]:
        lines.append(f"  {p['factor']:9s} {p['a']}  vs  {p['b']}: {p['verdict']}")
    lines.append("verdicts: " + ", ".join(f"{k} {v}" for k, v in report["verdicts"].items()))
    lines.append("conclusion: " + report["conclusion"])
    return "\n".join(lines) + "\n"


def linearity_figure(report: dict, path, min_coherence: float = MIN_COHERENCE) -> str:
    """Bode overlay of all conditions (Figure 3.8 style) in the project style (figstyle: PNG, SVG and the plotted
    numbers as ``.plot.csv``): low-coherence bins masked (gaps, no spikes), phase unwrapped over the coherent bins
    and shifted by whole turns to start within +-180 deg; the conclusion in full under the title (it was cut off
    at the figure's edge)."""

    lo, hi = report["band_hz"]
    rows = []
    with figstyle.style() as plt:
        fig, (am, ap) = plt.subplots(2, 1, figsize=figstyle.figsize("page", height_in=5.6), sharex=True,
                                     layout="constrained")
        for c in report["curves"]:
            sel = (c.f_hz >= lo / 2) & (c.f_hz <= min(hi * 2, c.f_hz[-1]))
            f = c.f_hz[sel]
            H = c.H[sel]
            ok = c.coherence[sel] >= min_coherence
            mag = np.where(ok, 20 * np.log10(np.abs(H)), np.nan)
            ph = np.full(f.size, np.nan)
            if ok.any():
                u = np.degrees(np.unwrap(np.angle(H[ok])))
                u -= 360.0 * np.round(u[0] / 360.0)
                ph[ok] = u
            am.semilogx(f, mag, lw=1, label=c.label)
            ap.semilogx(f, ph, lw=1)
            rows += [(c.label, fk, mk, pk, int(okk)) for fk, mk, pk, okk in zip(f, mag, ph, ok)]
        for ax in (am, ap):
            ax.axvspan(lo, hi, color="0.93", zorder=0)
            ax.grid(True, which="both", alpha=0.3)
        am.set_ylabel("|a/i| (dB re 1 m/s^2/A)")
        ap.set_ylabel("phase (deg)")
        ap.set_xlabel("frequency (Hz)")
        am.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=6, borderaxespad=0.0)
        conclusion = textwrap.fill("conclusion: " + " ".join(report["conclusion"].split()), 120)
        fig.suptitle(f"{report['device']}: ETFEs per condition (coherence < {min_coherence:g} masked)\n"
                     + conclusion, fontsize=7)
        paths = figstyle.save(fig, path, (["condition", "f_hz", "magnitude_db", "phase_deg", "coherent"], rows),
                              force=True)   # the command checked its --out (and --force) before measuring
    return str(paths["png"])
