"""The demo's offline HFAM pipeline (thesis Figure 4.7), cached in a user cache folder.

Three long steps, each through the owning package's Python API:

1. identify the sim device at several grip levels (swept sine, ETFE, automatic
   LTI fit: :func:`devices.identify.pipeline.identify_device`), giving a
   grip-dependent model set of commanded current -> handle acceleration;
2. record real taps on the simulated ``wood_on_foam`` sample over a range of
   incoming velocities with the motor off (:func:`devices.recording.record_taps`,
   written in the ``python -m devices record`` CSV format);
3. build the HFAM current library from those recordings and the per-grip
   models (:func:`stimuli.hfam.build_library`).

The results live in ``<cache base>/demo-<key>/`` where ``key`` hashes every
parameter of the three steps *and* the source code of the modules that
compute them, so a changed parameter or a changed algorithm never reuses a
stale library. ``<cache base>`` is ``--cache-dir`` or
``$XDG_CACHE_HOME/hfam-haptics`` (``~/.cache/hfam-haptics``). A cache entry
is written into a temporary folder and renamed when complete, so an
interrupted run never leaves a half-built entry behind.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: modules whose code determines the cached results (hashed into the cache key)
_CODE_PATHS = ("devices/sim", "devices/identify", "devices/model.py", "devices/recording.py",
               "stimuli/hfam.py", "stimuli/hfam_refine.py", "stimuli/library.py", "stimuli/recordings.py", "renderer/demo_pipeline.py")
CACHE_VERSION = 1
#: the simulated user's desired hand comes to rest this long after crossing the surface (s): a tap, not a
#: press (docs/demo.md, "The simulated tap")
TAP_STOP_TIME_S = 0.045


def tap_press_depth_m(velocity_m_s: float, stop_time_s: float = TAP_STOP_TIME_S) -> float:
    """How far below the surface the simulated hand aims a tap at ``velocity_m_s`` (m).

    :class:`devices.sim.TapTrajectory` keeps the tap speed for half the press
    depth ``d``, then brakes uniformly over the other half, so its desired
    hand comes to rest ``1.5 d / velocity`` after crossing the surface. A
    press depth of ``velocity x stop_time_s / 1.5`` makes every tap stop
    pushing ``stop_time_s`` after contact, whatever its speed (the arm's
    braking time, not its braking distance, is what a person keeps).
    """
    return float(velocity_m_s) * float(stop_time_s) / 1.5


def tap_approach_height_m(velocity_m_s: float) -> float:
    """Start height of the simulated hand's tap: 40 ms of travel at the tap speed, at least 4 mm.

    The same for the recordings and every rendering: the simulated person's
    arm has its own slow dynamics (the 8 Hz compensation), so the state it
    arrives in depends on how long it has travelled (issue 16).
    """
    return max(0.004, 0.04 * float(velocity_m_s))


def tap_trajectory_options(velocity_m_s: float, stop_time_s: float = TAP_STOP_TIME_S) -> dict:
    """Keyword arguments of the simulated hand's :class:`devices.sim.TapTrajectory` for one tap."""
    return {"press_depth_m": tap_press_depth_m(velocity_m_s, stop_time_s)}


