"""Renderings tapped by the simulated user, and the per-tap metrics of the demo (sections 4.4.3, 4.5.5).

Each rendering is a proportional wall (Table 4.1 stiffnesses), optionally with
an event-based transient, or the real ``wood_on_foam`` sample with the motor
off. The simulated hand taps it once per (velocity, grip) condition: a fresh
single-tap :class:`devices.sim.TapTrajectory` per tap (the sim places the
device at rest at the start of each trajectory), so every tap starts from the
same state whatever ran before it, and the run stops as soon as the contact
is over instead of simulating the lift and pause.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from devices.sim import TapTrajectory
from stimuli import DecayingSinusoid, Pulse
from stimuli.hfam.pipeline import TAP_STOP_TIME_S, tap_approach_height_m, tap_trajectory_options

from ..config import RendererConfig
from ..loop import ServoLoop
from . import metrics as dm
from .renderings import REAL, RENDERINGS, Rendering  # noqa: F401 (re-exported: runs.REAL, runs.RENDERINGS)

PRE_S = 0.01    # contact window before impact (s)
POST_S = 0.1    # ... and after it: the HFAM transient's 100 ms (section 4.4.2)
SETTLE_S = 0.3   # at most this long after impact (the hand's push-through, hence max penetration, is over)


def approach_height_m(velocity_m_s: float) -> float:
    """Start height of the simulated hand (:func:`stimuli.hfam.pipeline.tap_approach_height_m`, m).

    Enough for the handle to reach the hand's speed after the 20 ms ramp and
    for the renderer's 10 ms incoming-velocity window, without simulating
    long free flights; the recordings use the same height.
    """
    return tap_approach_height_m(velocity_m_s)


class FixedGripTransient:
    """An HFAM library played as if the grip were always ``grip_N`` (grip compensation switched off).

    Implements the stimuli ``Transient`` protocol by delegating to the library.
    """

    name = "hfam_fixed_grip"

    def __init__(self, library, grip_N: float):
        self.library = library
        self.grip_N = float(grip_N)

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """The library's transient for ``v_in_m_s`` at the fixed grip (``grip_N`` is ignored), N, shape (n,)."""
        return self.library.waveform(v_in_m_s, self.grip_N, fs_hz)

    def max_samples(self, fs_hz: float) -> int:
        """The library's transient length at ``fs_hz``."""
        return self.library.max_samples(fs_hz)

    def check_device(self, info, fs_hz: float) -> None:
        """The library's device check (ValueError if it cannot play on ``info`` at ``fs_hz``)."""
        self.library.check_device(info, fs_hz)

    def current_into(self, v_in_m_s: float, grip_N: float, out) -> int:
        """Write the fixed-grip transient's current (A) for ``v_in_m_s`` into ``out``; returns its length."""
        return self.library.current_into(v_in_m_s, self.grip_N, out)


def make_transient(r: Rendering, library=None, fixed_grip_N: float = 2.0):
    """The stimuli transient object of a rendering (None for plain walls and the real sample)."""
    if r.transient == "none":
        return None
    if r.transient == "pulse":
        return Pulse()
    if r.transient == "sinusoid":
        return DecayingSinusoid()
    if library is None:
        raise ValueError(f"rendering {r.name!r} needs an HFAM library")
    if r.transient == "hfam":
        return library
    if r.transient == "hfam_fixed_grip":
        return FixedGripTransient(library, fixed_grip_N)
    raise ValueError(f"rendering {r.name!r}: unknown transient {r.transient!r}")


@dataclass
class TapTrace:
    """One tap on one rendering: the contact window and the event summary.

    Attributes
    ----------
    rendering : str
    velocity_m_s : float
        Commanded (trajectory) tap speed.
    grip_N : float
        Commanded grip.
    v_in_m_s : float
        Incoming velocity the renderer estimated at the crossing.
    accel : ndarray, shape (n,)
        Handle acceleration window (``PRE_S`` before to ``POST_S`` after impact), m/s^2.
    current : ndarray, shape (n,)
        Commanded current (proportional + transient, after saturation) over the same window, A.
    penetration_m : float
        Maximum penetration of the event.
    clipped : bool
        The event hit the amplifier limit.
    found : bool
        False if the tap produced no contact event (then the numbers are NaN).
    metrics : dict
        Filled by :func:`add_metrics`.
    transient_current : ndarray or None
        The transient channel alone (before saturation) over the window, A.
    """

    rendering: str
    velocity_m_s: float
    grip_N: float
    v_in_m_s: float
    accel: np.ndarray
    current: np.ndarray
    penetration_m: float
    clipped: bool
    found: bool = True
    metrics: dict = field(default_factory=dict)
    transient_current: np.ndarray | None = None


