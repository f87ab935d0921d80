"""Time-domain validation of an identified model on recorded transients (thesis section 3.4.5)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..base import Device
from .record import hold_user, play
from .recording import read_csv_columns, write_csv_columns

if TYPE_CHECKING:  # annotations only: devices.model loads scipy.signal (~1 s), which recording does not need
    from ..model import ZpkModel

# (kind, frequency Hz, decay time constant s): contact-like transients (decaying sinusoids, a short pulse)
DEFAULT_TRANSIENTS = (("sinusoid", 80.0, 0.02), ("sinusoid", 150.0, 0.015), ("sinusoid", 300.0, 0.01),
                      ("pulse", 0.0, 0.002))
WINDOW_S = 0.15


def transient_current(fs_hz: float, amplitude_A: float, transients=DEFAULT_TRANSIENTS,
                      window_s: float = WINDOW_S) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """A current sequence of contact-like transients, each followed by rest.

    Returns
    -------
    current_A : ndarray, shape (n,)
    windows : list of (start, stop) sample indices, one per transient
    """
    n_win = int(round(window_s * fs_hz))
    t = np.arange(n_win) / fs_hz
    parts, windows = [], []
    for kind, f, tau in transients:
        if kind == "sinusoid":
            w = amplitude_A * np.exp(-t / tau) * np.sin(2 * np.pi * f * t)
        elif kind == "pulse":
            w = np.where(t < tau, amplitude_A, 0.0)
        else:
            raise ValueError(f"unknown transient kind {kind!r}")
        start = sum(p.size for p in parts)
        parts.append(w)
        windows.append((start, start + n_win))
    return np.concatenate(parts), windows


def nrmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Normalized RMS error ||y - y_hat|| / ||y - mean(y)|| (0 is perfect, 1 is as bad as the mean)."""
    y = np.asarray(measured, dtype=float)
    e = y - np.asarray(predicted, dtype=float)
    den = np.linalg.norm(y - y.mean())
    return float(np.linalg.norm(e) / den) if den > 0 else float("inf")


def validate_model(model: ZpkModel, current_A: np.ndarray, measured: np.ndarray, fs_hz: float,
                   windows: list[tuple[int, int]] | None = None) -> dict:
    """Simulate ``model`` on the commanded current and compare with the measured output.

    The measured output is taken relative to its value at the first sample
    (the model starts at rest).

    Returns
    -------
    dict
        ``nrmse`` over the whole record and ``nrmse_per_transient`` per window.
    """
    u = np.asarray(current_A, dtype=float)
    y = np.asarray(measured, dtype=float) - float(measured[0])
    y_hat = model.simulate(u, fs_hz)
    out = {"nrmse": nrmse(y, y_hat)}
    if windows:
        out["nrmse_per_transient"] = [nrmse(y[a:b], y_hat[a:b]) for a, b in windows]
    return out


def record_transients(dev: Device, amplitude_A: float, grip_N: float | None = None, settle_s: float = 0.1):
    """Play :func:`transient_current` on ``dev`` while the user holds the handle.

    Returns
    -------
    current_A, accel_m_s2, position_m : ndarray
    windows : list of (start, stop)
    """
    fs = dev.info.servo_rate_hz
    if amplitude_A > dev.info.current_peak_A:
        raise ValueError(f"transient amplitude {amplitude_A} A exceeds the peak limit {dev.info.current_peak_A} A")
    if grip_N is not None:
        hold_user(dev, grip_N)
    u, windows = transient_current(fs, amplitude_A)
    n0 = int(round(settle_s * fs))
    full = np.concatenate([np.zeros(n0), u])
    _, a, x, _ = play(dev, full)
    return u, a[n0:], x[n0:], windows


def write_transient_recording(path, fs_hz: float, current_A, accel_m_s2, position_m, grip_N=None):
    """Write a transient recording CSV (``t_s,current_A,accel_m_s2,position_m,grip_N``), atomically."""
    n = len(current_A)
    g = np.zeros(n) if grip_N is None else np.broadcast_to(np.asarray(grip_N, dtype=float), (n,))
    return write_csv_columns(path, ("t_s", "current_A", "accel_m_s2", "position_m", "grip_N"),
                             [np.arange(n) / fs_hz, current_A, accel_m_s2, position_m, g])


def read_transient_recording(path, output: str = "accel_m_s2") -> tuple[float, np.ndarray, np.ndarray]:
    """Read commanded current and one measured output from a CSV with ``t_s, current_A, <output>``.

    The sample rate comes from the (uniform) ``t_s`` steps.

    Returns
    -------
    fs_hz, current_A, measured : float, ndarray, ndarray

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file/column, NaN (naming line and column), non-uniform time steps.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"transient recording not found: {path}")
    cols = read_csv_columns(path, ("t_s", "current_A", output))
    t = cols["t_s"]
    if t.size < 16:
        raise ValueError(f"{path}: too few samples ({t.size})")
    dt = np.diff(t)
    step = float(np.median(dt))
    bad = np.flatnonzero(np.abs(dt - step) > 0.5 * step) if step > 0 else np.arange(1)
    if step <= 0 or bad.size:
        i = int(bad[0]) if bad.size else 0
        raise ValueError(f"{path}: t_s is not uniformly sampled (between lines {i + 2} and {i + 3})")
    return 1.0 / step, cols["current_A"], cols[output]