@dataclass(frozen=True)
class PipelineSettings:
    """Parameters of the offline pipeline (all part of the cache key).

    Attributes
    ----------
    device : str
        Sim device string (``sim``, ``sim:lti``, ``sim:<params file>``).
    identify_grips_N : tuple of float
        Grip levels identified (strictly increasing, N).
    identify_trials : int
        Swept-sine trials per grip level.
    sweep_amplitude_A, sweep_duration_s : float
        Swept-sine current amplitude (<= continuous limit) and length of one sweep.
    sweep_band_hz : (float, float)
        Start and end frequency of the sweep.
    record_velocities_m_s : tuple of float
        Incoming velocities of the recorded real taps (m/s).
    record_grip_N : float
        Grip of the simulated hand while recording (the thesis's recordings
        do not vary grip, section 4.4.1).
    tap_stop_time_s : float
        How long after crossing the surface the simulated hand's desired
        position comes to rest, s (:func:`tap_press_depth_m`). The same hand taps the recordings and
        every rendering (see ``docs/demo.md``, "The simulated tap").
    sample : str
        Real sample tapped for the recordings.
    library_velocities : int
        Number of velocities the builder picks for the library.
    smooth_hz : float
        Zero-phase smoothing bandwidth of the builder (<= 1000 Hz).
    refine_iterations : int
        Playback-and-correction passes over every library transient on the sim
        (``stimuli.hfam_refine``, over the firm wall; 0: off). Issue 16.
    seed : int
        Sensor-noise seed of the sim device.
    """

    device: str = "sim"
    identify_grips_N: tuple = (0.0, 1.0, 2.0, 3.0, 5.0, 10.0)
    identify_trials: int = 2
    sweep_amplitude_A: float = 0.25
    sweep_duration_s: float = 1.0
    sweep_band_hz: tuple = (5.0, 1000.0)
    # 12 taps over 0.04-0.12 m/s: the range where HFAM stays within NRMSE 0.35 at every grip (docs/demo.md)
    record_velocities_m_s: tuple = (0.04, 0.047, 0.055, 0.062, 0.069, 0.076, 0.084, 0.091, 0.098, 0.105, 0.113, 0.12)
    record_grip_N: float = 2.0
    tap_stop_time_s: float = TAP_STOP_TIME_S
    sample: str = "wood_on_foam"
    library_velocities: int = 10
    smooth_hz: float = 500.0
    refine_iterations: int = 0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.device.startswith("sim"):
            raise ValueError(f"the offline demo pipeline runs on a sim device, got device {self.device!r}")
        g = [float(x) for x in self.identify_grips_N]
        if not g or any(b <= a for a, b in zip(g, g[1:])) or g[0] < 0:
            raise ValueError(f"identify_grips_N must be >= 0 and strictly increasing, got {self.identify_grips_N!r}")
        v = [float(x) for x in self.record_velocities_m_s]
        if len(v) < 2 or any(x <= 0 for x in v):
            raise ValueError(f"record_velocities_m_s needs >= 2 positive velocities, got {self.record_velocities_m_s!r}")
        if not (math.isfinite(self.sweep_amplitude_A) and self.sweep_amplitude_A > 0):
            raise ValueError(f"sweep_amplitude_A must be > 0 A, got {self.sweep_amplitude_A!r}")
        if not (math.isfinite(self.tap_stop_time_s) and 0.003 <= self.tap_stop_time_s <= 1.0):
            raise ValueError(f"tap_stop_time_s must be in [0.003, 1] s, got {self.tap_stop_time_s!r}")
        if not self.record_grip_N >= 0:
            raise ValueError(f"record_grip_N must be >= 0 N, got {self.record_grip_N!r}")

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}


@dataclass
class Pipeline:
    """The cached products of :func:`build_or_load`.

    Attributes
    ----------
    directory : Path
        The cache entry.
    model_set : devices.identify.modelset.ModelSet
        Identified current -> acceleration (and motor position) models per grip.
    library : stimuli.HfamLibrary
    fs_hz : float
    taps : list of stimuli.recordings.Tap
        The recorded real taps (t relative to impact).
    from_cache : bool
    timings_s : dict
        Wall time of each step when it was built.
    """

    directory: Path
    model_set: object
    library: object
    fs_hz: float
    taps: list
    from_cache: bool
    timings_s: dict

    @property
    def etfe_npz(self) -> Path:
        return self.directory / "identify" / "etfe.npz"

    @property
    def recordings_csv(self) -> Path:
        return self.directory / "recordings.csv"

    @property
    def library_npz(self) -> Path:
        return self.directory / "library.npz"


def default_cache_base() -> Path:
    """``$XDG_CACHE_HOME/hfam-haptics`` or ``~/.cache/hfam-haptics``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hfam-haptics"


@functools.lru_cache(maxsize=4)
def code_digest(root: Path | None = None) -> str:
    """SHA-256 over the source files that compute the cached results (see ``_CODE_PATHS``).

    Computed once per process: the code a process runs is the code it imported.
    """
    root = Path(__file__).resolve().parent.parent if root is None else root
    h = hashlib.sha256()
    for rel in _CODE_PATHS:
        p = root / rel
        files = sorted(p.rglob("*")) if p.is_dir() else [p]
        for f in files:
            if f.is_file() and f.suffix in (".py", ".toml", ".json"):
                h.update(str(f.relative_to(root)).encode())
                h.update(f.read_bytes())
    return h.hexdigest()


def cache_key(settings: PipelineSettings) -> str:
    """16-hex-digit key of the settings, the sim parameters and the code (see module doc)."""
    from devices.registry import make_device

    dev = make_device(settings.device)
    params = dev.params.to_dict() if hasattr(dev, "params") and hasattr(dev.params, "to_dict") else {}
    blob = json.dumps({"version": CACHE_VERSION, "settings": settings.to_dict(), "sim_params": params,
                       "code": code_digest()}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


class Progress:
    """Step-wise progress on stderr: ``[i/n] what ...`` then the step's lines and its wall time."""

    def __init__(self, n_steps: int, stream=None, quiet: bool = False):
        self.n = n_steps
        self.i = 0
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self._t0 = 0.0

    def start(self, what: str) -> None:
        self.i += 1
        self._t0 = time.perf_counter()
        self.say(f"[{self.i}/{self.n}] {what} ...", indent=False)

    def done(self, note: str = "") -> float:
        dt = time.perf_counter() - self._t0
        self.say(f"done in {dt:.1f} s{(': ' + note) if note else ''}")
        return dt

    def say(self, msg: str, indent: bool = True) -> None:
        if not self.quiet:
            print(("      " if indent else "") + msg, file=self.stream, flush=True)


