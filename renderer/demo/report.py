"""The demo's files: ``summary.csv`` and ``traces.npz``, and the check that an earlier demo's are not replaced; the
reactive-hand line."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_open

from . import runs
from .config import DemoResult

SUMMARY_COLUMNS = ("rendering", "velocity_m_s", "grip_N", "peak_accel_m_s2", "dominant_freq_hz",
                   "penetration_mean_m", "nrmse", "correlation", "clipped")


#: what the demo (sim or hardware) writes into --out (an earlier demo's, refused without --force)
DEMO_PRODUCTS = ("summary.csv", "fidelity.csv", "traces.npz", "fig_*.png", "fig_*.svg", "fig_*.plot.csv")


def write_summary(rows: list[dict], path: Path) -> Path:
    """Write ``summary.csv`` (``SUMMARY_COLUMNS``) atomically."""
    path = Path(path)
    with atomic_open(path, "w", newline="") as fh:   # whole or not at all, fsynced
        w = csv.writer(fh)
        w.writerow(SUMMARY_COLUMNS)
        for row in rows:
            w.writerow([row[c] if isinstance(row[c], str) else (f"{row[c]:.6g}" if isinstance(row[c], float)
                                                                 else row[c]) for c in SUMMARY_COLUMNS])
    return path


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
