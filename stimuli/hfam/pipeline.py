"""Device -> models + recorded taps -> HFAM library: the pipeline of thesis Figure 4.7 end to end.

Two uses:

* the shipped default library, built from the sim device's analytic models
  (:func:`build_sim_library`);
* the demo's pipeline (:func:`build_pipeline`): identify the device at several
  grip levels, record real taps with the motor off, build the library through
  the identified models (cached by :mod:`renderer.demo.cache`).

``python -m stimuli sim-library --out stimuli/libraries/wood_on_foam_sim.npz`` regenerates
the library the default catalog's HFAM samples use: the demo's pipeline on chapter 4's
sim device (:func:`build_sim_library`); ``make artefacts`` rebuilds it with every other
artefact derived from the sim and stamps it (``plumbing.artefacts``).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from devices.identify.modelset import load_model_set
from devices.identify.pipeline import IdentifyConfig, identify_device
from devices.identify.sweep import SweepConfig
from devices.recording import record_taps, write_tap_recording
from devices.registry import make_device
from devices.sim import SimDevice, TapTrajectory
from stimuli.recordings import read_tap_csv

from ..library import HfamLibrary
from ..recordings import Tap
from .build import build_library_limits, format_verification
from .refine import RefineSettings, recording_targets, refine_library
from .settings import TAP_STOP_TIME_S, BuildSettings, PipelineSettings  # noqa: F401 (re-exported: the pipeline's settings)

DEFAULT_VELOCITIES_M_S = (0.03, 0.05, 0.07, 0.09, 0.11, 0.14, 0.17, 0.2, 0.25, 0.3)
#: the pipeline's settings as run (:meth:`PipelineSettings.to_dict`), written into its folder: which device built it
SETTINGS_FILE = "pipeline_settings.json"
DEFAULT_GRIPS_N = (0.0, 2.5, 5.0, 7.5, 10.0)


def record_sim_taps(velocities_m_s=DEFAULT_VELOCITIES_M_S, sample: str = "wood_on_foam", grip_N: float = 2.0,
                    pre_s: float = 0.005, post_s: float = 0.1, device=None, seed: int = 0) -> tuple[float, list[Tap]]:
    """Tap the sim's real ``sample`` with the motor off, one tap per velocity.

    Returns
    -------
    fs_hz : float
    taps : list of Tap
        Measured handle acceleration from ``pre_s`` before to ``post_s`` after
        the first in-contact sample (t = 0 there), tagged with the true
        incoming handle speed.
    """

    dev = device if device is not None else SimDevice(seed=seed)
    dev.set_sample(sample)
    dev.motor_enabled = False
    fs = dev.info.servo_rate_hz
    n_pre, n_post = int(round(pre_s * fs)), int(round(post_s * fs))
    taps = []
    with dev:
        for i, v in enumerate(velocities_m_s):
            dev.set_user(TapTrajectory(float(v), n_taps=1), grip_N=grip_N)
            acc, speeds, contact_at = [], [], None
            while not dev.trajectory_done:
                dev.command(0.0)
                acc.append(dev.read().accel_m_s2)
                speeds.append(abs(dev.true_state()["handle_velocity_m_s"]) if contact_at is None else 0.0)
                if contact_at is None and dev.in_contact:
                    contact_at = len(acc) - 1
                if contact_at is not None and len(acc) > contact_at + n_post:
                    break
            if contact_at is None or contact_at < n_pre + 1:
                raise RuntimeError(f"sim tap at {v} m/s did not hit the {sample} sample")
            a = np.array(acc[contact_at - n_pre: contact_at + n_post + 1])
            t = (np.arange(a.size) - n_pre) / fs
            taps.append(Tap(i, float(speeds[contact_at - 1]), t, a))
    return fs, taps


def build_sim_library(out=None, settings: PipelineSettings | None = None, log=print):
    """The shipped default library: the demo's whole pipeline (Figure 4.7) on chapter 4's sim device.

    Identify the device at each grip level, record real taps on its ``wood_on_foam`` sample with the motor off,
    build the library through the identified models and refine it by playback on the sim
    (:func:`build_pipeline` with :class:`PipelineSettings`, default ``sim:onedof``, the section 4.4.3 testbed): the
    library ``python -m renderer demo`` builds and plays, which the study's HFAM samples then play on the same
    device. Built in a temporary folder; ``out`` receives ``library.npz``.

    Returns
    -------
    HfamLibrary
    """
    settings = settings or PipelineSettings()
    with tempfile.TemporaryDirectory(prefix="sim-library-") as tmp:
        build_pipeline(Path(tmp), settings, Progress(4, quiet=log is None))
        lib = HfamLibrary.load(Path(tmp) / "library.npz")
    if out is not None:
        lib.save(out)
    return lib


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
    arrives in depends on how long it has travelled.
    """
    return max(0.004, 0.04 * float(velocity_m_s))


