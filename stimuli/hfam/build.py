"""HFAM transient library generation (thesis section 4.4.1, Figure 4.7).

Pipeline, per selected recorded tap and per device model (one per grip level):

1. **Selection**: drop taps with high pre-impact acceleration and atypical
   taps (low correlation with their velocity neighbours), then pick a nicely
   spaced subset over incoming velocity.
2. **Zero pre-padding** (and post-padding) so filters and the non-causal
   inverse have room.
3. **Zero-phase smoothing**: Butterworth low-pass run forwards and backwards
   (``scipy.signal.sosfiltfilt``), bandwidth <= 1 kHz.
4. **Model inversion** (eq. 4.6, section 4.2.2): the pure delay is discarded;
   a strictly proper model is made proper (relative degree zero) by added
   high-frequency zeros (pairs at ``added_zero_hz`` with damping
   ``added_zero_zeta``, normalised to unit DC gain), which act as a low-pass
   filter in the inverse (applied zero-phase, offline); the model's Tustin
   response (the discrete model the verification runs) is divided out on a
   long zero-padded DFT grid: the stable two-sided inverse (causal part for
   minimum-phase zeros, anti-causal part for right-half-plane zeros), so
   right-half-plane zeros never give an unbounded output.
5. **High-pass** second order (Butterworth) near 10 Hz, causal or zero-phase
   (``highpass_phase``; default ``best``: both, see 6).
6. Padding removed (the current starts at the first servo sample after
   impact and realises the target delayed by ``onset_delay_s``), tail
   tapered to zero (half cosine), optional gain; then ``window_iterations``
   corrective passes through the model (:func:`_current`), so the windowed
   current makes the recording high-passed *without* phase turn; with
   ``best`` the start (causal or zero-phase high-pass) whose result is closer
   through the model is kept.
7. **Verification**: every current transient is run through its forward model
   (Tustin, no delay) and compared with the desired acceleration (smoothed,
   high-passed without phase turn, delayed) over 20-1000 Hz (normalised RMS
   error and correlation); a transient above the device's peak current stops
   the build unless ``scale_to_limit``.

Details and the reasons for each choice: docs/hfam_library.md.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import hashlib
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy import signal

from plumbing import provenance

from ..library import HfamLibrary
from ..recordings import Tap
from .inversion import band_sos, check_model, forward_simulate, highpass_target, invert, nrmse_corr, sosfiltfilt
from .selection import Selection, select_taps
from .settings import BuildSettings


@dataclass
class BuildReport:
    """What the builder did, for printing and for the library metadata."""

    selection: Selection
    verification: list[dict]
    scaled: list[str]
    model_notes: list[str]
    elapsed_s: float = 0.0


# ---------------------------------------------------------------------------- builder
def build_library(
    taps: Sequence[Tap],
    fs_hz: float,
    models: Sequence[tuple[str, object]],
    settings: BuildSettings = BuildSettings(),
    *,
    force_per_amp_N_A: float,
    log: Callable[[str], None] | None = None,
    provenance: dict | None = None,
) -> tuple[HfamLibrary, BuildReport]:
    """Build an HFAM current library from recorded taps and per-grip device models (section 4.4.1).

    Parameters
    ----------
    taps : sequence of Tap
        Recorded impacts (see ``stimuli.recordings``), all sampled at ``fs_hz``.
    fs_hz : float
        Sample rate of the recordings = servo rate the library is for.
    models : sequence of (name, model)
        Current -> handle acceleration models (``devices.model.ZpkModel``), one
        per grip level (``model.grip_N``); ``name`` (usually the file) is used
        in messages.
    settings : BuildSettings
    force_per_amp_N_A : float
        Force constant of the device (stored with the library).
    log : callable(str) or None
        Progress output.
    provenance : dict or None
        Extra metadata (source files, command line) stored in the library.

    Returns
    -------
    library : HfamLibrary
        currents [n_v, n_g, n_t] in A, with desired accelerations and metadata.
    report : BuildReport

    Raises
    ------
    ValueError
        Bad models (named), no usable taps, sample rate problems, or a
        transient above ``settings.peak_current_A`` (naming velocity and
        grip) when ``scale_to_limit`` is False.
    """
    return build_library_limits(taps, fs_hz, models, settings, [settings.peak_current_A],
                                force_per_amp_N_A=force_per_amp_N_A, log=log, provenance=provenance)[0]


def build_library_limits(
    taps: Sequence[Tap],
    fs_hz: float,
    models: Sequence[tuple[str, object]],
    settings: BuildSettings,
    peak_currents_A: Sequence[float | None],
    *,
    force_per_amp_N_A: float,
    log: Callable[[str], None] | None = None,
    provenance: dict | None = None,
) -> list[tuple[HfamLibrary, BuildReport]]:
    """:func:`build_library` for each of several peak current limits (``settings.peak_current_A`` replaced by each).

    A transient's current before it is scaled to the limit does not depend on the limit: each cell is inverted
    once and scaled for each library (a scoring run builds the open-loop library at the device's peak current and
    again at a raised transient limit). Each library and report is the one :func:`build_library` returns with
    ``dataclasses.replace(settings, peak_current_A=limit)``, to the bit.

    Returns
    -------
    list of (HfamLibrary, BuildReport)
        One per limit, in order.
    """
    t_start = time.perf_counter()
    say = log or (lambda msg: None)
    fs_hz = float(fs_hz)
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"sample rate must be positive, got {fs_hz!r}")
    if settings.smooth_hz >= fs_hz / 2:
        raise ValueError(f"smooth_hz={settings.smooth_hz} must be below the Nyquist frequency {fs_hz / 2} Hz")
    if settings.added_zero_hz >= fs_hz / 2:
        raise ValueError(f"added_zero_hz={settings.added_zero_hz} must be below the Nyquist frequency {fs_hz / 2} Hz")
    if not models:
        raise ValueError("at least one device model is needed")
    for name, model in models:
        check_model(model, name, fs_hz)
    grips = _grip_levels(models)
    order = np.argsort(grips)
    models = [models[i] for i in order]
    grips = [grips[i] for i in order]

    selection = select_taps(taps, fs_hz, settings)
    for tp, why in selection.dropped:
        say(f"  dropped tap {tp.tap} ({tp.v_in_m_s:.4g} m/s): {why}")
    velocities = [tp.v_in_m_s for tp in selection.selected]
    say(f"selected {len(velocities)} taps: " + ", ".join(f"{tp.tap} ({tp.v_in_m_s:.4g} m/s)" for tp in selection.selected))

    n_t = int(round(settings.duration_s * fs_hz))
    available = min(int(np.count_nonzero(tp.t_s > 0)) for tp in selection.selected)
    if available < n_t:
        say(f"  note: recordings hold only {available} samples after impact; transients are {available / fs_hz * 1e3:.1f} ms")
        n_t = available
    pre = int(round(settings.pre_pad_s * fs_hz))
    post = int(round(settings.post_pad_s * fs_hz))
    n_pad = pre + n_t + 1 + post
    t_grid = (np.arange(n_pad) - pre) / fs_hz  # index pre is t = 0
    window = slice(pre + 1, pre + 1 + n_t)  # samples at t = (k+1)/fs, k = 0..n_t-1
    lead = int(round(settings.onset_delay_s * fs_hz))
    # the current for physical sample t = (k+1)/fs is the inverse at t - onset delay
    source = slice(pre + 1 - lead, pre + 1 - lead + n_t)
    smooth = signal.butter(settings.smooth_order, settings.smooth_hz, fs=fs_hz, output="sos")
    verify = band_sos(fs_hz, settings.verify_band_hz)
    taper = np.ones(n_t)
    n_taper = int(round(settings.taper_s * fs_hz))
    if n_taper > 0:
        taper[n_t - n_taper:] = 0.5 * (1.0 + np.cos(np.pi * np.arange(1, n_taper + 1) / n_taper))

    model_notes = []
    for name, model in models:
        r = len(model.poles_rad_s) - len(model.zeros_rad_s)
        n_rhp = int(np.count_nonzero(np.asarray(model.zeros_rad_s).real > 0))
        parts = []
        if r:
            parts.append(f"added {r} zero(s) at {settings.added_zero_hz:g} Hz, zeta {settings.added_zero_zeta:g}")
        if float(getattr(model, "delay_s", 0.0)):
            parts.append(f"discarded delay {model.delay_s * 1e3:.3g} ms")
        if n_rhp:
            parts.append(f"{n_rhp} right-half-plane zero(s): non-causal stable inversion")
        note = f"model {name} (grip {model.grip_N} N): " + ("; ".join(parts) or "proper, minimum phase, no delay")
        model_notes.append(note)
        say("  " + note)

    limits = list(peak_currents_A)
    each = [settings if lim == settings.peak_current_A else dataclasses.replace(settings, peak_current_A=lim)
            for lim in limits]
    currents = [np.zeros((len(velocities), len(models), n_t)) for _ in limits]
    desired = np.zeros((len(velocities), n_t))
    verification = [[] for _ in limits]
    scaled = [[] for _ in limits]
    for i, tp in enumerate(selection.selected):
        target = np.interp(t_grid, tp.t_s, tp.accel_m_s2, left=0.0, right=0.0)
        target_s = sosfiltfilt(smooth, target) * settings.gain
        desired[i] = target_s[source]
        # the desired acceleration: the recording without what the high-pass removes, with no phase turn
        target_hp = highpass_target(target_s, fs_hz, settings.highpass_hz, zero_phase=True)
        d_band = sosfiltfilt(verify, target_hp)[source]
        for j, (name, model) in enumerate(models):
            cur0, phase, y_band0 = _current(target_s, target_hp, d_band, model, fs_hz, settings, source, window,
                                            taper, verify)
            peak = float(np.max(np.abs(cur0)))
            for k, limit in enumerate(limits):
                cur, factor, y_band = cur0, 1.0, y_band0
                if limit is not None and peak > limit:
                    where = f"velocity {tp.v_in_m_s:.4g} m/s, grip {grips[j]:g} N (model {name})"
                    if not settings.scale_to_limit:
                        raise ValueError(f"transient at {where} needs {peak:.3f} A, above the device peak limit "
                                         f"{limit:g} A; lower --gain, or use --scale-to-limit")
                    factor = limit / peak
                    cur, y_band = cur0 * factor, None
                    msg = f"scaled transient at {where} by {factor:.3f} (peak {peak:.3f} A -> {limit:g} A)"
                    scaled[k].append(msg)
                    say("  " + msg)
                currents[k][i, j] = cur
                if y_band is None:            # not the current _current ran through the model: run this one
                    u = np.zeros(n_pad)
                    u[window] = cur
                    y = forward_simulate(model, u, fs_hz)
                    y_band = sosfiltfilt(verify, y)[window]
                err, cc = nrmse_corr(y_band, d_band)
                verification[k].append({"v_in_m_s": tp.v_in_m_s, "grip_N": grips[j], "tap": tp.tap,
                                        "peak_A": float(np.max(np.abs(cur))), "nrmse": err, "corr": cc,
                                        "scale": factor, "highpass": phase})
        say(f"  built velocity {i + 1}/{len(velocities)}: {tp.v_in_m_s:.4g} m/s x {len(models)} grip level(s)")

    elapsed = time.perf_counter() - t_start
    out = []
    for k, st in enumerate(each):
        report = BuildReport(selection, verification[k], scaled[k], model_notes, elapsed)
        metadata = {
            "software_version": _software_version(),
            "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "settings": _settings_dict(st),
            "models": [_model_dict(name, model) for name, model in models],
            "selection": {
                "selected": [{"tap": tp.tap, "v_in_m_s": tp.v_in_m_s} for tp in selection.selected],
                "dropped": [{"tap": tp.tap, "v_in_m_s": tp.v_in_m_s, "reason": why} for tp, why in selection.dropped],
            },
            "model_notes": list(model_notes),
            "scaled": scaled[k],
            "verification": verification[k],
        }
        metadata.update(copy.deepcopy(provenance or {}))
        library = HfamLibrary(velocities, grips, currents[k], fs_hz, force_per_amp_N_A,
                              max_extrapolation=st.max_extrapolation, metadata=metadata,
                              desired_accel_m_s2=desired.copy(), source="built library")
        out.append((library, report))
    return out


def _current(target_s, target_hp, d_band, model, fs_hz: float, settings: BuildSettings, source: slice,
             window: slice, taper: np.ndarray, verify) -> tuple[np.ndarray, str, np.ndarray | None]:
    """One cell's current (A, samples t = (k+1)/fs after impact), the high-pass phase it started from and, with
    ``best``, its response through ``model`` over ``window`` band-passed by ``verify`` (what the verification
    computes for an unscaled current; None otherwise).

    The inverse (eq. 4.6) with the second-order high-pass near 10 Hz of
    section 4.4.1, ``causal`` (Tustin Butterworth) or ``zero`` (its magnitude
    only; ``settings.highpass_phase``, ``best``: both, below), is cut to the
    window an event-triggered transient can play: from the first sample after
    impact, tapered at the end. Neither cut current makes the desired
    acceleration (``target_hp``: the recording high-passed without phase
    turn): the causal high-pass turns the phase of a tap's 20-60 Hz content by
    43-13 deg (NRMSE ~0.26 over 20-1000 Hz on the sim's wood-on-foam taps),
    the zero-phase inverse is non-causal at low frequency and loses what
    precedes impact. ``settings.window_iterations`` passes then run the
    windowed current through ``model`` and add the windowed causal inverse of
    the error band-limited to ``verify`` (20-1000 Hz, zero phase): the error
    within the band shrinks by |1 - HP(f)| per pass (0.69 at 20 Hz, 0.28 at
    50 Hz), while the error below it is not fed back (there |1 - HP| reaches
    1.22 at the cut-off, and the current would drift). With ``best`` both
    starts are iterated and the one whose response through ``model`` is
    closer to ``d_band`` (``target_hp`` over the band) is kept: the
    zero-phase start keeps more of the tap's early impulse, the causal one is
    better on models with slow zeros besides the two at s = 0.
    """
    out = {}
    mask = np.zeros(target_s.size)
    mask[source] = taper
    for phase in (("causal", "zero") if settings.highpass_phase == "best" else (settings.highpass_phase,)):
        u = invert(target_s, model, fs_hz, settings, zero_phase_highpass=phase == "zero")[0] * mask
        for _ in range(settings.window_iterations):
            err = sosfiltfilt(verify, target_hp - forward_simulate(model, u, fs_hz))
            u = u + invert(err, model, fs_hz, settings, zero_phase_highpass=False)[0] * mask
        out[phase] = u[source]
    if len(out) == 1:
        (phase, cur), = out.items()
        return cur, phase, None
    err, bands = {}, {}
    for phase, cur in out.items():
        u = np.zeros(target_s.size)
        u[window] = cur
        bands[phase] = sosfiltfilt(verify, forward_simulate(model, u, fs_hz))[window]
        err[phase] = nrmse_corr(bands[phase], d_band)[0]
    phase = min(err, key=err.get)
    return out[phase], phase, bands[phase]


def format_verification(report: BuildReport, band_hz=(20.0, 1000.0)) -> str:
    """The verification table: one row per (velocity, grip) with peak current, NRMSE and correlation."""
    lines = [f"verification through the forward models, {band_hz[0]:g}-{band_hz[1]:g} Hz:",
             f"{'v_in m/s':>9} {'grip N':>7} {'tap':>5} {'peak A':>8} {'NRMSE':>7} {'corr':>6}  note"]
    for row in report.verification:
        note = f"scaled x{row['scale']:.3f}" if row["scale"] != 1.0 else ""
        lines.append(f"{row['v_in_m_s']:>9.4g} {row['grip_N']:>7.3g} {row['tap']:>5} {row['peak_A']:>8.3f} "
                     f"{row['nrmse']:>7.3f} {row['corr']:>6.3f}  {note}")
    worst = max(report.verification, key=lambda r: r["nrmse"])
    lines.append(f"worst NRMSE {worst['nrmse']:.3f} at {worst['v_in_m_s']:.4g} m/s, grip {worst['grip_N']:g} N; "
                 f"built in {report.elapsed_s * 1e3:.0f} ms")
    return "\n".join(lines)


def _grip_levels(models) -> list[float]:
    grips = [getattr(m, "grip_N", None) for _, m in models]
    if len(models) == 1:
        return [float(grips[0]) if grips[0] is not None else 0.0]
    for (name, _), g in zip(models, grips):
        if g is None:
            raise ValueError(f"{name}: model has no grip_N; with several models each must name its grip level")
    if len(set(grips)) != len(grips):
        raise ValueError(f"models have repeated grip levels {grips}; one model per grip level")
    return [float(g) for g in grips]


def _settings_dict(settings: BuildSettings) -> dict:
    d = asdict(settings)
    d["verify_band_hz"] = list(settings.verify_band_hz)
    d["taps"] = list(settings.taps) if settings.taps is not None else None
    return d


def _model_dict(name: str, model) -> dict:
    if hasattr(model, "to_dict"):
        d = model.to_dict()
    else:
        d = {"zeros_rad_s": [[float(v.real), float(v.imag)] for v in np.asarray(model.zeros_rad_s, complex)],
             "poles_rad_s": [[float(v.real), float(v.imag)] for v in np.asarray(model.poles_rad_s, complex)],
             "gain": float(model.gain), "delay_s": float(getattr(model, "delay_s", 0.0)),
             "grip_N": getattr(model, "grip_N", None)}
    d["name"] = str(name)
    return d


def _software_version() -> str:
    return provenance.version_line()


def file_digest(path) -> str:
    """sha256 of a file, for provenance."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 16), b""):
            h.update(chunk)
    return h.hexdigest()


def source_entry(path) -> dict:
    """``{"path", "sha256"}`` of an input file, for the library's provenance."""
    p = Path(path)
    return {"path": str(p), "sha256": file_digest(p)}
