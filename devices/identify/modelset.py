"""Grip-dependent model sets and interpolation between grip levels (thesis section 3.4.6, 4.2.2).

A set is a directory with one model JSON per grip level and output plus an
index file ``model_set.json``::

    {"kind": "model_set", "grip_N": [0.0, 1.0, ...],
     "models": {"accel_m_s2": ["accel_g0N.json", ...], "position_m": [null, "position_g1N.json", ...]},
     "interpolation": "..."}

(``null`` where an output could not be fitted at that grip level).

Interpolation at a grip between two identified levels g0 < g < g1 (weight
``a = (g - g0)/(g1 - g0)``): the frequency response is interpolated
linearly in log-magnitude (dB) and in unwrapped phase, bin by bin, and the
delay linearly; :meth:`ModelSet.model_at` then fits a zpk model to that
response (order: the larger of the two neighbours', same automatic fitter),
so intermediate models are ordinary :class:`ZpkModel` objects. Pole/zero
positions are *not* interpolated, because neighbouring fits need not have
matching orders or an unambiguous pairing of roots. Outside the identified
range the nearest model is used (no extrapolation).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_write_text, read_json_file
from ..model import OUTPUTS, ZpkModel, load_model
from .fit import FitOptions, fit_frequency_response

INDEX_NAME = "model_set.json"
INTERPOLATION = ("linear in grip of log-magnitude (dB) and unwrapped phase of the neighbouring models' "
                 "frequency responses, delay linear; refitted to a zpk model; nearest model outside the range")


@dataclass(frozen=True, eq=False)
class ModelSet:
    """Models of one device at several grip levels.

    Attributes
    ----------
    grip_N : ndarray, shape (g,)
        Increasing grip levels.
    models : dict of str -> list of (ZpkModel or None)
        Per output (``"accel_m_s2"``, ``"position_m"``), one model per grip
        level; None where that output could not be fitted at that grip (the
        output's other grip levels are then used).
    """

    grip_N: np.ndarray
    models: dict

    def __post_init__(self) -> None:
        g = np.asarray(self.grip_N, dtype=float)
        if g.ndim != 1 or g.size < 1 or np.any(np.diff(g) <= 0) or not np.all(np.isfinite(g)) or np.any(g < 0):
            raise ValueError(f"model set grip levels must be finite, >= 0 N and strictly increasing, got {self.grip_N!r}")
        for out, ms in self.models.items():
            if out not in OUTPUTS:
                raise ValueError(f"model set: unknown output {out!r}")
            if len(ms) != g.size:
                raise ValueError(f"model set: {len(ms)} {out} models for {g.size} grip levels")
            if all(m is None for m in ms):
                raise ValueError(f"model set: no {out} model at any grip level")
        object.__setattr__(self, "grip_N", g)

    def grips_for(self, output: str) -> np.ndarray:
        """Grip levels that have a model for ``output``."""
        return np.array([g for g, m in zip(self.grip_N, self._get(output)) if m is not None])

    def _neighbours(self, grip_N: float, output: str):
        """(model_lo, model_hi, weight of model_hi) around ``grip_N``."""
        pairs = [(g, m) for g, m in zip(self.grip_N, self._get(output)) if m is not None]
        g = np.array([p[0] for p in pairs])
        ms = [p[1] for p in pairs]
        if not np.isfinite(grip_N):
            raise ValueError(f"grip_N must be finite, got {grip_N}")
        if grip_N <= g[0]:
            return ms[0], ms[0], 0.0, (g[0], g[0])
        if grip_N >= g[-1]:
            return ms[-1], ms[-1], 0.0, (g[-1], g[-1])
        i = int(np.searchsorted(g, grip_N, side="right") - 1)
        a = float((grip_N - g[i]) / (g[i + 1] - g[i]))
        return ms[i], ms[i + 1], a, (g[i], g[i + 1])

    def response_at(self, grip_N: float, f_hz, output: str = "accel_m_s2") -> np.ndarray:
        """Interpolated frequency response at ``grip_N`` (see module doc), delay included."""
        m0, m1, a, _ = self._neighbours(float(grip_N), output)
        f = np.asarray(f_hz, dtype=float)
        h0 = m0.frequency_response(f)
        if a == 0.0:
            return h0
        h1 = m1.frequency_response(f)
        mag = np.exp((1 - a) * np.log(np.abs(h0)) + a * np.log(np.abs(h1)))
        p0, p1 = np.unwrap(np.angle(h0)), np.unwrap(np.angle(h1))
        p1 -= 2 * np.pi * np.round((p1[0] - p0[0]) / (2 * np.pi))
        return mag * np.exp(1j * ((1 - a) * p0 + a * p1))

    def model_at(self, grip_N: float, output: str = "accel_m_s2", n_points: int = 400) -> ZpkModel:
        """A zpk model at ``grip_N``: a stored one, or one fitted to the interpolated response."""
        m0, m1, a, (g0, g1) = self._neighbours(float(grip_N), output)
        if a == 0.0:
            return m0
        lo = max(m.band_hz[0] if m.band_hz else 10.0 for m in (m0, m1))
        hi = min(m.band_hz[1] if m.band_hz else 1000.0 for m in (m0, m1))
        f = np.linspace(lo, hi, n_points)
        delay = (1 - a) * m0.delay_s + a * m1.delay_s
        # fit the rational part with the interpolated delay removed
        H = self.response_at(grip_N, f, output) * np.exp(2j * np.pi * f * delay)
        order = max(m0.order, m1.order)
        res = fit_frequency_response(f, H, None, FitOptions(order=order, delay_s=0.0, max_rms_db=1e9,
                                                             max_rms_phase_deg=1e9, max_points=n_points),
                                     output=output, grip_N=float(grip_N))
        m = res.model
        fit = {"interpolated_from_grip_N": [float(g0), float(g1)],
               "interpolation": INTERPOLATION, "refit_rms_db": res.metrics["rms_db"],
               "refit_rms_phase_deg": res.metrics["rms_phase_deg"]}
        return ZpkModel(m.zeros_rad_s, m.poles_rad_s, m.gain, delay, output=output, band_hz=(lo, hi),
                        grip_N=float(grip_N), fit=fit, source="interpolated model set")

    def _get(self, output: str) -> list:
        if output not in self.models:
            raise ValueError(f"model set has no {output!r} models (has {sorted(self.models)})")
        return self.models[output]

    def save(self, directory) -> Path:
        """Write every model and the index file into ``directory``; returns the index path."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        names = {}
        for out, ms in self.models.items():
            short = "accel" if out == "accel_m_s2" else "position"
            names[out] = []
            for g, m in zip(self.grip_N, ms):
                name = None if m is None else f"{short}_g{g:g}N.json"
                if m is not None:
                    m.save(d / name)
                names[out].append(name)
        index = {"kind": "model_set", "grip_N": [float(g) for g in self.grip_N], "models": names,
                 "interpolation": INTERPOLATION}
        return atomic_write_text(d / INDEX_NAME, json.dumps(index, indent=2) + "\n")


def read_model_set_index(path) -> tuple[Path, dict, dict]:
    """Read and check a model set's index file (or the directory holding ``model_set.json``), loading no model.

    Shared by :func:`load_model_set` and ``python -m stimuli build-library``, so both refuse the same
    malformed indexes with the same messages.

    Returns
    -------
    index : Path
        The index file.
    data : dict
        Its parsed content.
    files : dict of str -> list of (Path or None)
        Per output, the model file of each grip level (None where there is none).

    Raises
    ------
    FileNotFoundError
        Index missing.
    ValueError
        Malformed index, naming the file and key.
    """
    path = Path(path)
    if path.is_dir():
        path = path / INDEX_NAME
    data = read_json_file(path, "model set index")
    if not isinstance(data, dict) or data.get("kind") != "model_set":
        raise ValueError(f"{path}: key 'kind' must be \"model_set\"")
    for key in ("grip_N", "models"):
        if key not in data:
            raise ValueError(f"{path}: missing key {key!r}")
    if not isinstance(data["models"], dict):
        raise ValueError(f"{path}: key 'models' must be an object of output -> list of files")
    files = {}
    for out, names in data["models"].items():
        if not isinstance(names, list):
            raise ValueError(f"{path}: key 'models.{out}' must be a list of file names")
        for i, f in enumerate(names):
            if f is not None and not isinstance(f, str):
                raise ValueError(f"{path}: key 'models.{out}'[{i}] must be a file name or null")
        files[out] = [None if f is None else path.parent / f for f in names]
    return path, data, files


def load_model_set(path) -> ModelSet:
    """Load a model set from its index file (or the directory holding ``model_set.json``).

    Raises
    ------
    FileNotFoundError
        Index or a model file missing.
    ValueError
        Malformed index (naming file and key) or model files.
    """
    path, data, files = read_model_set_index(path)
    models = {out: [None if f is None else load_model(f) for f in fs] for out, fs in files.items()}
    try:
        ms = ModelSet(np.asarray(data["grip_N"], dtype=float), models)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    _check_entries(path, ms, files)
    return ms


def _check_entries(path, ms: ModelSet, files: dict) -> None:
    """Each model file named in the index describes the output it is listed under, and (where it records
    its grip) the grip level of its slot: its grip is nearer to that level than to any other. Identification
    records the mean measured grip, so an exact match is not required; a list in the wrong order is caught."""
    levels = ms.grip_N
    for out, fs in files.items():
        for j, (f, m) in enumerate(zip(fs, ms.models[out])):
            if m is None:
                continue
            if m.output != out:
                raise ValueError(f"{path}: models.{out}[{j}] = {f} is a model of {m.output!r}, not {out!r}")
            if m.grip_N is not None and int(np.argmin(np.abs(levels - m.grip_N))) != j:
                raise ValueError(f"{path}: models.{out}[{j}] = {f} was identified at grip {m.grip_N:g} N, not at "
                                 f"the index's level {levels[j]:g} N (is the list in the order of grip_N?)")