def tap_trajectory_options(velocity_m_s: float, stop_time_s: float = TAP_STOP_TIME_S) -> dict:
    """Keyword arguments of the simulated hand's :class:`devices.sim.TapTrajectory` for one tap."""
    return {"press_depth_m": tap_press_depth_m(velocity_m_s, stop_time_s)}


class Progress:
    """Step-wise progress on stderr: ``[i/n] what ...`` then the step's lines and its wall time."""

    def __init__(self, n_steps: int, stream=None, quiet: bool = False):
        self.n = n_steps
        self.i = 0
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self._t0 = 0.0

    def start(self, what: str) -> None:
        """Begin step ``i`` of ``n``: print ``[i/n] what ...`` and start its clock."""
        self.i += 1
        self._t0 = time.perf_counter()
        self.say(f"[{self.i}/{self.n}] {what} ...", indent=False)

    def done(self, note: str = "") -> float:
        """End the step: print its wall time (and ``note``); returns the time in s."""
        dt = time.perf_counter() - self._t0
        self.say(f"done in {dt:.1f} s{(': ' + note) if note else ''}")
        return dt

    def say(self, msg: str, indent: bool = True) -> None:
        """Print one line (indented under the step unless ``indent`` is False), unless quiet."""
        if not self.quiet:
            print(("      " if indent else "") + msg, file=self.stream, flush=True)


def build_pipeline(out: Path, s: PipelineSettings, progress: Progress) -> dict:
    """Identify the device at every grip, record real taps, build the library into ``out`` (Figure 4.7).

    Writes ``identify/`` (model set, ``etfe_accel.npz``), ``recordings.csv``, ``library.npz`` and
    ``library_verification.txt``.

    Returns
    -------
    dict
        Wall time of each step (s): ``identify``, ``record``, ``library``.
    """

    timings = {}
    out.mkdir(parents=True, exist_ok=True)
    (out / SETTINGS_FILE).write_text(json.dumps(s.to_dict(), indent=1, default=str) + "\n")
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
    lib, rep, models, rec_taps, bs = build_from_folder(out, s, fs, dev.info.current_peak_A,
                                                       dev.info.force_per_amp_N_A)
    refine_note = ""
    if s.refine_iterations > 0:

        lines = []

        def say(msg: str) -> None:
            # the error per iteration goes to the progress lines and library_refinement.txt
            lines.append(msg)
            progress.say(msg)

        lib, hist = refine_library(lib, models, lambda: make_device(s.device, seed=s.seed),
                                   RefineSettings(iterations=s.refine_iterations, gain=s.refine_gain,
                                                  stop_time_s=s.tap_stop_time_s,
                                                  recording_iterations=s.refine_recording_iterations),
                                   bs, log=say, recordings_m_s2=recording_targets(lib, rec_taps, bs))
        (out / "library_refinement.txt").write_text("\n".join(lines) + "\n")
        first = [h for h in hist if h["target"] == "smoothed"]
        refine_note = (f"; refined {s.refine_iterations}x on the sim over the firm wall: NRMSE median "
                       f"{first[0]['median_nrmse']:.3f} -> {first[-1]['median_nrmse']:.3f}, worst "
                       f"{first[0]['worst_nrmse']:.3f} -> {first[-1]['worst_nrmse']:.3f}")
        second = [h for h in hist if h["target"] == "recording"]
        if len(second) > 1:
            refine_note += (f"; then {len(second) - 1}x towards the recordings: median "
                            f"{second[0]['median_nrmse']:.3f} -> {second[-1]['median_nrmse']:.3f}")
        ref = lib.metadata["refinement"]
        at_limit = ref["cells_at_limit"]
        # per grip, the slowest cell at the clip (the faster ones are, too, on a monotonic library)
        slowest = {}
        for v, g, _ in at_limit:
            slowest[g] = min(v, slowest.get(g, v))
        refine_note += (f"; {len(at_limit)} of {lib.currents_A.shape[0] * lib.currents_A.shape[1]} cells held at "
                        f"the refinement's {ref['current_limit_A']:.2f} A current limit (saturated"
                        + (", from " + ", ".join(f"{slowest[g]:.3f} m/s at {g:g} N" for g in sorted(slowest))
                           if at_limit else "") + "; library.npz metadata: refinement.cells_at_limit)")
    lib.save(out / "library.npz")
    (out / "library_verification.txt").write_text(format_verification(rep) + "\n")
    worst = max(rep.verification, key=lambda r: r["nrmse"])
    timings["library"] = progress.done(f"{len(lib.velocities_m_s)} velocities x {len(lib.grips_N)} grips; "
                                       f"forward-model check worst NRMSE {worst['nrmse']:.3f}"
                                       + (f"; {len(rep.scaled)} transient(s) scaled to the peak limit"
                                          if rep.scaled else "") + refine_note)
    return timings


