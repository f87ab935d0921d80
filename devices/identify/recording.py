"""Swept-sine identification recordings: CSV + JSON sidecar (format in docs/models.md).

``REC.csv`` has the header ``t_s,current_A,accel_m_s2,position_m,grip_N`` and
one row per servo sample; ``REC.json`` (same stem) holds at least
``fs_hz, f_start_hz, f_end_hz, duration_s, amplitude_A, repetitions``.
Reading validates both and refuses NaN, dropped samples, too short records
and sweep bands above Nyquist, naming the file, key and line.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_open, atomic_write_text, read_json_file
from plumbing.validation import is_finite_number, shown_value

from .sweep import SweepConfig

COLUMNS = ("t_s", "current_A", "accel_m_s2", "position_m", "grip_N")
SIDECAR_KEYS = ("fs_hz", "f_start_hz", "f_end_hz", "duration_s", "amplitude_A", "repetitions")
# a step of t_s further than this fraction of a sample period from 1/fs_hz is a dropped/duplicated sample
GAP_TOLERANCE = 0.5


@dataclass(frozen=True, eq=False)
class Recording:
    """One swept-sine trial: command and responses sampled at ``sweep.fs_hz``.

    Attributes
    ----------
    sweep : SweepConfig
    t_s, current_A, accel_m_s2, position_m, grip_N : ndarray of float, shape (n,)
        Sample times (s), commanded current (A), handle acceleration (m/s^2),
        handle position (m) and grip force (N). ``n >= sweep.repetitions * N``.
    meta : dict
        The rest of the sidecar (polarity, grip target, device, trial, ...).
    path : Path or None
        The CSV file it was read from / written to.
    """

    sweep: SweepConfig
    t_s: np.ndarray
    current_A: np.ndarray
    accel_m_s2: np.ndarray
    position_m: np.ndarray
    grip_N: np.ndarray
    meta: dict = field(default_factory=dict)
    path: Path | None = None

    def signal(self, name: str) -> np.ndarray:
        """Column by name (one of ``COLUMNS``)."""
        if name not in COLUMNS:
            raise ValueError(f"unknown recording column {name!r}; columns: {', '.join(COLUMNS)}")
        return getattr(self, name)

    @property
    def label(self) -> str:
        """The file the recording came from, or ``recording(<trial>)`` for one in memory."""
        return str(self.path) if self.path is not None else f"recording({self.meta.get('trial', '?')})"

    def grip_variation_N(self) -> float:
        """Half the peak-to-peak grip over the analysed (second) sweep, N (the +-0.5 N criterion)."""
        lo, hi = analysed_slice(self)
        g = self.grip_N[lo:hi]
        return float((g.max() - g.min()) / 2) if g.size else 0.0

    def sidecar(self) -> dict:
        """The JSON sidecar dictionary."""
        s = self.sweep
        data = {"fs_hz": s.fs_hz, "f_start_hz": s.f_start_hz, "f_end_hz": s.f_end_hz,
                "duration_s": s.duration_s, "amplitude_A": s.amplitude_A, "repetitions": s.repetitions}
        data.update(self.meta)
        return data


def analysed_slice(rec: Recording) -> tuple[int, int]:
    """Sample range [lo, hi) of the sweep copy analysed by the ETFE: the second one (section 3.4.2).

    A recording with a single repetition uses its only copy (start-up
    transients then remain in the data).
    """
    n = rec.sweep.n_samples
    rep = 1 if rec.sweep.repetitions >= 2 else 0
    return rep * n, (rep + 1) * n


def sidecar_path(csv_path) -> Path:
    """The ``.json`` metadata file that goes with a recording CSV."""
    return Path(csv_path).with_suffix(".json")


def write_recording(path, rec: Recording) -> Path:
    """Write ``rec`` as ``path`` (CSV) plus its ``.json`` sidecar; atomic per file.

    Returns
    -------
    Path
        The CSV path.
    """
    path = write_csv_columns(path, COLUMNS, [rec.t_s, rec.current_A, rec.accel_m_s2, rec.position_m, rec.grip_N])
    atomic_write_text(sidecar_path(path), json.dumps(rec.sidecar(), indent=2, allow_nan=False) + "\n")
    return path


def write_csv_columns(path, columns, arrays) -> Path:
    """Write equal-length 1-D ``arrays`` (one per name in ``columns``) as a CSV with a header line.

    Atomic (see :func:`plumbing.fileio.atomic_open`); values as ``%.10g``.
    The counterpart of :func:`read_csv_columns`.
    """
    data = [np.ascontiguousarray(a, dtype=float) for a in arrays]
    if not data or any(a.ndim != 1 or a.shape != data[0].shape for a in data):
        np.column_stack(arrays)  # no arrays or mismatched lengths: numpy's error
        raise ValueError(f"need 1-D arrays of one length, got shapes {[a.shape for a in data]}")
    # same text as np.savetxt(fmt="%.10g", delimiter=","): each distinct value formatted once, column by column
    text = [_column_text(a) for a in data]
    with atomic_open(path) as fh:
        fh.write(",".join(columns) + "\n")
        for i in range(0, data[0].size, 8192):
            fh.write("".join([",".join(row) + "\n" for row in zip(*(t[i:i + 8192] for t in text))]))
    return Path(path)


# text of recent columns with many distinct values (fingerprint -> (values, text)), at most _TEXT_CACHE_SIZE:
# the sweep's current repeats trial after trial (two polarities), and with a fresh simulated device per grip
# (identify's parallel mode) so does the time column of each trial number
_TEXT_CACHE: OrderedDict = OrderedDict()
_TEXT_CACHE_SIZE = 8


def _column_text(a: np.ndarray) -> list[str]:
    """``"%.10g" % v`` of each value of ``a`` (float64, contiguous), formatting each distinct value once."""
    bits = a.view(np.int64)  # exact identity: 0.0 and -0.0 format differently
    key = (a.size, bits[:: max(1, a.size // 64)].tobytes())
    hit = _TEXT_CACHE.get(key)
    if hit is not None and np.array_equal(hit[0], bits):
        _TEXT_CACHE.move_to_end(key)
        return hit[1]
    u, inv = np.unique(bits, return_inverse=True)
    text = np.array(["%.10g" % v for v in u.view(np.float64).tolist()], dtype=object)[inv].tolist()
    if u.size * 4 > a.size:
        _TEXT_CACHE[key] = (bits.copy(), text)
        while len(_TEXT_CACHE) > _TEXT_CACHE_SIZE:
            _TEXT_CACHE.popitem(last=False)
    return text


def _sweep_from_sidecar(data: dict, where: str) -> SweepConfig:
    if not isinstance(data, dict):
        raise ValueError(f"{where}: top level must be a JSON object")
    for key in SIDECAR_KEYS:
        if key not in data:
            raise ValueError(f"{where}: missing key {key!r}")
        value = data[key]
        if not is_finite_number(value):
            raise ValueError(f"{where}: key {key!r} must be a finite number, got {shown_value(value)}")
    if data["repetitions"] != int(data["repetitions"]):
        raise ValueError(f"{where}: key 'repetitions' must be an integer, got {data['repetitions']!r}")
    try:
        return SweepConfig(amplitude_A=float(data["amplitude_A"]), f_start_hz=float(data["f_start_hz"]),
                           f_end_hz=float(data["f_end_hz"]), duration_s=float(data["duration_s"]),
                           fs_hz=float(data["fs_hz"]), repetitions=int(data["repetitions"]))
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def read_csv_columns(path: Path, columns) -> dict[str, np.ndarray]:
    """Read the named numeric columns of a CSV with a header line (other columns are ignored).

    Returns
    -------
    dict of column name -> ndarray, shape (n,)

    Raises
    ------
    ValueError
        Naming the file for an unparsable CSV or missing column(s), and file,
        line and column of the first non-numeric or NaN/inf value.
    """
    import pandas as pd  # deferred: 1.35 s CPU; only reading a recording needs it (identify, the demo only write)

    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot parse CSV ({exc})") from None
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (header must have {', '.join(columns)})")
    arrays = {}
    for col in columns:
        values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = int(bad[0])
            raise ValueError(f"{path}: line {row + 2}, column {col!r}: value {df[col].iloc[row]!r} is not a "
                             f"finite number (NaN/inf or text); {bad.size} such row(s)")
        arrays[col] = values
    return arrays


def read_recording(path) -> Recording:
    """Read and validate a recording (CSV + sidecar).

    Raises
    ------
    FileNotFoundError
        If the CSV or its sidecar is missing.
    ValueError
        Naming file, key/column and line for: malformed sidecar, sweep band
        at or above Nyquist, missing column, non-numeric or NaN/inf value,
        dropped-sample gap (t_s step not 1/fs_hz), too few samples for
        ``repetitions`` sweeps.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recording not found: {path}")
    side = sidecar_path(path)
    if not side.is_file():
        raise FileNotFoundError(f"recording sidecar not found: {side} (needed next to {path})")
    meta = read_json_file(side, "recording sidecar")
    sweep = _sweep_from_sidecar(meta, str(side))
    grip = meta.get("grip_mean_N")  # groups the curves of `devices fit` and is averaged by identify
    if grip is not None and not is_finite_number(grip):
        raise ValueError(f"{side}: key 'grip_mean_N' must be a finite number (mean grip in N) or absent, got "
                         f"{grip!r:.40}")
    arrays = read_csv_columns(path, COLUMNS)
    rec = Recording(sweep, arrays["t_s"], arrays["current_A"], arrays["accel_m_s2"], arrays["position_m"],
                    arrays["grip_N"], {k: v for k, v in meta.items() if k not in SIDECAR_KEYS}, path)
    check_recording(rec)
    return rec


