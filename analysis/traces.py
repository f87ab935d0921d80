"""Tolerant reader of the study's per-attempt traces, for Figure 4.20.

The study writes ``DATA/<subject>/traces/<phase>_t<trial:03d>_a<attempt:02d>.npz`` with full-rate
arrays (docs/study.md). This reader accepts a few spellings of the keys, so a
renamed array degrades Figure 4.20 to a note in the report instead of an error:

* time: ``t_s`` | ``time_s`` | ``t`` (s), or ``fs_hz`` alone (samples from t = 0)
* handle acceleration: ``accel_m_s2`` | ``acceleration_m_s2`` | ``handle_accel_m_s2`` | ``a_m_s2`` (m/s^2)
* handle position (to find impacts when no event times are stored): ``position_m`` | ``x_m`` (m, up)
* impacts, optional: ``event_t_s`` | ``events_t_s`` | ``impact_t_s`` | ``tap_t_s`` (s), with
  ``event_incoming_velocity_m_s`` | ``incoming_velocity_m_s`` | ``impact_velocity_m_s`` (m/s)
"""

from __future__ import annotations

import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.load import parse_lists

TIME_KEYS = ("t_s", "time_s", "t")
ACCEL_KEYS = ("accel_m_s2", "acceleration_m_s2", "handle_accel_m_s2", "a_m_s2", "accel")
POSITION_KEYS = ("position_m", "x_m", "handle_position_m")
IMPACT_KEYS = ("event_t_s", "events_t_s", "impact_t_s", "tap_t_s", "impact_times_s", "event_time_s")
VELOCITY_KEYS = ("event_incoming_velocity_m_s", "incoming_velocity_m_s", "impact_velocity_m_s",
                 "events_incoming_velocity_m_s", "incoming_velocities_m_s")


@dataclass(frozen=True)
class Tap:
    """Acceleration around one impact: ``t_s`` relative to the impact (s), ``accel_m_s2``, ``v_in_m_s``."""

    subject: str
    sample: str
    v_in_m_s: float
    t_s: np.ndarray
    accel_m_s2: np.ndarray
    source: str


def trace_path(subject_dir: Path, phase: str, trial: int, attempt: int) -> Path:
    """Where the study stores the trace of one attempt."""
    return Path(subject_dir) / "traces" / f"{phase}_t{int(trial):03d}_a{int(attempt):02d}.npz"


def _first(arrays, keys):
    names = arrays.files if hasattr(arrays, "files") else arrays
    for k in keys:
        if k in names:
            return np.asarray(arrays[k], dtype=float).reshape(-1)
    return None