def build_or_load(settings: PipelineSettings, cache_base: Path | None = None, rebuild: bool = False,
                  progress: Progress | None = None) -> Pipeline:
    """Return the pipeline products, from the cache when present, else built (and cached).

    Parameters
    ----------
    settings : PipelineSettings
    cache_base : Path or None
        Cache folder (default :func:`default_cache_base`).
    rebuild : bool
        Ignore and replace an existing cache entry.
    progress : Progress or None
        Where the three steps report; None prints nothing.
    """
    progress = progress or Progress(3, quiet=True)
    base = Path(cache_base) if cache_base is not None else default_cache_base()
    key = cache_key(settings)
    entry = base / f"demo-{key}"
    if not rebuild and (entry / "manifest.json").is_file():
        try:
            return _load(entry, settings)
        except (OSError, ValueError, KeyError) as exc:  # a damaged entry is rebuilt, not trusted
            progress.say(f"cache entry {entry} unusable ({exc}); rebuilding", indent=False)
    base.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".demo-{key}-", dir=base))
    try:
        timings = _build(tmp, settings, progress)
        manifest = {"key": key, "settings": settings.to_dict(), "timings_s": timings,
                    "created_unix": time.time(), "version": CACHE_VERSION}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        if entry.exists():
            shutil.rmtree(entry)
        os.replace(tmp, entry)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    pipe = _load(entry, settings)
    pipe.from_cache = False
    return pipe


def _build(out: Path, s: PipelineSettings, progress: Progress) -> dict:
    from devices.recording import record_taps, write_tap_recording
    from devices.registry import make_device
    from stimuli.hfam import BuildSettings, build_library, format_verification
    from stimuli.recordings import read_tap_csv

    timings = {}
    dev = make_device(s.device, seed=s.seed)
    fs = dev.info.servo_rate_hz
    with dev:
        progress.start(f"identifying {s.device} at grips {', '.join(f'{g:g}' for g in s.identify_grips_N)} N "
                       f"({s.identify_trials} swept-sine trials each)")
        timings["identify"] = progress.done(identify_grips(dev, s, out / "identify", progress.say))

        progress.start(f"recording {len(s.record_velocities_m_s)} real taps on {s.sample} "
                       f"({min(s.record_velocities_m_s):g}-{max(s.record_velocities_m_s):g} m/s, "
                       f"grip {s.record_grip_N:g} N, motor off)")
        dev.set_sample(s.sample)
        # one call per velocity: the hand's aim below the surface scales with the tap speed
        taps = [tap for v in s.record_velocities_m_s
                for tap in record_taps(dev, [float(v)], grip_N=s.record_grip_N,
                                       approach_height_m=tap_approach_height_m(v),
                                       trajectory_options=tap_trajectory_options(v, s.tap_stop_time_s))]
        write_tap_recording(out / "recordings.csv", taps, fs)
        timings["record"] = progress.done(f"{len(taps)} taps, peak |a| "
                                          f"{min(np.max(np.abs(a)) for _, _, a in taps):.0f}-"
                                          f"{max(np.max(np.abs(a)) for _, _, a in taps):.0f} m/s^2")

    progress.start("building the HFAM library (select, smooth, invert per grip, high-pass, taper, verify)")
    from devices.identify.modelset import load_model_set

    mset = load_model_set(out / "identify")
    models = [(f"identify/accel_g{g:g}N.json", m) for g, m in zip(mset.grip_N, mset.models["accel_m_s2"])]
    fs_rec, rec_taps = read_tap_csv(out / "recordings.csv")
    # the reader estimates fs from t_s steps (9999.99999...); the library must carry the servo rate exactly
    fs_rec = fs if abs(fs_rec - fs) < 1e-6 * fs else fs_rec
    bs = BuildSettings(n_velocities=min(s.library_velocities, len(rec_taps)), smooth_hz=s.smooth_hz,
                       peak_current_A=dev.info.current_peak_A, scale_to_limit=True)
    lib, rep = build_library(rec_taps, fs_rec, models, bs, force_per_amp_N_A=dev.info.force_per_amp_N_A,
                             log=None, provenance={"source_files": {"recordings": "recordings.csv",
                                                                    "models": [n for n, _ in models]},
                                                   "device": s.device, "built_by": "python -m renderer demo"})
    refine_note = ""
    if s.refine_iterations > 0:
        from devices.registry import make_device
        from stimuli.hfam_refine import RefineSettings, refine_library

        lines = []
        lib, hist = refine_library(lib, models, lambda: make_device(s.device, seed=s.seed),
                                   RefineSettings(iterations=s.refine_iterations, stop_time_s=s.tap_stop_time_s),
                                   bs, log=lines.append)
        (out / "library_refinement.txt").write_text("\n".join(lines) + "\n")
        refine_note = (f"; refined {s.refine_iterations}x on the sim over the firm wall: NRMSE median "
                       f"{hist[0]['median_nrmse']:.3f} -> {hist[-1]['median_nrmse']:.3f}, worst "
                       f"{hist[0]['worst_nrmse']:.3f} -> {hist[-1]['worst_nrmse']:.3f}")
    lib.save(out / "library.npz")
    (out / "library_verification.txt").write_text(format_verification(rep) + "\n")
    worst = max(rep.verification, key=lambda r: r["nrmse"])
    timings["library"] = progress.done(f"{len(lib.velocities_m_s)} velocities x {len(lib.grips_N)} grips; "
                                       f"forward-model check worst NRMSE {worst['nrmse']:.3f}"
                                       + (f"; {len(rep.scaled)} transient(s) scaled to the peak limit"
                                          if rep.scaled else "") + refine_note)
    return timings


