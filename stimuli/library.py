"""HFAM transient libraries: storage and real-time lookup (thesis section 4.4.2, Figure 4.9).

A library holds motor-current transients ``currents_A[i_v, i_g, k]`` for incoming
velocities ``velocities_m_s[i_v]`` and grip levels ``grips_N[i_g]``; sample ``k``
is played at ``t = (k + 1)/fs_hz`` after impact. The file format is documented
in ``docs/hfam_library.md``.
"""

from __future__ import annotations

import bisect
import json
import math
import zipfile
import zlib
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_open
from plumbing.npzfile import load_npz

FORMAT = "hfam-library"
FORMAT_VERSION = 1
DEFAULT_MAX_EXTRAPOLATION = 1.5
# relative tolerances when checking a library against a device
FS_RTOL = 1e-6
FORCE_CONSTANT_RTOL = 0.02


def _as_1d_increasing(key: str, values, where: str) -> np.ndarray:
    arr = np.array(values, dtype=float).reshape(-1)
    if arr.size == 0:
        raise ValueError(f"{where}: {key} is empty")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: {key} contains NaN or inf: {arr.tolist()}")
    if arr.size > 1 and not np.all(np.diff(arr) > 0):
        raise ValueError(f"{where}: {key} must be strictly increasing, got {arr.tolist()}")
    return arr