def _impacts_from_position(t: np.ndarray, x: np.ndarray, surface_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Downward crossings of the surface height and the approach speed over the 5 ms before each."""
    below = x < surface_m
    idx = np.flatnonzero(below[1:] & ~below[:-1]) + 1
    fs = 1.0 / np.median(np.diff(t)) if t.size > 1 else 1.0
    back = max(1, int(round(0.005 * fs)))
    v = np.array([(x[max(i - back, 0)] - x[i]) / (t[i] - t[max(i - back, 0)]) if i > 0 else np.nan for i in idx])
    return t[idx], v


def read_trace_taps(path: Path, subject: str, sample: str, velocities_m_s=None, pre_s: float = 0.01,
                    post_s: float = 0.1) -> list[Tap]:
    """Cut the acceleration of every impact in one trace file into windows ``[-pre_s, post_s]``.

    ``velocities_m_s``: the attempt's incoming velocities from trials.csv, used when the trace
    stores no velocities and their count matches the impacts found. Returns [] when the file
    lacks a usable time or acceleration array.
    """
    with np.load(path, allow_pickle=False) as z:
        return _taps_from_arrays(z, path, subject, sample, velocities_m_s, pre_s, post_s)


def _taps_from_arrays(arrays, path, subject, sample, velocities_m_s, pre_s, post_s) -> list[Tap]:
    """Body of :func:`read_trace_taps` on a mapping of arrays (an open NpzFile reads only the keys used)."""
    acc = _first(arrays, ACCEL_KEYS)
    if acc is None or acc.size < 2:
        return []
    t = _first(arrays, TIME_KEYS)
    if t is None or t.size != acc.size:
        fs = _first(arrays, ("fs_hz", "rate_hz", "servo_rate_hz"))
        if fs is None or not fs.size or not fs[0] > 0:
            return []
        t = np.arange(acc.size) / fs[0]
    impacts, v = _first(arrays, IMPACT_KEYS), _first(arrays, VELOCITY_KEYS)
    if impacts is None:
        x = _first(arrays, POSITION_KEYS)
        if x is None or x.size != acc.size:
            return []
        impacts, v_est = _impacts_from_position(t, x)
        if v is None or v.size != impacts.size:
            # the renderer's recorded velocities (trials.csv) beat a finite-difference estimate
            csv_ok = velocities_m_s is not None and len(velocities_m_s) == impacts.size
            v = np.asarray(velocities_m_s, dtype=float) if csv_ok else v_est
    if velocities_m_s is not None and (v is None or v.size != impacts.size) and len(velocities_m_s) == impacts.size:
        v = np.asarray(velocities_m_s, dtype=float)
    if v is None or v.size != impacts.size:
        return []
    fs = 1.0 / np.median(np.diff(t))
    n_pre, n_post = int(round(pre_s * fs)), int(round(post_s * fs))
    taps = []
    for ti, vi in zip(impacts, v):
        i = int(np.searchsorted(t, ti))
        if i - n_pre < 0 or i + n_post > acc.size or not np.isfinite(vi):
            continue
        seg = acc[i - n_pre:i + n_post]
        taps.append(Tap(subject, sample, float(abs(vi)), (np.arange(-n_pre, n_post)) / fs,
                        seg - seg[:n_pre].mean() if n_pre else seg, str(path)))
    return taps


def folders_with_traces(folders) -> set:
    """The folders (of ``folders``, as given) whose ``traces`` folder holds a ``.npz`` file: one directory
    listing per folder, not a stat per attempt."""
    found = set()
    for folder in folders:
        try:
            with os.scandir(os.path.join(folder, "traces")) as it:
                if any(e.name.endswith(".npz") for e in it):
                    found.add(folder)
        except OSError:
            continue
    return found


def typical_taps(trials: pd.DataFrame, subject_dirs: dict, samples, target_v_m_s: float | None = None,
                 max_files_per_sample: int = 30, velocities=None, traced=None) -> tuple[dict, float, list[str]]:
    """For each sample, the tap whose incoming velocity is nearest a common target (Figure 4.20).

    Parameters
    ----------
    trials : DataFrame
        Valid testing attempts (``subject, phase, trial, attempt, sample, incoming_velocities_m_s``).
    subject_dirs : dict
        subject -> folder (str or Path).
    samples : sequence of str
        Catalog order.
    target_v_m_s : float or None
        Common incoming velocity; default the median of all valid testing taps.
    max_files_per_sample : int
        Trace files opened per sample at most (those whose listed velocities come closest first).
    velocities : (ndarray, ndarray) or None
        The rows' listed incoming velocities already parsed: every value (m/s) and the 0-based row
        of ``trials`` it belongs to (as :attr:`analysis.load.Study.taps` holds them); parsed from
        ``incoming_velocities_m_s`` when None.
    traced : set or None
        The values of ``subject_dirs`` whose folders hold traces (:func:`folders_with_traces`, e.g. listed
        by the report's drawing process while the study loads); listed here when None.

    Returns
    -------
    taps : dict sample -> Tap
    target_v_m_s : float
    notes : list of str
        Why samples have no tap (no trace files, unreadable keys).
    """
    notes = []
    n_rows = len(trials)
    # all velocities in one vectorised parse (linear in rows; a Python loop per row was not)
    if velocities is None:
        lists = trials["incoming_velocities_m_s"].fillna("").astype(str).to_numpy(dtype=object)
        where = trials["file"].to_numpy(dtype=object) if "file" in trials else np.full(n_rows, "?", dtype=object)
        lines = trials["line"].to_numpy() if "line" in trials else np.zeros(n_rows, dtype=np.int64)
        allv, row, counts = parse_lists(lists, where, lines, "incoming_velocities_m_s")
    else:
        allv, row = velocities
        counts = np.bincount(row, minlength=n_rows)
    starts = np.concatenate([[0], np.cumsum(counts)])
    if target_v_m_s is None:
        target_v_m_s = float(np.median(allv)) if allv.size else 0.1
    dist = np.full(n_rows, np.inf)
    if allv.size:
        np.minimum.at(dist, row, np.abs(allv - target_v_m_s))

    def parsed(r):
        return allv[starts[r]:starts[r + 1]]

    # only subjects that saved any trace can give a tap: with thousands of subjects the nearest velocities
    # are otherwise all trace-less
    subjects = pd.unique(trials["subject"])
    if traced is None:
        traced = folders_with_traces([subject_dirs[subj] for subj in subjects])
    with_traces = [subj for subj in subjects if subject_dirs[subj] in traced]
    has_trace = trials["subject"].isin(with_traces).to_numpy(dtype=bool)
    out = {}
    codes = pd.Categorical(trials["sample"], categories=list(samples)).codes
    for k, sample in enumerate(samples):
        rows = np.flatnonzero((codes == k) & has_trace)
        rows = rows[np.argsort(dist[rows], kind="stable")][:max_files_per_sample]
        best, found_file = None, False
        for r in rows:
            rec = trials.iloc[r]
            path = trace_path(subject_dirs[rec["subject"]], rec["phase"], rec["trial"], rec["attempt"])
            if not path.is_file():
                continue
            found_file = True
            try:
                taps = read_trace_taps(path, rec["subject"], sample, parsed(r))
            except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # truncated/corrupt npz
                notes.append(f"{path}: unreadable trace ({type(exc).__name__}: {exc})")
                continue
            for tap in taps:
                if best is None or abs(tap.v_in_m_s - target_v_m_s) < abs(best.v_in_m_s - target_v_m_s):
                    best = tap
        if best is not None:
            out[sample] = best
        elif not found_file:
            notes.append(f"{sample}: no trace files of valid testing attempts")
        else:
            notes.append(f"{sample}: trace files found but no usable time/acceleration/impact arrays")
    return out, target_v_m_s, notes
