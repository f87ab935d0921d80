"""Recordings of real taps: reference handle accelerations for HFAM (thesis sections 4.4, 4.5.2).

File format (long-format CSV, one row per sample, UTF-8, ``,`` separated)::

    tap,incoming_velocity_m_s,t_s,accel_m_s2
    0,0.0501,-0.0005,0.015
    0,0.0501,-0.0004,0.0
    ...

* ``tap``: tap index 0, 1, ... (rows of one tap are contiguous, in time order);
* ``incoming_velocity_m_s``: incoming speed of that tap (positive, same on every row of the tap);
* ``t_s``: time relative to impact, uniform steps of 1/fs (the servo rate), first sample <= 0;
* ``accel_m_s2``: measured handle acceleration (positive up).

Every tap has the same sampling rate. :func:`read_taps` (tap ids kept) and
:func:`read_tap_recording` (plain tuples) validate all of this and name the
file and line of the first problem; this is the one reader of the format
(``stimuli.recordings`` builds on it).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_write_text, read_text_utf8

from .sim import TapTrajectory

COLUMNS = ("tap", "incoming_velocity_m_s", "t_s", "accel_m_s2")
# t_s steps may wobble by 1 % (timestamp rounding, e.g. 7 decimals at 10 kHz) before they count as
# non-uniform or as a different sampling rate
STEP_RTOL = 0.01


def write_tap_recording(path, taps, fs_hz: float) -> Path:
    """Write taps to ``path`` atomically (temporary file, then rename: no partial files).

    Parameters
    ----------
    path : str or Path
    taps : sequence of (incoming_velocity_m_s, t_s, accel_m_s2)
        ``t_s`` and ``accel_m_s2`` arrays of equal length n >= 2.
    fs_hz : float
        Sampling rate; ``t_s`` must step by 1/fs_hz.
    """
    path = Path(path)
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"write_tap_recording: fs_hz must be > 0, got {fs_hz!r}")
    lines = [",".join(COLUMNS)]
    for i, (v, t, a) in enumerate(taps):
        t = np.asarray(t, dtype=float)
        a = np.asarray(a, dtype=float)
        if t.shape != a.shape or t.ndim != 1 or t.size < 2:
            raise ValueError(f"write_tap_recording: tap {i}: t_s and accel_m_s2 must be 1-D of equal length >= 2")
        if not (math.isfinite(v) and v > 0) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(a)):
            raise ValueError(f"write_tap_recording: tap {i}: values must be finite and velocity > 0")
        vs = f"{v:.6g}"
        lines.extend(f"{i},{vs},{tk:.7f},{ak:.6g}" for tk, ak in zip(t.tolist(), a.tolist()))
    return atomic_write_text(path, "\n".join(lines) + "\n")


@dataclass(frozen=True)
class Tap:
    """One recorded impact, as read from a tap recording.

    Attributes
    ----------
    tap : int
        Tap id from the file's ``tap`` column.
    v_in_m_s : float
        Incoming speed in m/s (> 0).
    t_s : ndarray, shape (n,)
        Time relative to impact in s (uniform steps of 1/fs, first <= 0).
    accel_m_s2 : ndarray, shape (n,)
        Handle acceleration in m/s^2 (up positive).
    """

    tap: int
    v_in_m_s: float
    t_s: np.ndarray
    accel_m_s2: np.ndarray


def _parse_rows(path: Path) -> list[tuple[int, float, list[float], list[float], list[int]]]:
    """Rows of a tap recording grouped per tap: (tap, v, t_s values, accel values, line numbers)."""
    text = read_text_utf8(path, "tap recording")
    with io.StringIO(text, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise ValueError(f"{path}: empty file (expected header {','.join(COLUMNS)})") from None
        header = [h.strip() for h in header]
        if tuple(header) != COLUMNS:
            missing = [c for c in COLUMNS if c not in header]
            hint = f" (missing column(s) {', '.join(missing)})" if missing else ""
            raise ValueError(f"{path}: line 1: header must be {','.join(COLUMNS)}, got {','.join(header)}{hint}")
        groups: list = []
        seen: set[int] = set()
        current = None
        for row in reader:
            line = reader.line_num
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(COLUMNS):
                raise ValueError(f"{path}: line {line}: expected {len(COLUMNS)} values, got {len(row)}")
            values = []
            for col, cell in zip(COLUMNS, row):
                try:
                    values.append(int(cell) if col == "tap" else float(cell))
                except ValueError:
                    raise ValueError(f"{path}: line {line}: non-numeric value in column {col}: {cell!r}") from None
                if not math.isfinite(values[-1]):
                    raise ValueError(f"{path}: line {line}: non-finite value in column {col}: {cell!r}")
            tap, v, t, a = values
            if tap != current:
                if tap in seen:
                    raise ValueError(f"{path}: line {line}: rows of tap {tap} are not contiguous")
                seen.add(tap)
                current = tap
                if not v > 0:
                    raise ValueError(f"{path}: line {line}: incoming_velocity_m_s must be > 0, got {v}")
                groups.append((tap, v, [], [], []))
            if v != groups[-1][1]:
                raise ValueError(f"{path}: line {line}: incoming_velocity_m_s changes within tap {tap}")
            groups[-1][2].append(t)
            groups[-1][3].append(a)
            groups[-1][4].append(line)
    if not groups:
        raise ValueError(f"{path}: no data rows")
    return groups


def read_taps(path) -> tuple[float, list[Tap]]:
    """Read and validate a tap recording, keeping each tap's id from the file.

    Returns
    -------
    fs_hz : float
        Sampling rate (from the t_s steps, common to all taps).
    taps : list of Tap
        One per tap in file order; arrays of shape (n,).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Naming the file and line (and tap or column) of a bad header (missing
        column), non-numeric or non-finite value, non-contiguous tap, changing or
        non-positive velocity, time not strictly increasing, non-uniform or
        inconsistent sampling, or a tap whose first sample is after the impact.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"tap recording not found: {path}")
    fs_hz = None
    taps = []
    for tap, v, ts, acc, lines in _parse_rows(path):
        where = f"{path}: tap {tap}"
        t = np.array(ts)
        if t.size < 2:
            raise ValueError(f"{where} (line {lines[0]}): needs at least 2 samples")
        dt = np.diff(t)
        if np.any(dt <= 0):
            i = int(np.flatnonzero(dt <= 0)[0])
            raise ValueError(f"{where}: time is not strictly increasing at line {lines[i + 1]} "
                             f"(t_s {t[i]} then {t[i + 1]})")
        step = float(np.median(dt))
        if np.any(np.abs(dt - step) > STEP_RTOL * step):
            i = int(np.argmax(np.abs(dt - step)))
            raise ValueError(f"{where} (line {lines[i + 1]}): t_s must increase in uniform steps "
                             f"(step {dt[i]:.6g} s, median {step:.6g} s)")
        fs = 1.0 / step
        if fs_hz is None:
            fs_hz = fs
        elif abs(fs - fs_hz) > STEP_RTOL * fs_hz:
            raise ValueError(f"{where} (line {lines[0]}): sampling rate {fs:.6g} Hz differs from "
                             f"the first tap's {fs_hz:.6g} Hz")
        if t[0] > 1e-12:
            raise ValueError(f"{where} (line {lines[0]}): first t_s must be <= 0 (impact at t=0), got {t[0]}")
        taps.append(Tap(tap, v, t, np.array(acc)))
    # a rate written with 7 decimals of t_s: snap to the nearest plausible rate
    return float(round(fs_hz, 3)), taps