def build_from_folder(out: Path, s: PipelineSettings, fs_hz: float, peak_current_A: float,
                      force_per_amp_N_A: float, settings: BuildSettings | None = None):
    """Build the open-loop library (section 4.4.1: select, smooth, invert, high-pass, taper) from a pipeline
    folder's identification (``identify/``) and recordings (``recordings.csv``).

    Parameters
    ----------
    out : Path
        The folder :func:`build_pipeline` wrote.
    s : PipelineSettings
    fs_hz : float
        The device's servo rate (Hz; the recordings' time column rounds it).
    peak_current_A : float
        Current limit of the transients (A); those above are scaled down to it (``BuildSettings.scale_to_limit``).
    force_per_amp_N_A : float
        The device's force constant (N/A).
    settings : BuildSettings or None
        None: the pipeline's own (``s.library_velocities``, ``s.smooth_hz``).

    Returns
    -------
    library : HfamLibrary
    report : BuildReport
    models : list of (name, ZpkModel)
    taps : list of Tap
        The recordings read back.
    settings : BuildSettings
        What was used.
    """
    ((lib, rep, bs),), models, rec_taps = build_from_folder_limits(out, s, fs_hz, [peak_current_A], force_per_amp_N_A,
                                                                settings)
    return lib, rep, models, rec_taps, bs


def build_from_folder_limits(out: Path, s: PipelineSettings, fs_hz: float, peak_currents_A, force_per_amp_N_A: float,
                             settings: BuildSettings | None = None):
    """:func:`build_from_folder` at each of several current limits, reading the folder and inverting each cell once
    (:func:`stimuli.hfam.build.build_library_limits`): each library is the one :func:`build_from_folder` builds at
    that limit.

    Returns
    -------
    builds : list of (HfamLibrary, BuildReport, BuildSettings)
        One per limit, in order.
    models : list of (name, ZpkModel)
    taps : list of Tap
    """
    mset = load_model_set(out / "identify")
    models = [(f"identify/accel_g{g:g}N.json", m) for g, m in zip(mset.grip_N, mset.models["accel_m_s2"])]
    fs_rec, rec_taps = read_tap_csv(out / "recordings.csv")
    # the reader estimates fs from t_s steps (9999.99999...); the library must carry the servo rate exactly
    fs_rec = fs_hz if abs(fs_rec - fs_hz) < 1e-6 * fs_hz else fs_rec
    bs = settings or BuildSettings(n_velocities=min(s.library_velocities, len(rec_taps)), smooth_hz=s.smooth_hz)
    each = [dataclasses.replace(bs, peak_current_A=float(limit), scale_to_limit=True) for limit in peak_currents_A]
    built = build_library_limits(rec_taps, fs_rec, models, each[0], [b.peak_current_A for b in each],
                                 force_per_amp_N_A=force_per_amp_N_A, log=None,
                                 provenance={"source_files": {"recordings": "recordings.csv",
                                                              "models": [n for n, _ in models]},
                                             "device": s.device, "built_by": "python -m renderer demo"})
    return [(lib, rep, b) for (lib, rep), b in zip(built, each)], models, rec_taps


def identify_grips(dev, s: PipelineSettings, out: Path, say) -> str:
    """Identify current -> handle acceleration at each grip level and save the model set (section 3.4.6).

    Runs :func:`devices.identify.pipeline.identify_device` with what HFAM needs: the acceleration
    models H_ha only (HFAM does not use G_i), no time-domain validation and no Bode figures of its
    own (the demo draws one). Writes what identification writes: ``model_set.json``, one model JSON
    per grip, ``recordings/``, ``report.json``/``.txt`` and ``etfe_accel.npz`` (``f_hz``, ``H`` [grip, f],
    ``coherence`` [grip, f], ``grip_N``).

    Parameters
    ----------
    dev : devices.base.Device
        The open device.
    s : PipelineSettings
        Sweep amplitude (A), band (Hz) and duration (s), grip levels (N) and trials per grip.
    out : Path
        Output folder (created).
    say : callable
        Receives one line per message.

    Returns
    -------
    str
        A one-line summary of the fits.
    """

    sweep = SweepConfig(amplitude_A=s.sweep_amplitude_A, f_start_hz=s.sweep_band_hz[0],
                        f_end_hz=s.sweep_band_hz[1], duration_s=s.sweep_duration_s, fs_hz=dev.info.servo_rate_hz)
    cfg = IdentifyConfig(grips_N=tuple(float(g) for g in s.identify_grips_N), trials=s.identify_trials,
                         sweep=sweep, validate=False, outputs=("accel_m_s2",), figures=False)
    report = identify_device(dev, cfg, out, log=say, device_spec=s.device, progress=False)
    orders = [row["accel"]["order"] for row in report["grips"] if "order" in row.get("accel", {})]
    return f"{len(orders)} acceleration models, orders {orders}"
