"""Reading recorded real taps (the CSV written by ``python -m devices record``).

Long format, one row per sample: ``tap, incoming_velocity_m_s, t_s, accel_m_s2``;
``t_s`` is relative to impact (first sample of a tap <= 0), uniformly sampled.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

COLUMNS = ("tap", "incoming_velocity_m_s", "t_s", "accel_m_s2")
FS_RTOL = 0.01  # sample spacing may wobble by 1 % (timestamp rounding) before we call it non-uniform


@dataclass(frozen=True)
class Tap:
    """One recorded impact.

    Attributes
    ----------
    tap : int
        Tap id from the file.
    v_in_m_s : float
        Incoming velocity magnitude in m/s.
    t_s : ndarray, shape (n,)
        Time relative to impact in s (strictly increasing, first <= 0).
    accel_m_s2 : ndarray, shape (n,)
        Handle/stylus acceleration in m/s^2.
    """

    tap: int
    v_in_m_s: float
    t_s: np.ndarray
    accel_m_s2: np.ndarray


def read_tap_csv(path) -> tuple[float, list[Tap]]:
    """Read and validate a tap recording CSV.

    Returns
    -------
    fs_hz : float
        Sample rate common to all taps.
    taps : list of Tap
        In file order.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file (and tap, column and line) for: missing columns, NaN or
        non-numeric values, non-monotonic time, a tap whose velocity changes, a
        tap without a pre-impact sample, non-uniform or inconsistent sampling,
        fewer than two distinct incoming velocities.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recording file not found: {path}")
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable CSV ({exc})") from None
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (need {', '.join(COLUMNS)})")
    for col in COLUMNS:
        values = pd.to_numeric(df[col], errors="coerce")
        bad = np.flatnonzero(~np.isfinite(values.to_numpy(dtype=float)))
        if bad.size:
            line = int(bad[0]) + 2  # header is line 1
            raise ValueError(f"{path}: line {line}, column {col}: NaN or non-numeric value {df[col].iloc[bad[0]]!r}")
        df[col] = values
    if len(df) == 0:
        raise ValueError(f"{path}: no data rows")
    taps: list[Tap] = []
    fs_values = []
    for tap_id, group in df.groupby("tap", sort=False):
        lines = group.index.to_numpy() + 2
        t = group["t_s"].to_numpy(dtype=float)
        a = group["accel_m_s2"].to_numpy(dtype=float)
        v = group["incoming_velocity_m_s"].to_numpy(dtype=float)
        where = f"{path}: tap {tap_id}"
        if t.size < 4:
            raise ValueError(f"{where}: only {t.size} samples")
        dt = np.diff(t)
        if np.any(dt <= 0):
            i = int(np.flatnonzero(dt <= 0)[0])
            raise ValueError(f"{where}: time is not strictly increasing at line {lines[i + 1]} (t_s {t[i]} then {t[i + 1]})")
        if np.any(v != v[0]):
            i = int(np.flatnonzero(v != v[0])[0])
            raise ValueError(f"{where}: incoming_velocity_m_s changes within the tap at line {lines[i]}")
        if t[0] > 0:
            raise ValueError(f"{where}: first sample at t_s={t[0]} > 0; the recording must start at or before impact")
        step = float(np.median(dt))
        if np.max(np.abs(dt - step)) > FS_RTOL * step:
            i = int(np.argmax(np.abs(dt - step)))
            raise ValueError(f"{where}: non-uniform sampling at line {lines[i + 1]} (step {dt[i]} s, median {step} s)")
        fs_values.append((1.0 / step, tap_id))
        taps.append(Tap(int(tap_id), abs(float(v[0])), t, a))
    fs = float(np.median([f for f, _ in fs_values]))
    for f, tap_id in fs_values:
        if abs(f - fs) > FS_RTOL * fs:
            raise ValueError(f"{path}: tap {tap_id} is sampled at {f:.1f} Hz, others at {fs:.1f} Hz")
    if len({tp.v_in_m_s for tp in taps}) < 2:
        raise ValueError(
            f"{path}: all taps have the same incoming velocity ({taps[0].v_in_m_s} m/s); a library needs a range of velocities"
        )
    return fs, taps


def read_recording(path) -> tuple[float, list[Tap]]:
    """Read a tap recording for the library builder (see :func:`read_tap_csv`).

    We keep our own reader rather than ``devices.recording.read_tap_recording``
    because the builder reports dropped taps by their id from the file.
    """
    return read_tap_csv(path)