def check_recording(rec: Recording) -> None:
    """Validate sample count and timing of ``rec`` (see :func:`read_recording`)."""
    where = rec.label
    n = rec.t_s.size
    for name in COLUMNS:
        arr = rec.signal(name)
        if arr.shape != (n,):
            raise ValueError(f"{where}: column {name!r} has shape {arr.shape}, expected ({n},)")
        if not np.all(np.isfinite(arr)):
            row = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise ValueError(f"{where}: line {row + 2}, column {name!r}: NaN/inf")
    step = 1.0 / rec.sweep.fs_hz
    dt = np.diff(rec.t_s)
    bad = np.flatnonzero(np.abs(dt - step) > GAP_TOLERANCE * step)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{where}: dropped-sample gap between lines {i + 2} and {i + 3}: t_s goes from "
                         f"{rec.t_s[i]:.6g} to {rec.t_s[i + 1]:.6g} s, expected a step of {step:.6g} s "
                         f"(fs_hz = {rec.sweep.fs_hz})")
    n_needed = rec.sweep.repetitions * rec.sweep.n_samples
    if n < n_needed:
        raise ValueError(f"{where}: too few samples for the sweep: {n} rows, need {n_needed} "
                         f"({rec.sweep.repetitions} x {rec.sweep.duration_s} s at {rec.sweep.fs_hz} Hz)")