def read_tap_recording(path) -> tuple[float, list[tuple[float, np.ndarray, np.ndarray]]]:
    """Read and validate a tap recording (see :func:`read_taps` for the checks).

    Returns
    -------
    fs_hz : float
        Sampling rate (from the t_s step, common to all taps).
    taps : list of (incoming_velocity_m_s, t_s, accel_m_s2)
        One entry per tap in file order; arrays of shape (n,).
    """
    fs_hz, taps = read_taps(path)
    return fs_hz, [(tp.v_in_m_s, tp.t_s, tp.accel_m_s2) for tp in taps]


def incoming_velocity_m_s(position_m: np.ndarray, fs_hz: float) -> float:
    """Incoming speed (m/s, > 0 when moving down) from encoder positions just before impact.

    Least-squares slope of the (quantized) positions over the window, which
    averages the encoder quantization.

    Parameters
    ----------
    position_m : ndarray (n,), n >= 2
        Measured positions at the servo rate, ending at the last tick before impact.
    """
    x = np.asarray(position_m, dtype=float)
    t = np.arange(x.size) / fs_hz
    slope = np.polyfit(t, x, 1)[0]
    return float(-slope)


def record_taps(device, velocities_m_s, grip_N: float = 2.0, window_s: float = 0.1, pre_s: float = 0.005,
                velocity_window_s: float = 0.005, approach_height_m: float = 0.01, detect: str = "auto",
                max_wait_s: float = 30.0, trajectory_options: dict | None = None):
    """Tap a surface once per velocity with the motor unpowered and capture the handle acceleration.

    Parameters
    ----------
    device : Device
        An open device. A simulated device (has ``set_user``) gets a
        :class:`~devices.sim.TapTrajectory` per velocity; on other devices the
        user taps by hand and ``velocities_m_s`` only sets the number of taps.
    velocities_m_s : sequence of float
        Tap speeds (m/s, > 0).
    grip_N : float
        Simulated user's grip (sim only).
    window_s, pre_s : float
        Length of each capture and how much of it precedes the impact (s).
    velocity_window_s : float
        Encoder window before impact for the incoming velocity (s).
    detect : str
        ``"contact"``: impact = first servo tick in contact with the sample
        (true state, sim only); ``"position"``: first tick with the measured
        position at or below the surface (height 0) coming from above;
        ``"auto"``: contact on sim devices, position otherwise.
    trajectory_options : dict or None
        Sim only: extra keyword arguments of the simulated hand's
        :class:`~devices.sim.TapTrajectory` (e.g. ``press_depth_m``, ``brake``:
        how the hand stops below the surface).

    Returns
    -------
    list of (incoming_velocity_m_s, t_s, accel_m_s2)
        Ready for :func:`write_tap_recording`; t_s = (tick - impact tick)/fs.

    Raises
    ------
    ValueError
        For bad arguments or a tap with no impact (e.g. the placeholder sample).
    """
    vels = [float(v) for v in velocities_m_s]
    if not vels or any(not (math.isfinite(v) and v > 0) for v in vels):
        raise ValueError(f"record: velocities must be positive m/s, got {velocities_m_s!r}")
    fs = device.info.servo_rate_hz
    n_pre = max(1, int(round(pre_s * fs)))
    n_win = int(round(window_s * fs))
    n_vel = max(2, int(round(velocity_window_s * fs)))
    if n_win <= n_pre:
        raise ValueError(f"record: window_s ({window_s}) must exceed pre_s ({pre_s})")
    is_sim = hasattr(device, "set_user")
    if detect == "auto":
        detect = "contact" if is_sim else "position"
    if detect not in ("contact", "position") or (detect == "contact" and not is_sim):
        raise ValueError(f"record: detect must be 'contact' (sim only), 'position' or 'auto', got {detect!r}")
    was_enabled = getattr(device, "motor_enabled", None)
    if is_sim:
        device.motor_enabled = False
    taps = []
    try:
        for i, v in enumerate(vels):
            if is_sim:

                traj = TapTrajectory(v, 1, approach_height_m=approach_height_m, **(trajectory_options or {}))
                device.set_user(traj, grip_N=grip_N)
                n_max = int(math.ceil(traj.duration_s * fs))
            else:
                n_max = int(math.ceil(max_wait_s * fs))
            pos = np.empty(n_max + n_win)
            acc = np.empty(n_max + n_win)
            k_imp = -1
            armed = False
            state = device.read()
            for k in range(n_max + n_win):
                device.command(0.0)
                state = device.read()
                pos[k] = state.position_m
                acc[k] = state.accel_m_s2
                if k_imp < 0:
                    if detect == "contact":
                        if device.in_contact:
                            k_imp = k
                    else:
                        if state.position_m > 0.5 * approach_height_m:
                            armed = True
                        elif armed and state.position_m <= 0.0:
                            k_imp = k
                    if k_imp < 0 and k >= n_max:
                        break
                elif k >= k_imp + n_win - n_pre - 1:
                    break
            if k_imp < 0:
                where = f"sample {getattr(device, 'sample_name', '?')!r}" if is_sim else "the surface"
                raise ValueError(f"record: tap {i} (v={v} m/s): no impact detected on {where}")
            if k_imp < max(n_pre, n_vel):
                raise ValueError(f"record: tap {i}: impact too early to capture {pre_s} s before it")
            first = k_imp - n_pre
            a = acc[first:first + n_win].copy()
            t = (np.arange(n_win) - n_pre) / fs
            v_in = incoming_velocity_m_s(pos[k_imp - n_vel:k_imp], fs)
            if not v_in > 0:
                raise ValueError(f"record: tap {i}: measured incoming velocity {v_in:.3g} m/s is not downward")
            taps.append((v_in, t, a))
    finally:
        device.zero()
        if is_sim and was_enabled is not None:
            device.motor_enabled = was_enabled
    return taps