def identify_grips(dev, s: PipelineSettings, out: Path, say) -> str:
    """Identify current -> handle acceleration at each grip level and save the model set (section 3.4.6).

    Uses the identification package step by step (swept-sine trials per grip,
    ETFE, automatic fit) instead of ``identify_device``, because the demo
    needs only the acceleration models (H_ha; HFAM does not use G_i) and
    draws one Bode figure of its own: this halves the cold-cache time.
    Writes ``model_set.json`` + one model JSON per grip and ``etfe.npz``
    (``f_hz``, ``H`` [grip, f], ``coherence`` [grip, f], ``grip_N``).

    Returns
    -------
    str
        A one-line summary of the fits.
    """
    from devices.identify.etfe import etfe
    from devices.identify.fit import FitOptions, fit_etfes
    from devices.identify.modelset import ModelSet
    from devices.identify.record import record_condition
    from devices.identify.sweep import SweepConfig

    sweep = SweepConfig(amplitude_A=s.sweep_amplitude_A, f_start_hz=s.sweep_band_hz[0],
                        f_end_hz=s.sweep_band_hz[1], duration_s=s.sweep_duration_s, fs_hz=dev.info.servo_rate_hz)
    curves, models = [], []
    for g in s.identify_grips_N:
        recs = record_condition(dev, sweep, float(g), s.identify_trials)
        curve = etfe(recs, "accel_m_s2", label=f"grip {g:g} N")
        res = fit_etfes([curve], FitOptions(), source=f"python -m renderer demo: {s.device}, grip {g:g} N, "
                                                        f"{len(recs)} swept-sine trials", grip_N=float(g))
        m = res.metrics
        say(f"grip {g:g} N: order {m['order']}, delay {m['delay_s'] * 1e3:.2f} ms, RMS {m['rms_db']:.2f} dB / "
            f"{m['rms_phase_deg']:.1f} deg over {res.model.band_hz[0]:.0f}-{res.model.band_hz[1]:.0f} Hz, "
            f"peak {20 * np.log10(np.max(np.abs(curve.H))):.1f} dB at {curve.f_hz[np.argmax(np.abs(curve.H))]:.0f} Hz")
        curves.append(curve)
        models.append(res.model)
    ModelSet(np.array([float(g) for g in s.identify_grips_N]), {"accel_m_s2": models}).save(out)
    f = curves[0].f_hz
    np.savez(out / "etfe.npz", f_hz=f, grip_N=np.array([c.grip_N for c in curves]),
             H=np.array([np.interp(f, c.f_hz, c.H.real) + 1j * np.interp(f, c.f_hz, c.H.imag) for c in curves]),
             coherence=np.array([np.interp(f, c.f_hz, c.coherence) for c in curves]))
    return f"{len(models)} acceleration models, orders {[m.order for m in models]}"


def _load(entry: Path, settings: PipelineSettings) -> Pipeline:
    from devices.identify.modelset import load_model_set
    from stimuli import HfamLibrary
    from stimuli.recordings import read_tap_csv

    manifest = json.loads((entry / "manifest.json").read_text())
    if manifest.get("settings") != settings.to_dict():
        raise ValueError("settings in manifest.json differ from the requested ones")
    mset = load_model_set(entry / "identify")
    lib = HfamLibrary.load(entry / "library.npz")
    _, taps = read_tap_csv(entry / "recordings.csv")
    return Pipeline(entry, mset, lib, lib.fs_hz, taps, True, manifest.get("timings_s", {}))
