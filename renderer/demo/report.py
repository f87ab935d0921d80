"""The demo's printed table and its files: ``summary.csv`` and ``traces.npz``."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from . import runs
from .config import DemoConfig, DemoResult


SUMMARY_COLUMNS = ("rendering", "velocity_m_s", "grip_N", "peak_accel_m_s2", "dominant_freq_hz",
                   "penetration_mean_m", "nrmse", "correlation", "clipped")


def write_summary(rows: list[dict], path: Path) -> Path:
    """Write ``summary.csv`` (``SUMMARY_COLUMNS``) atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(SUMMARY_COLUMNS)
        for row in rows:
            w.writerow([row[c] if isinstance(row[c], str) else (f"{row[c]:.6g}" if isinstance(row[c], float)
                                                                 else row[c]) for c in SUMMARY_COLUMNS])
    os.replace(tmp, path)
    return path


def penetration_cuts(cfg: DemoConfig, rows: list[dict]) -> dict:
    """Fraction by which each transient rendering cuts the mean penetration of its wall alone (section 4.5.5).

    Pairs every rendering with a transient with the plain wall of the same
    stiffness; means over all velocities x grips. Returns name -> 1 - pen/pen_wall.
    """
    def pen(name):
        vals = [x["penetration_mean_m"] for x in rows if x["rendering"] == name and math.isfinite(x["penetration_mean_m"])]
        return float(np.mean(vals)) if vals else math.nan

    walls = {r.stiffness_N_m: r.name for r in cfg.renderings if r.transient == "none" and not r.is_real}
    out = {}
    for r in cfg.renderings:
        if r.transient != "none" and r.stiffness_N_m in walls:
            p_tr, p_wall = pen(r.name), pen(walls[r.stiffness_N_m])
            if math.isfinite(p_tr) and p_wall > 0:
                out[r.name] = 1.0 - p_tr / p_wall
    return out


def format_table(cfg: DemoConfig, rows: list[dict], library) -> str:
    """The printed table: one line per rendering (means over velocities x grips; see the header)."""
    lib_lo, lib_hi = float(library.velocities_m_s[0]), float(library.velocities_m_s[-1])
    lines = [
        f"Renderings tapped by the simulated user at {', '.join(f'{v:g}' for v in cfg.velocities_m_s)} m/s x "
        f"grips {', '.join(f'{g:g}' for g in cfg.grips_N)} N ({cfg.taps} tap(s) each).",
        f"NRMSE and correlation: handle acceleration vs the real sample at the same velocity, 20-1000 Hz, "
        f"mean over velocities inside the library range ({lib_lo:.3f}-{lib_hi:.3f} m/s); other columns: "
        f"mean (dominant frequency: median) over all taps.",
        f"{'rendering':22s} {'peak a m/s2':>11} {'f_dom Hz':>8} {'pen mm':>7} {'NRMSE':>6} {'corr':>6} "
        f"{'clipped':>8}",
    ]
    for r in cfg.renderings:
        rr = [x for x in rows if x["rendering"] == r.name]
        inr = [x for x in rr if x["in_library_range"]]

        def m(key, sel=rr):
            vals = [x[key] for x in sel if math.isfinite(x[key])]
            return float(np.mean(vals)) if vals else math.nan

        f_dom = float(np.nanmedian([x["dominant_freq_hz"] for x in rr]))
        clipped = sum(x["clipped"] for x in rr)
        taps = sum(x["taps"] for x in rr)
        lines.append(f"{r.name:22s} {m('peak_accel_m_s2'):11.1f} {f_dom:8.0f} {m('penetration_mean_m') * 1e3:7.2f} "
                     f"{m('nrmse', inr):6.3f} {m('correlation', inr):6.3f} {clipped:>4d}/{taps:<3d}")
    cuts = penetration_cuts(cfg, rows)
    if cuts:
        lines.append("Mean penetration cut by the transient vs the same wall alone: "
                     + ", ".join(f"{name} {cut * 100:.0f} %" for name, cut in cuts.items())
                     + " (thesis 4.5.5: about a factor of two; docs/demo.md, 'The simulated tap')")
    out_of_range = [v for v in cfg.velocities_m_s if not lib_lo <= v <= lib_hi]
    hf = [x for x in rows if x["rendering"] == "hfam_firm"]
    if out_of_range and hf:
        parts = []
        for v in out_of_range:
            sel = [x for x in hf if x["velocity_m_s"] == v]
            parts.append(f"{v:g} m/s NRMSE {np.mean([x['nrmse'] for x in sel]):.2f}, corr "
                         f"{np.mean([x['correlation'] for x in sel]):.2f}, clipped {sum(x['clipped'] for x in sel)}"
                         f"/{sum(x['taps'] for x in sel)}")
        lines.append("HFAM over firm beyond the library range (extrapolated transient): " + "; ".join(parts))
    return "\n".join(lines)


def format_reactive(reactive: dict) -> str:
    """The printed line of :func:`reactive_hand_cuts` ("" if empty)."""
    if not reactive:
        return ""
    c = reactive["cuts"]
    return (f"With the reactive hand model (0.2 kg hand, 120 N/m muscle, 40 ms reflex; "
            f"{', '.join(f'{v:g}' for v in reactive['velocities_m_s'])} m/s): cut {c['pulse_firm'] * 100:.0f} % "
            f"(pulse), {c['hfam_firm'] * 100:.0f} % (HFAM) vs firm alone "
            f"(docs/demo.md, 'The reactive hand')")


def write_traces(result: DemoResult, path: Path) -> Path:
    """Save every contact window: ``accel`` and ``current`` [n_taps, n] plus per-tap keys (npz)."""
    keys = sorted(result.traces, key=lambda k: (k[0], k[1], k[2]))
    taps = [t for k in keys for t in result.traces[k]]
    np.savez_compressed(
        path,
        rendering=np.array([t.rendering for t in taps]),
        velocity_m_s=np.array([t.velocity_m_s for t in taps]),
        grip_N=np.array([t.grip_N for t in taps]),
        v_in_m_s=np.array([t.v_in_m_s for t in taps]),
        accel_m_s2=np.array([t.accel for t in taps]),
        current_A=np.array([t.current for t in taps]),
        transient_current_A=np.array([t.transient_current for t in taps]),
        reference_velocity_m_s=np.array(sorted(result.references)),
        reference_accel_m_s2=np.array([result.references[v] for v in sorted(result.references)]),
        fs_hz=result.fs_hz, pre_s=runs.PRE_S,
    )
    return Path(path)