class HfamLibrary:
    """Library of HFAM current transients with bilinear (velocity x grip) lookup.

    Parameters
    ----------
    velocities_m_s : array_like, shape (n_v,)
        Incoming velocity magnitudes of the transients, strictly increasing, > 0.
    grips_N : array_like, shape (n_g,)
        Grip-force levels of the device models, strictly increasing (n_g = 1: grip ignored).
    currents_A : array_like, shape (n_v, n_g, n_t)
        Motor current transients in A; sample k at t = (k+1)/fs_hz after impact.
    fs_hz : float
        Sample rate of the transients; must equal the servo rate they are played at.
    force_per_amp_N_A : float
        Handle force per amp of the device the library was built for (eq. 3.17).
    gain : float
        Global gain applied on lookup (0.8-0.9 for "active"-feeling users, section 4.4.1).
    max_extrapolation : float
        Cap on the factor v_in / v_max used above the library's velocity range.
    metadata : dict
        JSON-serialisable provenance (source files, models, settings, verification).
    desired_accel_m_s2 : array_like, shape (n_v, n_t), optional
        The (smoothed) target accelerations the currents were built to produce.
    """

    name = "hfam"

    def __init__(
        self,
        velocities_m_s,
        grips_N,
        currents_A,
        fs_hz: float,
        force_per_amp_N_A: float,
        *,
        gain: float = 1.0,
        max_extrapolation: float = DEFAULT_MAX_EXTRAPOLATION,
        metadata: dict | None = None,
        desired_accel_m_s2=None,
        source: str = "HfamLibrary",
    ) -> None:
        where = source
        v = _as_1d_increasing("velocities_m_s", velocities_m_s, where)
        if v[0] <= 0:
            raise ValueError(f"{where}: velocities_m_s must be > 0, got {v.tolist()}")
        g = _as_1d_increasing("grips_N", grips_N, where)
        c = np.array(currents_A, dtype=float)
        if c.ndim != 3 or c.shape[0] != v.size or c.shape[1] != g.size or c.shape[2] < 1:
            raise ValueError(
                f"{where}: currents_A must have shape (n_v={v.size}, n_g={g.size}, n_t>=1), got {c.shape}"
            )
        if not np.all(np.isfinite(c)):
            bad = np.argwhere(~np.isfinite(c))[0]
            raise ValueError(
                f"{where}: currents_A contains NaN/inf (velocity {v[bad[0]]} m/s, grip {g[bad[1]]} N, sample {bad[2]})"
            )
        for key, value in (("fs_hz", fs_hz), ("force_per_amp_N_A", force_per_amp_N_A)):
            if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{where}: {key} must be a positive finite number, got {value!r}")
        self.gain = float(gain)
        if not (math.isfinite(self.gain) and self.gain >= 0):
            raise ValueError(f"{where}: gain must be a finite number >= 0, got {gain!r}")
        self.max_extrapolation = float(max_extrapolation)
        if not (math.isfinite(self.max_extrapolation) and self.max_extrapolation >= 1.0):
            raise ValueError(f"{where}: max_extrapolation must be >= 1, got {max_extrapolation!r}")
        if desired_accel_m_s2 is not None:
            desired_accel_m_s2 = np.array(desired_accel_m_s2, dtype=float)
            if desired_accel_m_s2.shape != (v.size, c.shape[2]):
                raise ValueError(
                    f"{where}: desired_accel_m_s2 must have shape {(v.size, c.shape[2])}, got {desired_accel_m_s2.shape}"
                )
        for arr in (v, g, c):
            arr.flags.writeable = False
        self.velocities_m_s = v
        self.grips_N = g
        self.currents_A = c
        self.fs_hz = float(fs_hz)
        self.force_per_amp_N_A = float(force_per_amp_N_A)
        self.metadata = dict(metadata or {})
        self.desired_accel_m_s2 = desired_accel_m_s2
        self.source = source
        # plain-Python copies and per-transient row views so the lookup allocates nothing
        self._v = [float(x) for x in v]
        self._g = [float(x) for x in g]
        self._n_t = int(c.shape[2])
        # the (up to) four transients of one lookup are rows k00, k00+dj, k00+di*n_g, k00+di*n_g+dj of the
        # flattened array: one matrix-vector product over the block of rows between them does the weighted sum
        flat = np.ascontiguousarray(c.reshape(v.size * g.size, self._n_t))
        flat.flags.writeable = False
        self._flat = flat
        n_g = g.size
        spans = sorted({1, 2, n_g + 1, n_g + 2})
        self._blocks = {(k, span): flat[k:k + span] for k in range(flat.shape[0]) for span in spans
                        if k + span <= flat.shape[0]}
        self._wvec = {span: np.zeros(span) for span in spans}
        self._out_obj = None
        self._out_view = None

    # -- properties --------------------------------------------------------
    @property
    def n_samples(self) -> int:
        """Samples per transient, n_t."""
        return self._n_t

    @property
    def duration_s(self) -> float:
        """Length of every transient, s."""
        return self._n_t / self.fs_hz

    def __repr__(self) -> str:
        return (
            f"HfamLibrary(velocities_m_s={self._v}, grips_N={self._g}, n_t={self._n_t}, fs_hz={self.fs_hz}, "
            f"force_per_amp_N_A={self.force_per_amp_N_A}, gain={self.gain})"
        )

    # -- lookup (servo path) -----------------------------------------------
    def weights(self, v_in_m_s: float, grip_N: float) -> tuple[int, int, int, int, float, float, float, float]:
        """Bilinear lookup weights (section 4.4.2).

        Returns ``(i0, i1, j0, j1, w00, w01, w10, w11)``: the transient is
        ``w00*C[i0,j0] + w01*C[i0,j1] + w10*C[i1,j0] + w11*C[i1,j1]`` (gain and the
        out-of-range velocity scaling included). Velocity: linear between the two
        bracketing library velocities (0.07 between 0.065 and 0.081 gives
        0.3125*lower + 0.6875*upper); below/above the range the nearest transient
        scaled by v_in/v_nearest, capped at ``max_extrapolation``. Grip: linear
        between bracketing levels, clamped outside; a NaN grip uses the lowest
        level (the smallest currents). A NaN velocity gives all-zero weights.
        """
        v = abs(v_in_m_s)
        vel = self._v
        last = len(vel) - 1
        scale = self.gain
        if not v == v:  # NaN: play nothing rather than a NaN
            return 0, 0, 0, 0, 0.0, 0.0, 0.0, 0.0
        if v <= vel[0]:
            i0 = i1 = 0
            wv = 0.0
            scale *= v / vel[0]
        elif v >= vel[last]:
            i0 = i1 = last
            wv = 0.0
            ratio = v / vel[last]
            scale *= ratio if ratio < self.max_extrapolation else self.max_extrapolation
        else:
            i1 = bisect.bisect_right(vel, v)
            i0 = i1 - 1
            wv = (v - vel[i0]) / (vel[i1] - vel[i0])
        grips = self._g
        glast = len(grips) - 1
        g = grip_N
        if not g == g or g <= grips[0]:
            j0 = j1 = 0
            wg = 0.0
        elif g >= grips[glast]:
            j0 = j1 = glast
            wg = 0.0
        else:
            j1 = bisect.bisect_right(grips, g)
            j0 = j1 - 1
            wg = (g - grips[j0]) / (grips[j1] - grips[j0])
        return (
            i0, i1, j0, j1,
            scale * (1.0 - wv) * (1.0 - wg),
            scale * (1.0 - wv) * wg,
            scale * wv * (1.0 - wg),
            scale * wv * wg,
        )

    def current_into(self, v_in_m_s: float, grip_N: float, out: np.ndarray) -> int:
        """Write the interpolated current transient (A) into ``out[:n_t]``; return n_t.

        No allocation when ``out`` (a contiguous float64 array) is reused: its
        length-n_t view, the row blocks and the weight vectors are cached, and
        the weighted sum of the (up to) four neighbouring transients is one
        matrix-vector product (BLAS) over the block of rows spanning them. O(1)
        in the library size apart from a bisection over the handful of velocity
        and grip levels.

        Raises
        ------
        ValueError
            If ``out`` is shorter than ``n_samples``.
        """
        n = self._n_t
        if out is self._out_obj:
            dst = self._out_view
        else:
            if out.shape[0] < n:
                raise ValueError(f"HfamLibrary.current_into: buffer has {out.shape[0]} samples, needs {n}")
            dst = out if out.shape[0] == n else out[:n]
            if dst.dtype != np.float64 or not dst.flags.c_contiguous:
                raise ValueError("HfamLibrary.current_into: out must be a contiguous float64 array")
            self._out_obj = out
            self._out_view = dst
        i0, i1, j0, j1, w00, w01, w10, w11 = self.weights(v_in_m_s, grip_N)
        n_g = len(self._g)
        dj = j1 - j0
        di = (i1 - i0) * n_g
        span = di + dj + 1
        w = self._wvec[span]
        w[0] = w00
        w[dj] += w01  # offsets coincide only where the extra weight is zero
        w[di] += w10
        w[di + dj] += w11
        np.dot(w, self._blocks[(i0 * n_g + j0, span)], out=dst)
        w[0] = w[dj] = w[di] = w[di + dj] = 0.0
        return n

    def current(self, v_in_m_s: float, grip_N: float) -> np.ndarray:
        """Interpolated current transient in A, shape (n_t,) (a new array; see ``current_into``)."""
        out = np.empty(self._n_t)
        self.current_into(v_in_m_s, grip_N, out)
        return out

    # -- Transient protocol --------------------------------------------------
    def max_samples(self, fs_hz: float) -> int:
        """n_t (the library is only playable at its own sample rate; see check_device)."""
        return self._n_t

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """Force at the handle in N, shape (n_t,): ``force_per_amp_N_A * current(v, grip)``.

        Raises
        ------
        ValueError
            If ``fs_hz`` differs from the library's sample rate.
        """
        self._check_fs(fs_hz)
        return self.force_per_amp_N_A * self.current(v_in_m_s, grip_N)

    def _check_fs(self, fs_hz: float) -> None:
        if not abs(float(fs_hz) - self.fs_hz) <= FS_RTOL * self.fs_hz:
            raise ValueError(
                f"{self.source}: library sample rate {self.fs_hz} Hz does not match the servo rate {fs_hz} Hz; "
                "rebuild the library at the servo rate"
            )

    def check_device(self, info, fs_hz: float) -> None:
        """Refuse (ValueError) a device this library cannot be played on safely and faithfully.

        Checks: ``fs_hz`` equals the library rate; the device's force constant
        matches the library's within 2 %; the library's peak current (times
        gain) is within ``info.current_peak_A``; and, for grip-compensated
        libraries (n_g > 1), the grip levels cover ``info.grip_range_N``
        (outside the levels the lookup would clamp). A one-level library is
        grip-independent by construction and skips the grip check.
        """
        self._check_fs(fs_hz)
        fpa = float(info.force_per_amp_N_A)
        if abs(fpa - self.force_per_amp_N_A) > FORCE_CONSTANT_RTOL * self.force_per_amp_N_A:
            raise ValueError(
                f"{self.source}: built for a force constant of {self.force_per_amp_N_A:.4g} N/A but device "
                f"{info.name!r} has {fpa:.4g} N/A; rebuild the library with this device's models"
            )
        peak = float(np.max(np.abs(self.currents_A))) * self.gain
        if peak > info.current_peak_A:
            raise ValueError(
                f"{self.source}: library peak current {peak:.3f} A (gain {self.gain}) exceeds device "
                f"{info.name!r} peak limit {info.current_peak_A} A"
            )
        if len(self._g) > 1:
            lo, hi = (float(x) for x in info.grip_range_N)
            if self._g[0] > lo + 1e-9 or self._g[-1] < hi - 1e-9:
                raise ValueError(
                    f"{self.source}: library grip levels {self._g[0]}..{self._g[-1]} N do not cover device "
                    f"{info.name!r} grip range {lo}..{hi} N; add models for the missing grip levels"
                )

    # -- file I/O --------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the library to ``path`` (.npz, format in docs/hfam_library.md) atomically; return the path."""
        path = Path(path)
        meta = dict(self.metadata)
        meta.update(format=FORMAT, format_version=FORMAT_VERSION)
        arrays = {
            "velocities_m_s": np.asarray(self.velocities_m_s),
            "grips_N": np.asarray(self.grips_N),
            "currents_A": np.asarray(self.currents_A),
            "fs_hz": np.float64(self.fs_hz),
            "force_per_amp_N_A": np.float64(self.force_per_amp_N_A),
            "gain": np.float64(self.gain),
            "max_extrapolation": np.float64(self.max_extrapolation),
            "metadata_json": np.array(json.dumps(meta, sort_keys=True, default=_json_default)),
        }
        if self.desired_accel_m_s2 is not None:
            arrays["desired_accel_m_s2"] = np.asarray(self.desired_accel_m_s2)
        with atomic_open(path, "wb") as fh:  # a file object keeps numpy from appending ".npz"
            np.savez_compressed(fh, **arrays)
        return path

    @classmethod
    def load(cls, path, *, gain: float | None = None, max_extrapolation: float | None = None) -> "HfamLibrary":
        """Read a library written by :meth:`save`; errors name the file and key."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"HFAM library {path} does not exist")
        data = load_npz(path, "HFAM library")  # names the file; pickle, .npy, non-zip and truncated told apart
        with data:
            missing = [k for k in ("velocities_m_s", "grips_N", "currents_A", "fs_hz", "force_per_amp_N_A") if k not in data]
            if missing:
                raise ValueError(f"{path}: missing array(s) {', '.join(missing)}; not an HFAM library")
            meta = {}
            if "metadata_json" in data:
                raw = _member(data, "metadata_json", path)
                if raw.dtype.kind not in "US" or raw.ndim != 0:
                    raise ValueError(f"{path}: metadata_json must be a single JSON string, got a {raw.dtype} array "
                                     f"of shape {raw.shape}")
                try:
                    meta = json.loads(str(raw))
                except json.JSONDecodeError as exc:
                    raise ValueError(f"{path}: metadata_json is not valid JSON ({exc})") from None
                if not isinstance(meta, dict):
                    raise ValueError(f"{path}: metadata_json must be a JSON object, got {type(meta).__name__}")
            version = meta.get("format_version", FORMAT_VERSION)
            if isinstance(version, bool) or not isinstance(version, int):
                raise ValueError(f"{path}: metadata_json format_version must be an integer, got {version!r}")
            if meta.get("format", FORMAT) != FORMAT or version > FORMAT_VERSION:
                raise ValueError(
                    f"{path}: format {meta.get('format')!r} version {meta.get('format_version')!r} is not "
                    f"{FORMAT!r} <= {FORMAT_VERSION}"
                )
            arrays = {key: _numeric(data, key, path) for key in ("velocities_m_s", "grips_N", "currents_A")}
            return cls(
                arrays["velocities_m_s"],
                arrays["grips_N"],
                arrays["currents_A"],
                _scalar(data, "fs_hz", path),
                _scalar(data, "force_per_amp_N_A", path),
                gain=_scalar(data, "gain", path) if gain is None and "gain" in data else (1.0 if gain is None else gain),
                max_extrapolation=(
                    _scalar(data, "max_extrapolation", path)
                    if max_extrapolation is None and "max_extrapolation" in data
                    else (DEFAULT_MAX_EXTRAPOLATION if max_extrapolation is None else max_extrapolation)
                ),
                metadata=meta,
                desired_accel_m_s2=(_numeric(data, "desired_accel_m_s2", path)
                                    if "desired_accel_m_s2" in data else None),
                source=str(path),
            )


def _member(data, key: str, path) -> np.ndarray:
    """Read one member of an open library archive; a corrupt member or a pickled (object) array names the key."""
    try:
        return data[key]
    except (zipfile.BadZipFile, EOFError, OSError, zlib.error) as exc:
        raise ValueError(f"{path}: member {key!r} of the HFAM library is corrupt ({exc})") from None
    except ValueError as exc:  # object arrays (allow_pickle=False) and malformed .npy headers
        raise ValueError(f"{path}: member {key!r} of the HFAM library cannot be read ({exc})") from None


def _numeric(data, key: str, path) -> np.ndarray:
    arr = _member(data, key, path)
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{path}: {key} must be a numeric array, got dtype {arr.dtype}")
    return arr


def _scalar(data, key: str, path) -> float:
    """One number stored as a 0-d (or one-element) numeric array; anything else names the key."""
    arr = _member(data, key, path)
    if arr.dtype.kind not in "iuf" or arr.size != 1:
        shown = arr.tolist() if arr.size <= 5 else f"shape {arr.shape}"
        raise ValueError(f"{path}: {key} must be a single number, got {shown!r} (dtype {arr.dtype})")
    return float(arr.reshape(()))


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, (complex, np.complexfloating)):
        return [obj.real, obj.imag]
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