def tap_sim(device, rendering: Rendering, transient, velocity_m_s: float, grip_N: float, fs_hz: float,
            stop_time_s: float = TAP_STOP_TIME_S, hand=None) -> TapTrace:
    """Let the simulated hand tap ``rendering`` once and cut the contact window.

    Parameters
    ----------
    device : devices.sim.SimDevice
        Open sim device (reused between taps; its sample and user are set here).
    transient : stimuli transient or None
    velocity_m_s, grip_N : float
        Tap speed (m/s) and grip (N) of the simulated hand.
    stop_time_s : float
        How long after crossing the surface the hand's desired position comes
        to rest (s): it aims :func:`~renderer.demo.cache.tap_press_depth_m`
        below the surface.
    hand : devices.sim.ReactiveHand or None
        None: the default simulated hand (tied to its trajectory); a
        ``ReactiveHand``: hand mass, muscle impedance and contact reflex.
    """

    device.set_sample(rendering.sample)
    traj = TapTrajectory(float(velocity_m_s), n_taps=1, approach_height_m=approach_height_m(velocity_m_s),
                         **tap_trajectory_options(velocity_m_s, stop_time_s))
    if hand is None:
        device.set_user(traj, grip_N=float(grip_N))
    else:
        device.set_user(traj, grip_N=float(grip_N), hand=hand)
    cfg = RendererConfig(stiffness_N_m=rendering.stiffness_N_m, motor_enabled=not rendering.is_real,
                         log_capacity_s=traj.duration_s + 0.01)
    loop = ServoLoop(device, cfg, transient=transient)
    state = device.read()
    track = {"t_end": math.inf, "t_min": math.inf, "pen": 0.0}

    def until(lp) -> bool:
        # stop once the transient is over and the hand's push-through has clearly passed its deepest point
        if lp.events and track["t_end"] == math.inf:
            t_imp = lp.events[0].t_s
            track["t_end"], track["t_min"] = t_imp + SETTLE_S, t_imp + POST_S
        pen = -state.position_m
        if pen > track["pen"]:
            track["pen"] = pen
        t = lp.time_s
        return (t >= track["t_end"] or device.trajectory_done
                or (t >= track["t_min"] and pen < 0.7 * track["pen"]))

    res = loop.run(until=until, max_ticks=int(math.ceil(traj.duration_s * fs_hz)) + 10)
    n = int(round((PRE_S + POST_S) * fs_hz))
    if not res.events:
        nan = np.full(n, np.nan)
        return TapTrace(rendering.name, velocity_m_s, grip_N, math.nan, nan, nan, math.nan, False, found=False,
                        transient_current=nan)
    ev = res.events[0]
    t = res.log["t_s"]
    acc = dm.cut_window(t, res.log["accel_m_s2"], ev.t_s, fs_hz, PRE_S, POST_S)
    cur = dm.cut_window(t, res.log["current_A"], ev.t_s, fs_hz, PRE_S, POST_S)
    i_tr = dm.cut_window(t, res.log["force_transient_N"], ev.t_s, fs_hz, PRE_S, POST_S) / device.info.force_per_amp_N_A
    return TapTrace(rendering.name, float(velocity_m_s), float(grip_N), float(ev.incoming_velocity_m_s), acc, cur,
                    float(ev.max_penetration_m), bool(ev.clipped), transient_current=i_tr)


def add_metrics(trace: TapTrace, reference: np.ndarray | None, fs_hz: float) -> TapTrace:
    """Fill ``trace.metrics``: peak accel, dominant frequency and, against ``reference``, NRMSE/correlation."""
    if not trace.found:
        trace.metrics = {"peak_accel_m_s2": math.nan, "dominant_freq_hz": math.nan, "nrmse": math.nan,
                         "correlation": math.nan, "lag_ms": math.nan}
        return trace
    # the window's band-pass serves both its frequency and the comparison, the reference's every tap at its speed
    x_bp = dm.bandpass(trace.accel, fs_hz)
    peak, f_dom = dm.contact_metrics(trace.accel, fs_hz, PRE_S, POST_S, x_bp=x_bp)
    m = {"peak_accel_m_s2": peak, "dominant_freq_hz": f_dom, "nrmse": math.nan, "correlation": math.nan,
         "lag_ms": math.nan}
    if reference is not None and np.all(np.isfinite(reference)):
        c = dm.compare(trace.accel, reference, fs_hz, PRE_S, POST_S, **ALIGN, x_bp=x_bp,
                       ref_bp=_reference_bandpass(np.asarray(reference, dtype=float).tobytes(), float(fs_hz)))
        m.update(nrmse=c.nrmse, correlation=c.correlation, lag_ms=c.lag_samples / fs_hz * 1e3)
    trace.metrics = m
    return trace


@lru_cache(maxsize=32)
def _reference_bandpass(reference: bytes, fs_hz: float) -> np.ndarray:
    """``dm.bandpass`` of a reference window given by its float64 bytes (the demo compares every rendering's taps
    at a speed with the same reference), read-only."""
    out = dm.bandpass(np.frombuffer(reference, dtype=np.float64), fs_hz)
    out.flags.writeable = False
    return out


#: alignment search of the comparison (see demo_metrics): the rendered trace may lag the real one by up to
#: 3 ms (the HFAM builder plays its transients 2 ms late on purpose, BuildSettings.onset_delay_s, so the
#: non-causal start of the inverse is not cut; a few ms are imperceptible) and lead it by up to 0.5 ms
#: (encoder quantization of the detected crossing)
ALIGN = {"min_lag_s": -0.5e-3, "max_lag_s": 3e-3}
