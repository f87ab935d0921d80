"""Validating an identified model against the device: ETFE agreement at several current magnitudes and
time-domain prediction of held-handle responses to contact-like transients (thesis sec. 3.4.5, Figure 3.10;
sec. 3.5.4, Figure 3.25). Works with a nonlinear sim parameter set (successive isolation) and with a zpk
model (comprehensive evaluation)."""

from __future__ import annotations

import numpy as np

import figstyle

from ..base import Device
from ..model import ZpkModel
from .etfe import Etfe, etfe
from .record import hold_user, play, record_condition
from .sweep import SweepConfig
from .validate import nrmse, transient_current


def accel_etfe(dev: Device, amplitude_A: float, grip_N: float = 2.0, trials: int = 2, duration_s: float = 1.0,
               f_start_hz: float = 5.0, f_end_hz: float = 1000.0, label: str = "") -> Etfe:
    """ETFE of handle acceleration from ``trials`` swept sines (eq. 3.11-3.16) at ``amplitude_A``."""
    sweep = SweepConfig(amplitude_A=amplitude_A, f_start_hz=f_start_hz, f_end_hz=f_end_hz, duration_s=duration_s,
                        fs_hz=dev.info.servo_rate_hz, repetitions=2)
    recs = record_condition(dev, sweep, grip_N, trials)
    return etfe(recs, "accel_m_s2", label=label or f"{amplitude_A:g} A, grip {grip_N:g} N", detrend="periodic")


def compare_etfes(a: Etfe, b: Etfe, band_hz=(20.0, 500.0)) -> dict:
    """Magnitude (dB) and phase (deg, wrapped to +-180) differences of two ETFEs on the same bins over a band.

    Returns
    -------
    dict
        ``rms_db``, ``max_db``, ``rms_deg``, ``max_deg``, ``band_hz``.
    """
    if a.f_hz.shape != b.f_hz.shape or not np.allclose(a.f_hz, b.f_hz):
        raise ValueError("ETFEs to compare must share their frequency bins (same sweep)")
    sel = (a.f_hz >= band_hz[0]) & (a.f_hz <= band_hz[1])
    ddb = 20 * np.log10(np.abs(a.H[sel]) / np.abs(b.H[sel]))
    ddeg = np.degrees(np.angle(a.H[sel] / b.H[sel]))
    return {"rms_db": float(np.sqrt(np.mean(ddb ** 2))), "max_db": float(np.max(np.abs(ddb))),
            "rms_deg": float(np.sqrt(np.mean(ddeg ** 2))), "max_deg": float(np.max(np.abs(ddeg))),
            "band_hz": list(band_hz)}


def etfe_agreement(dev: Device, model_dev: Device, amplitudes_A=(0.2, 0.75, 1.25), grip_N: float = 2.0,
                   band_hz=(20.0, 500.0), trials: int = 2) -> list[dict]:
    """Compare device and model ETFEs (acceleration) at several current magnitudes.

    Returns
    -------
    list of dict
        Per amplitude: ``amplitude_A`` plus :func:`compare_etfes` fields, and the two curves (``curves``).
    """
    out = []
    for amp in amplitudes_A:
        e_dev = accel_etfe(dev, amp, grip_N, trials, label=f"device {amp:g} A")
        e_mod = accel_etfe(model_dev, amp, grip_N, trials, label=f"model {amp:g} A")
        out.append({"amplitude_A": amp, **compare_etfes(e_dev, e_mod, band_hz), "curves": (e_dev, e_mod)})
    return out


def record_held_transients(dev: Device, amplitude_A: float, grip_N: float, settle_s: float = 0.1):
    """Contact-like transients (:func:`devices.identify.validate.transient_current`) played while the user
    holds at ``grip_N``. Returns (current_A, accel_m_s2, position_m, windows)."""
    fs = dev.info.servo_rate_hz
    hold_user(dev, grip_N)
    u, windows = transient_current(fs, amplitude_A)
    n0 = int(round(settle_s * fs))
    _, a, x, _ = play(dev, np.concatenate([np.zeros(n0), u]))
    return u, a[n0:], x[n0:] - x[n0], windows


def predict_sim(model_dev: Device, current_A: np.ndarray, grip_N: float, settle_s: float = 0.1):
    """Acceleration and position a (noise-free) model sim device predicts for the same held transients."""
    fs = model_dev.info.servo_rate_hz
    hold_user(model_dev, grip_N)
    n0 = int(round(settle_s * fs))
    _, a, x, _ = play(model_dev, np.concatenate([np.zeros(n0), current_A]))
    return a[n0:], x[n0:] - x[n0]


def time_domain_validation(dev: Device, models: dict, grip_N: float = 2.0, amplitude_A: float = 1.0) -> dict:
    """NRMSE per transient of each model's predicted handle acceleration (sec. 3.4.5).

    Parameters
    ----------
    dev : Device
        The device (the simulated person holds at ``grip_N``).
    models : dict
        ``name -> Device`` (a model sim, e.g. ``SimDevice(result.params)``) or ``name -> ZpkModel``.

    Returns
    -------
    dict
        ``{"windows", "current_A", "measured", "fs_hz", "models": {name: {"nrmse", "nrmse_per_transient",
        "predicted"}}}``.
    """
    fs = dev.info.servo_rate_hz
    u, a, x, windows = record_held_transients(dev, amplitude_A, grip_N)
    out = {"windows": windows, "current_A": u, "measured": a, "fs_hz": fs, "grip_N": grip_N,
           "amplitude_A": amplitude_A, "models": {}}
    for name, m in models.items():
        if isinstance(m, ZpkModel):
            pred = m.simulate(u, fs)
        else:
            pred, _ = predict_sim(m, u, grip_N)
        out["models"][name] = {"nrmse": nrmse(a, pred), "predicted": pred,
                               "nrmse_per_transient": [nrmse(a[i:j], pred[i:j]) for i, j in windows]}
    return out


def time_domain_figure(result: dict, path, title: str = "", force: bool = False) -> str:
    """Figure 3.10 style: current and measured/predicted acceleration per transient, residuals below; in the
    project style (figstyle: PNG, SVG and the plotted numbers as ``.plot.csv``; ValueError if one of them exists,
    unless ``force``)."""

    wins = result["windows"]
    fs = result["fs_hz"]
    names = list(result["models"])
    rows = []
    with figstyle.style() as plt:
        width = "page" if len(wins) > 1 else "column"
        fig, axes = plt.subplots(3, len(wins), figsize=figstyle.figsize(width, height_in=5.4), squeeze=False,
                                 sharex="col", layout="constrained")
        for c, (i, j) in enumerate(wins):
            t = np.arange(j - i) / fs * 1e3
            axes[0, c].plot(t, result["current_A"][i:j], "k")
            axes[1, c].plot(t, result["measured"][i:j], "k", lw=1.5, label="measured")
            for name, m in result["models"].items():
                axes[1, c].plot(t, m["predicted"][i:j], lw=1, label=name)
                axes[2, c].plot(t, result["measured"][i:j] - m["predicted"][i:j], lw=1, label=name)
            axes[2, c].set_xlabel("time (ms)")
            nr = ", ".join(f"{m['nrmse_per_transient'][c]:.2f}" for m in result["models"].values())
            axes[0, c].set_title(f"transient {c + 1}: NRMSE {nr}", fontsize=7)
            rows += [(c + 1, tk, result["current_A"][i + k], result["measured"][i + k],
                      *(result["models"][n]["predicted"][i + k] for n in names)) for k, tk in enumerate(t)]
        axes[0, 0].set_ylabel("current (A)")
        axes[1, 0].set_ylabel("handle accel (m/s^2)")
        axes[2, 0].set_ylabel("residual (m/s^2)")
        fig.legend(handles=axes[1, -1].lines, loc="outside lower center", ncol=len(names) + 1, fontsize=6)
        fig.suptitle(title or f"time-domain validation, grip {result['grip_N']:g} N", fontsize=8)
        header = ["transient", "t_ms", "current_A", "measured_m_s2"] + [f"{n}_m_s2" for n in names]
        paths = figstyle.save(fig, path, (header, rows), force=force)
    return str(paths["png"])
