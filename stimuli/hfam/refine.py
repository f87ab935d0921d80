"""Iterative refinement of HFAM library transients by playback and correction (section 4.4).

One LTI inverse (eq. 4.6) cannot match an amplitude-dependent device: the
sim's hysteretic linkage is stiffer for small swings than for large ones, so
a transient inverted through one identified model comes out too weak or too
strong at other amplitudes. Refinement removes that error cell by cell with
an iterative learning update (the same procedure runs on hardware with
repeated taps by a person: tap the wall with the cell's transient at the
cell's velocity and grip, record the handle acceleration, correct, repeat)::

    e_j  = bandpass_20-1000Hz(d - y_j(t + L_j))   d: the library's target, y_j: measured after impact,
                                                 L_j: the lag (<= 1 ms) that best aligns them
    u_j+1 = clip(u_j + gain * invert(e_j, model(grip)), +/- peak current)

``invert`` is the builder's inverse (the identified model of the cell's grip),
so each step is the Newton-like correction of the LTI model and the
measurement supplies the nonlinear truth. The error is band-passed exactly as
the demo compares taps (2nd-order Butterworth run forwards and backwards).

Two stages: ``iterations`` passes towards the library's target (the recording
smoothed at the builder's 500 Hz), then, given the recordings themselves,
``recording_iterations`` passes towards the unsmoothed recording (what a
person's tap is compared with), each a line search: the correction smoothed at
each of ``candidate_smooth_hz`` is played and the best kept, halving the gain
up to ``backtracks`` times when none lowers the error. Where the current
allows (slow taps, grips >= 2 N) the wider corrections reproduce part of the
tile's impact click that the 500 Hz target has not. A transient that already
reaches the current limit takes, in the same passes, a step that respects the
limit instead: the box-constrained, regularised least-squares correction
through the cell's model (:func:`box_step`); adding an inverse and clipping it
throws away the part of the correction where the transient is at the limit,
and the next pass asks for it again. The sim plays it here with a
minimal proportional-wall loop (the renderer's convention: the transient's
first sample is commanded on the tick after the one that detects the crossing), the
person of ``devices.sim`` tapping at the cell's velocity (adjusted so the
measured incoming velocity matches) and grip.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

from devices.sim import TapTrajectory

from ..library import HfamLibrary
from ._fasttap import tap_on_wall
from .inversion import band_sos, forward_simulate, invert, nrmse_corr, sosfiltfilt
from .settings import MAX_SMOOTH_HZ, BuildSettings


@dataclass(frozen=True)
class RefineSettings:
    """Parameters of the refinement.

    Attributes
    ----------
    iterations : int
        Playback-and-correct passes (>= 1).
    gain : float
        Learning gain of the correction (0 < gain <= 1). At 0.8 the first pass overshoots in many of the
        demo's cells (median NRMSE 0.277 -> 0.365 on the sim; a cell made worse is undone and its gain
        halved, so passes are lost); 0.3 lowers it in every pass (docs/demo.md).
    wall_N_m : float
        Stiffness of the proportional wall the transients are refined over (the firm wall, Table 4.1).
    band_hz : (float, float)
        Band of the error and of the reported NRMSE (the demo's 20-1000 Hz).
    min_grip_N : float
        Grip levels below this are not refined (no hand holds the handle at 0 N).
    stop_time_s : float
        The simulated tap's stop time (renderer.demo's tap, 45 ms).
    hand : devices.sim.Person, "prescribed" or None
        The simulated user that taps (None: the device's default); the one that tapped the recordings.
    headroom : float
        Refined currents are clipped at ``headroom`` x the peak current (the wall's current adds to them).
        0.95: at the transient's peak, ~1 ms after impact, the wall's current is still small; on the demo's
        sim no refined tap reaches the 4 A limit with 0.95 (0.85: 0.2 m/s x 3 N NRMSE 0.39 instead of
        0.35; 1.0: every tap at 0.2-0.3 m/s but one clips, for 0.01-0.04 less NRMSE).
    band_order : int
        Order of the Butterworth band-pass of the error, run forwards and backwards: 2, as
        ``renderer.demo.metrics.bandpass`` compares taps. With 4 the error below ~25 Hz (the 1 N
        grip's, where the band edge of a 2nd-order filter still passes half of it) was invisible to the
        refinement: a refined 0.05 m/s x 1 N cell measured 0.20 with order 4 and 0.30 with order 2.
    recording_iterations : int
        Passes of the second stage, towards the unsmoothed recordings (only when ``refine_library`` is
        given them; 0: none).
    candidate_smooth_hz : tuple of float
        Second stage: the smoothing bandwidths (Hz, <= 1000) of the correction tried in each pass.
    backtracks : int
        Second stage: how many times the gain of the best candidate is halved and the tap repeated
        when no candidate lowers the error.
    limit_regularisation : float
        Second stage, transients at the current limit: weight of the correction's own energy in the
        constrained least-squares step, relative to the largest singular value of the band-passed model
        (0.01 / 0.03 / 0.1: 0.3 m/s x 3 N NRMSE 0.437 / 0.427 / 0.438 on the demo's sim).
    limit_out_of_band_weight : float
        Weight of the acceleration change outside the band in that step (:func:`_normal_equations`; 0:
        free, and the transients at 0.2-0.3 m/s gave up their low-frequency impulse for the band: HFAM
        over soft cut penetration 35 % instead of 51 %).
    limit_solver_iterations : int
        Projected-gradient (FISTA) iterations of that step.
    max_lag_s : float
        Before the error is taken, the measured response is shifted against the target by the lag within
        +/- ``max_lag_s`` that maximises their cross-correlation (0: no alignment; the demo's comparison
        searches its lag too, ``renderer.demo.runs.ALIGN``). The device's own
        delay (e.g. the 0.55 ms the identified 1 N model carries and the inverse discards) is then not
        read as a shape error: without it the correction tries to make the response earlier than the
        device can, and distorts the transient.
    """

    iterations: int = 3
    gain: float = 0.3
    wall_N_m: float = 680.0
    band_hz: tuple = (20.0, 1000.0)
    min_grip_N: float = 0.5
    stop_time_s: float = 0.045
    hand: object = None
    headroom: float = 0.95
    max_lag_s: float = 0.001
    band_order: int = 2
    recording_iterations: int = 4
    candidate_smooth_hz: tuple = (500.0, 700.0)
    backtracks: int = 2
    limit_regularisation: float = 0.03
    limit_out_of_band_weight: float = 1.0
    limit_solver_iterations: int = 150

    def __post_init__(self):
        if int(self.iterations) != self.iterations or self.iterations < 1:
            raise ValueError(f"RefineSettings: iterations must be a positive integer, got {self.iterations!r}")
        if not (0 < self.gain <= 1):
            raise ValueError(f"RefineSettings: gain must be in (0, 1], got {self.gain!r}")
        if not (self.wall_N_m >= 0 and math.isfinite(self.wall_N_m)):
            raise ValueError(f"RefineSettings: wall_N_m must be >= 0, got {self.wall_N_m!r}")
        if not (0 <= self.max_lag_s <= 0.005):
            raise ValueError(f"RefineSettings: max_lag_s must be in [0, 0.005] s, got {self.max_lag_s!r}")
        if int(self.band_order) != self.band_order or not 1 <= self.band_order <= 8:
            raise ValueError(f"RefineSettings: band_order must be an integer in [1, 8], got {self.band_order!r}")
        if int(self.recording_iterations) != self.recording_iterations or self.recording_iterations < 0:
            raise ValueError("RefineSettings: recording_iterations must be a non-negative integer, "
                             f"got {self.recording_iterations!r}")
        if not self.candidate_smooth_hz or any(not (0 < h <= MAX_SMOOTH_HZ) for h in self.candidate_smooth_hz):
            raise ValueError(f"RefineSettings: candidate_smooth_hz must be in (0, {MAX_SMOOTH_HZ:g}] Hz, "
                             f"got {self.candidate_smooth_hz!r}")
        if not (math.isfinite(self.limit_regularisation) and self.limit_regularisation >= 0):
            raise ValueError(f"RefineSettings: limit_regularisation must be >= 0, got {self.limit_regularisation!r}")
        if not (math.isfinite(self.limit_out_of_band_weight) and self.limit_out_of_band_weight >= 0):
            raise ValueError("RefineSettings: limit_out_of_band_weight must be >= 0, "
                             f"got {self.limit_out_of_band_weight!r}")
        if int(self.limit_solver_iterations) != self.limit_solver_iterations or self.limit_solver_iterations < 1:
            raise ValueError("RefineSettings: limit_solver_iterations must be a positive integer, "
                             f"got {self.limit_solver_iterations!r}")
        if int(self.backtracks) != self.backtracks or self.backtracks < 0:
            raise ValueError(f"RefineSettings: backtracks must be a non-negative integer, got {self.backtracks!r}")


def aligned(y: np.ndarray, d: np.ndarray, max_lag: int) -> np.ndarray:
    """``y`` shifted by the lag in [-max_lag, max_lag] samples that maximises its correlation with ``d``.

    A positive lag means ``y`` is late: the result is ``y[lag:]`` zero-padded at the end (and the other
    way for an early ``y``), so the result has ``d``'s length.
    """
    best, out = -math.inf, y
    for lag in range(-max_lag, max_lag + 1):
        z = np.zeros_like(y)
        if lag >= 0:
            z[:y.size - lag] = y[lag:]
        else:
            z[-lag:] = y[:y.size + lag]
        c = float(np.dot(z, d))
        if c > best:
            best, out = c, z
    return out


@dataclass(frozen=True)
class WallTap:
    """One simulated tap played by :func:`play_tap` (arrays on the library's time base).

    Attributes
    ----------
    accel_m_s2 : ndarray, shape (n,)
        Measured handle acceleration at ticks 1..n after the crossing tick (sample k at t = (k+1)/fs after
        impact); NaN if the tap never crossed.
    pre_accel_m_s2 : ndarray, shape (n_pre,)
        The acceleration read on the ``n_pre`` ticks up to and including the crossing tick, oldest first.
    command_A : ndarray, shape (n,)
        The current commanded on the same ticks as ``accel_m_s2`` (wall + transient, before the amplifier's
        clamp), A.
    v_in_m_s : float
        Incoming speed (least-squares slope of the encoder over the 5 ms before the crossing, m/s).
    """

    accel_m_s2: np.ndarray
    pre_accel_m_s2: np.ndarray
    command_A: np.ndarray
    v_in_m_s: float


def play_on_wall(device, current_A: np.ndarray, velocity_m_s: float, grip_N: float, wall_N_m: float,
                 stop_time_s: float = 0.045, hand=None) -> tuple[np.ndarray, float]:
    """One simulated tap on a proportional wall with a transient; the handle acceleration after impact.

    Parameters
    ----------
    device : devices.sim.SimDevice
        The sim (its default person taps; the motor is enabled here).
    current_A : ndarray, shape (n,)
        Transient current, sample k commanded k + 1 ticks after the tick that detects the crossing (as
        :class:`renderer.loop.ServoLoop` plays it).
    velocity_m_s, grip_N : float
        The person's planned tap speed (m/s) and grip (N).
    wall_N_m : float
        Proportional wall stiffness (eq. 4.1, F = -k x below the surface).
    stop_time_s : float
        When the plan stops after crossing the surface (s).
    hand : devices.sim.Person, "prescribed" or None
        The simulated user (None: the device's default); use the hand that tapped the recordings.

    Returns
    -------
    accel_m_s2 : ndarray, shape (n,)
        :attr:`WallTap.accel_m_s2`.
    v_in_m_s : float
        :attr:`WallTap.v_in_m_s`.
    """
    tap = play_tap(device, current_A, velocity_m_s, grip_N, wall_N_m, stop_time_s, hand)
    return tap.accel_m_s2, tap.v_in_m_s


def play_tap(device, current_A: np.ndarray, velocity_m_s: float, grip_N: float, wall_N_m: float,
             stop_time_s: float = 0.045, hand=None, sample: str = "placeholder", motor_on: bool = True,
             pre_s: float = 0.01) -> WallTap:
    """:func:`play_on_wall` with everything the HFAM scoring needs (``stimuli.hfam.scoring``).

    Parameters
    ----------
    device, current_A, velocity_m_s, grip_N, wall_N_m, stop_time_s, hand
        As :func:`play_on_wall`.
    sample : str
        The sim sample under the stylus (``placeholder``: none, a virtual wall; ``wood_on_foam``: the real
        sample, with ``motor_on=False`` and ``wall_N_m=0``, as the recordings are tapped).
    motor_on : bool
        The motor's enable (False: a real-sample tap with the motor off, section 4.4.1).
    pre_s : float
        How much acceleration before the crossing to keep (s, at least the 5 ms of the incoming-speed fit).

    Returns
    -------
    WallTap
    """

    fs = device.info.servo_rate_hz
    kf = device.info.force_per_amp_N_A
    n = int(current_A.size)
    traj = TapTrajectory(float(velocity_m_s), n_taps=1, approach_height_m=max(0.004, 0.04 * velocity_m_s),
                         press_depth_m=float(velocity_m_s) * stop_time_s / 1.5)
    device.set_sample(sample)
    device.set_user(traj, grip_N=float(grip_N), hand=hand)
    device.motor_enabled = bool(motor_on)
    n_fit = int(round(0.005 * fs))
    n_hist = max(n_fit, int(round(pre_s * fs)))
    acc = np.full(n, np.nan)
    cmd = np.full(n, np.nan)
    limit = int(math.ceil(traj.duration_s * fs))
    if callable(getattr(device, "fused_arrays", None)):
        # the same ticks in one compiled call (~15x faster: the refinement plays ~900 taps per demo build)

        arrays = device.fused_arrays(limit + 1)   # the tap's whole plan (a window that long: streamed plans)
        dv = device.fused_state()
        ring, ring_acc = np.empty(n_hist), np.empty(n_hist)
        try:
            k_imp, pushed = tap_on_wall(dv, *arrays, np.ascontiguousarray(current_A, dtype=float),
                                        float(wall_N_m), float(kf), limit, ring, acc, ring_acc, cmd)
        finally:
            device.fused_sync(dv)
        order = np.arange(pushed - min(pushed, n_hist), pushed) % n_hist   # the ring, oldest first
        h, h_acc = ring[order], ring_acc[order]
    else:
        k_imp, hist, hist_acc = _tap_loop(device, current_A, wall_N_m, kf, limit, acc, cmd)
        h, h_acc = np.array(hist[-n_hist:]), np.array(hist_acc[-n_hist:])
    pre = np.zeros(n_hist)
    pre[n_hist - h_acc.size:] = h_acc
    if k_imp < 0:
        return WallTap(acc, pre, cmd, math.nan)
    h = h[-n_fit:]
    t = np.arange(h.size) / fs
    v_in = -float(np.polyfit(t, h, 1)[0]) if h.size > 2 else math.nan
    return WallTap(acc, pre, cmd, v_in)


def _tap_loop(device, current_A, wall_N_m, kf, limit, acc, cmd):
    """:func:`play_tap`'s ticks through ``read()``/``command()`` (any device); returns the crossing tick
    (-1: none), the positions read up to it and the accelerations read with them."""
    n = int(current_A.size)
    hist, hist_acc = [], []
    k_imp = -1
    prev = device.read().position_m
    k = 0
    while k < limit:
        st = device.read()
        x = st.position_m
        if k_imp < 0:
            hist.append(x)
            hist_acc.append(st.accel_m_s2)
            if prev >= 0.0 > x:                         # the renderer: depth -x > 0
                k_imp = k
        i_cmd = (-wall_N_m * x / kf) if x < 0.0 else 0.0
        j = k - k_imp if k_imp >= 0 else -1
        if 1 <= j <= n:
            i_cmd += float(current_A[j - 1])           # the renderer's timing: sample 0 on the next tick
        if 0 <= j < n:
            cmd[j] = i_cmd
        device.command(i_cmd)
        if 0 <= j < n:
            acc[j] = device.read().accel_m_s2      # the state one period after the command
        if j >= n - 1:
            break
        prev = x
        k += 1
    return k_imp, hist, hist_acc


def refine_library(library: HfamLibrary, models: Sequence[tuple[str, object]], device_factory: Callable,
                   settings: RefineSettings = RefineSettings(), build_settings: BuildSettings = BuildSettings(),
                   log: Callable[[str], None] | None = None,
                   model_sets: Sequence[tuple[float, Sequence[tuple[str, object]]]] = (),
                   amplitude_ratio: float = 0.25,
                   recordings_m_s2: np.ndarray | None = None) -> tuple[HfamLibrary, list[dict]]:
    """Refine every (velocity, grip) transient of ``library`` by playback on the sim and correction.

    Parameters
    ----------
    library : HfamLibrary
        Built library with ``desired_accel_m_s2`` (the targets).
    models : sequence of (name, model)
        The per-grip models the library was inverted through (``model.grip_N`` must match the grips).
    device_factory : callable() -> devices.sim.SimDevice
        Makes the device to play on (a fresh, seeded one per cell keeps runs reproducible).
    settings : RefineSettings
    build_settings : BuildSettings
        The builder's settings (the inverse's added zeros and high-pass).
    log : callable(str) or None
        Receives one line per iteration (NRMSE median / worst over the refined cells).
    model_sets : sequence of (sweep_amplitude_A, models)
        Per-grip model sets, each identified at its swept-sine amplitude (A); if given, ``models`` is
        not used for the corrections. The correction of a cell is inverted through the set whose sweep
        amplitude is closest to ``amplitude_ratio`` x the cell's current peak: the device's current ->
        acceleration response is amplitude dependent (the hysteretic linkage, section 3.5.3) and an LTI
        model is right for one amplitude only; a correction through a model of the wrong amplitude turns
        the phase near the resonance and overshoots. Empty: every cell through ``models``.
    amplitude_ratio : float
        Sweep amplitude that matches a transient, as a fraction of its peak current (measured on the sim:
        the best sweep amplitude is about a quarter of the transient's peak, docs/demo.md).
        Measured on the demo's sim (0.25, 0.4, 0.6, 1 A sets): it lowers the 2-3 N cells at 0.2 m/s by
        0.03-0.05 NRMSE and raises the 1 N cells at 0.08-0.11 m/s by as much (docs/demo.md).
    recordings_m_s2 : ndarray, shape (n_velocities, n_t), or None
        The library's recordings on its time base, unsmoothed (:func:`recording_targets`): the target of
        the second stage (``settings.recording_iterations`` passes). None: no second stage.

    Returns
    -------
    library : HfamLibrary
        A new library with the refined currents (same targets, metadata gains ``refinement``).
    history : list of dict
        Per iteration (0 = before): ``{"iteration", "median_nrmse", "worst_nrmse", "min_corr", "cells",
        "target"}`` with ``cells`` a list of ``(velocity_m_s, grip_N, nrmse, corr)`` and ``target``
        ``smoothed`` (first stage) or ``recording`` (second stage, errors against the recordings).
    """

    if library.desired_accel_m_s2 is None:
        raise ValueError("refine_library: the library has no desired_accel_m_s2 (targets)")
    say = log or (lambda msg: None)
    fs = library.fs_hz
    sets = list(model_sets) if model_sets else [(math.nan, models)]
    by_grip = [(amp, {round(float(m.grip_N), 6): m for _, m in ms}) for amp, ms in sets]

    def model_for(grip_N: float, peak_A: float):
        # the set whose sweep amplitude is closest to amplitude_ratio x the cell's peak current
        _, table = min(by_grip, key=lambda s: abs(s[0] - amplitude_ratio * peak_A) if math.isfinite(s[0]) else 0.0)
        return table.get(round(grip_N, 6))
    # the demo's comparison filter (renderer.demo.metrics.bandpass): order 2, forwards and backwards
    sos = band_sos(fs, settings.band_hz, settings.band_order)
    smooth = signal.butter(build_settings.smooth_order, build_settings.smooth_hz, fs=fs, output="sos")
    cur = np.array(library.currents_A, dtype=float)
    n_v, n_g, n_t = cur.shape
    # headroom under the peak limit: the wall's own current adds to the transient in the renderer
    peak_A = build_settings.peak_current_A
    if peak_A is None:
        peak_A = device_factory().info.current_peak_A
    peak = settings.headroom * float(peak_A)
    pre, post = int(round(build_settings.pre_pad_s * fs)), int(round(build_settings.post_pad_s * fs))
    max_lag = int(round(settings.max_lag_s * fs))
    cells = [(i, j) for i in range(n_v) for j in range(n_g) if library.grips_N[j] >= settings.min_grip_N]
    v_plan = {c: float(library.velocities_m_s[c[0]]) for c in cells}
    # per cell: the best transient so far and its error; a step that makes a cell worse is undone and
    # that cell's gain halved (the amplitude-dependent device can make a full LTI step overshoot)
    best = {c: (math.inf, cur[c].copy(), math.nan) for c in cells}
    cell_gain = {c: settings.gain for c in cells}
    history = []
    for it in range(settings.iterations + 1):
        rows = []
        for (i, j) in cells:
            v_lib, g = float(library.velocities_m_s[i]), float(library.grips_N[j])
            dev = device_factory()
            y, v_in = play_on_wall(dev, cur[i, j], v_plan[(i, j)], g, settings.wall_N_m, settings.stop_time_s,
                                 settings.hand)
            if not np.all(np.isfinite(y)) or not math.isfinite(v_in) or v_in <= 0:
                rows.append((v_lib, g, math.nan, math.nan))
                continue
            v_plan[(i, j)] *= v_lib / v_in          # next time arrive at the cell's velocity
            d = library.desired_accel_m_s2[i]
            yb, db = sosfiltfilt(sos, y), sosfiltfilt(sos, d)
            yb = aligned(yb, db, max_lag)
            err, corr = nrmse_corr(yb, db)
            rows.append((v_lib, g, err, corr))
            if err < best[(i, j)][0]:
                best[(i, j)] = (err, cur[i, j].copy(), corr)
            else:
                cur[i, j] = best[(i, j)][1]
                cell_gain[(i, j)] *= 0.5
                continue
            if it == settings.iterations:
                continue
            model = model_for(g, float(np.max(np.abs(cur[i, j]))))
            if model is None:
                raise ValueError(f"refine_library: no model for grip {g:g} N")
            e = db - yb
            padded = np.concatenate([np.zeros(pre), e, np.zeros(post)])
            du, _ = invert(padded, model, fs, build_settings)
            # the correction smoothed like the target: the inverse's gain above the band (e.g. a 5 N model's
            # zero near 1.46 kHz) would otherwise build up currents the 20-1000 Hz error never sees
            du = sosfiltfilt(smooth, du)
            cur[i, j] = np.clip(cur[i, j] + cell_gain[(i, j)] * du[pre:pre + n_t], -peak, peak)
        if it == settings.iterations:
            # the library keeps each cell's best transient; report those
            rows = [(float(library.velocities_m_s[c[0]]), float(library.grips_N[c[1]]), best[c][0], best[c][2])
                    for c in cells]
            for c in cells:
                cur[c] = best[c][1]
        _record(history, it, rows, "smoothed", settings, say)
    if recordings_m_s2 is not None and settings.recording_iterations > 0:
        recs = np.asarray(recordings_m_s2, dtype=float)
        if recs.shape != library.desired_accel_m_s2.shape:
            raise ValueError(f"refine_library: recordings_m_s2 has shape {recs.shape}, the library's targets "
                             f"{library.desired_accel_m_s2.shape}")

        def model_of(grip_N: float, peak_now_A: float):
            # as in the first stage: with model_sets, the set whose sweep amplitude suits the transient
            m = model_for(grip_N, peak_now_A)
            if m is None:
                raise ValueError(f"refine_library: no model for grip {grip_N:g} N")
            return m
        # a transient already at the current limit cannot take the wider corrections (they are clipped: on
        # the demo's sim 0.2 m/s x 3 N went 0.350 -> 0.373 against the real tap while its error against the
        # recording fell); those cells take the constrained step (box_step) instead
        open_cells = [c for c in cells if np.max(np.abs(cur[c])) < AT_LIMIT * peak]
        _second_stage(library, cur, recs, open_cells, cells, v_plan, model_of, device_factory, settings,
                      build_settings, sos, peak, history, say)
    meta = dict(library.metadata)
    meta["refinement"] = {"iterations": settings.iterations, "gain": settings.gain, "wall_N_m": settings.wall_N_m,
                          "recording_iterations": settings.recording_iterations if recordings_m_s2 is not None else 0,
                          "current_limit_A": peak, "cells_at_limit": cells_at_limit(cur, library, peak),
                          "history": [{k: v for k, v in h.items() if k != "cells"} for h in history]}
    lib = HfamLibrary(library.velocities_m_s, library.grips_N, cur, fs, library.force_per_amp_N_A,
                      gain=library.gain, max_extrapolation=library.max_extrapolation, metadata=meta,
                      desired_accel_m_s2=library.desired_accel_m_s2, source=library.source)
    return lib, history


#: a transient whose peak |current| is within 1 % of the refinement's clip is at it (saturated)
AT_LIMIT = 0.99


def cells_at_limit(currents_A: np.ndarray, library: HfamLibrary, limit_A: float) -> list:
    """Cells whose refined transient reaches the refinement's current clip (section 4.4.3's saturation).

    The refinement clips every correction at ``limit_A`` (``RefineSettings.headroom`` x the peak current), so
    the renderer's amplifier limit is never hit by these transients and a demo counts no clipped tap; a cell
    held at the clip is saturated all the same (its transient is flattened where the target asks for more).

    Parameters
    ----------
    currents_A : ndarray, shape (n_velocities, n_grips, n_t)
        Refined currents (A).
    library : HfamLibrary
        Gives the cells' velocities (m/s) and grips (N).
    limit_A : float
        The refinement's current clip (A).

    Returns
    -------
    list of [velocity_m_s, grip_N, peak_A]
        The cells whose peak |current| is within 1 % of ``limit_A``, in library order.
    """
    peaks = np.max(np.abs(currents_A), axis=-1)
    return [[float(library.velocities_m_s[i]), float(library.grips_N[j]), float(peaks[i, j])]
            for i in range(peaks.shape[0]) for j in range(peaks.shape[1]) if peaks[i, j] >= AT_LIMIT * limit_A]


def _record(history: list, it: int, rows: list, target: str, settings: RefineSettings, say) -> None:
    """Append one iteration's summary to ``history`` and log it."""
    errs = np.array([r[2] for r in rows], dtype=float)
    cors = np.array([r[3] for r in rows], dtype=float)
    rec = {"iteration": it, "median_nrmse": float(np.nanmedian(errs)), "worst_nrmse": float(np.nanmax(errs)),
           "min_corr": float(np.nanmin(cors)), "cells": rows, "target": target}
    history.append(rec)
    say(f"refinement iteration {it}: NRMSE median {rec['median_nrmse']:.3f}, worst "
        f"{rec['worst_nrmse']:.3f}, min correlation {rec['min_corr']:.3f} over {len(rows)} cells "
        f"(wall {settings.wall_N_m:g} N/m, target: {target})")


def _second_stage(library: HfamLibrary, cur: np.ndarray, recs: np.ndarray, open_cells: list, cells: list,
                  v_plan: dict, model_of: Callable, device_factory: Callable, settings: RefineSettings,
                  build_settings: BuildSettings, sos: np.ndarray, peak: float, history: list, say) -> None:
    """Refine ``cur[cells]`` in place towards the unsmoothed recordings ``recs``.

    In each pass a cell of ``open_cells`` inverts its error (aligned as in the first stage) through its
    grip's model, smooths the correction at every ``settings.candidate_smooth_hz``, plays each and keeps
    the best if it lowers the error; otherwise the best candidate's step is halved and played again, up
    to ``settings.backtracks`` times, and the cell's gain halved for the next pass. The other cells (at
    the current limit) play the constrained step :func:`box_step` and keep it if it lowers the error
    (else their gain is halved).
    """

    fs = library.fs_hz
    n_t = cur.shape[2]
    pre, post = int(round(build_settings.pre_pad_s * fs)), int(round(build_settings.post_pad_s * fs))
    max_lag = int(round(settings.max_lag_s * fs))
    smooth = [signal.butter(build_settings.smooth_order, h, fs=fs, output="sos") for h in settings.candidate_smooth_hz]
    targets = [sosfiltfilt(sos, d) for d in recs]

    def measure(c: tuple, u: np.ndarray) -> tuple[float, float, np.ndarray]:
        i, j = c
        y, v_in = play_on_wall(device_factory(), u, v_plan[c], float(library.grips_N[j]), settings.wall_N_m,
                               settings.stop_time_s, settings.hand)
        if not np.all(np.isfinite(y)) or not math.isfinite(v_in) or v_in <= 0:
            return math.inf, math.nan, np.zeros(n_t)
        v_plan[c] *= float(library.velocities_m_s[i]) / v_in
        yb = aligned(sosfiltfilt(sos, y), targets[i], max_lag)
        err, corr = nrmse_corr(yb, targets[i])
        return err, corr, targets[i] - yb

    state = {c: [*measure(c, cur[c]), settings.gain] for c in cells}

    def rows() -> list:
        return [(float(library.velocities_m_s[c[0]]), float(library.grips_N[c[1]]), state[c][0], state[c][1])
                for c in cells]
    it0 = history[-1]["iteration"] + 1 if history else 0
    _record(history, it0, rows(), "recording", settings, say)
    open_set = set(open_cells)

    def keep_if_better(c: tuple, u: np.ndarray, err: float, corr: float, e: np.ndarray, err0: float,
                       gain: float) -> None:
        # a pass that does not lower the cell's error is undone and the cell's gain halved
        if err < err0:
            cur[c] = u
            state[c][:3] = [err, corr, e]
        else:
            state[c][3] = 0.5 * gain
    # per model: the constrained step's operator (FFT kernels)
    normal: dict = {}
    for it in range(1, settings.recording_iterations + 1):
        for c in cells:
            err0, _, e0, gain = state[c]
            if not math.isfinite(err0):
                continue
            model = model_of(float(library.grips_N[c[1]]), float(np.max(np.abs(cur[c]))))
            if c not in open_set:
                if id(model) not in normal:
                    normal[id(model)] = _normal_equations(model, fs, n_t, sos, settings.limit_regularisation,
                                                          settings.limit_out_of_band_weight)
                du_box = box_step(*normal[id(model)], gain * e0, cur[c], peak, settings.limit_solver_iterations)
                u = np.clip(cur[c] + du_box, -peak, peak)
                keep_if_better(c, u, *measure(c, u), err0, gain)
                continue
            du_raw, _ = invert(np.concatenate([np.zeros(pre), e0, np.zeros(post)]), model, fs, build_settings)
            trials = []
            for sm in smooth:
                du = sosfiltfilt(sm, du_raw)[pre:pre + n_t]
                u = np.clip(cur[c] + gain * du, -peak, peak)
                trials.append((*measure(c, u), u, du))
            err, corr, e, u, du = min(trials, key=lambda t: t[0])
            step = gain
            for _ in range(settings.backtracks):
                if err < err0:
                    break
                step *= 0.5
                u = np.clip(cur[c] + step * du, -peak, peak)
                err, corr, e = measure(c, u)
            keep_if_better(c, u, err, corr, e, err0, gain)
        _record(history, it0 + it, rows(), "recording", settings, say)


def recording_targets(library: HfamLibrary, taps: Sequence, build_settings: BuildSettings) -> np.ndarray:
    """The library's recordings, unsmoothed, on its time base (the second stage's targets), m/s^2.

    Sample k is the recording at t = (k + 1)/fs - ``onset_delay_s`` after impact, as the builder's
    ``desired_accel_m_s2`` (which is the same recording smoothed at ``smooth_hz``).

    Parameters
    ----------
    library : HfamLibrary
        Built by :func:`stimuli.hfam.build_library` (its metadata names the selected taps).
    taps : sequence of stimuli.recordings.Tap
        The recordings it was built from.
    build_settings : BuildSettings

    Returns
    -------
    ndarray, shape (n_velocities, n_t)
    """
    fs = library.fs_hz
    n_t = library.currents_A.shape[2]
    lead = int(round(build_settings.onset_delay_s * fs))
    t = (np.arange(n_t) + 1 - lead) / fs
    by_id = {tp.tap: tp for tp in taps}
    selected = library.metadata.get("selection", {}).get("selected")
    if selected is None or len(selected) != len(library.velocities_m_s):
        raise ValueError("recording_targets: the library's metadata does not name its selected taps")
    return np.array([np.interp(t, by_id[sel["tap"]].t_s, by_id[sel["tap"]].accel_m_s2, left=0.0, right=0.0)
                     for sel in selected])


def _normal_equations(model, fs_hz: float, n_t: int, sos: np.ndarray, regularisation: float,
                      out_of_band_weight: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The constrained step's operator for one model, in the frequency domain.

    ``A`` (current -> band-passed acceleration) is the model's impulse response followed by the error's
    zero-phase band-pass: on an FFT grid of ``n_fft`` >= 8 x ``n_t`` points (room for the model's and the
    filter's tails) it is the kernel ``K = |B|^2 H``. The normal operator ``A^T A + lam^2`` is then
    ``QK = |K|^2 + w |(1 - |B|^2) H|^2 + lam^2``, with ``lam^2 = regularisation^2 x max |K|^2`` and ``w`` =
    ``out_of_band_weight``: the middle term keeps the step from changing the acceleration outside the band,
    which the error does not see, in particular the transient's net early impulse below 20 Hz that cuts
    penetration (without it the cut over the soft wall fell from 0.55 to 0.35 on the demo's sim). FFTs instead of n_t x n_t matrices:
    the products of a 949-sample matrix with a vector are memory bound and call a multi-threaded BLAS,
    which on a loaded two-core machine waited ~4x longer for its second thread than it computed.

    Returns
    -------
    K : ndarray, complex, shape (n_fft // 2 + 1,)
    QK : ndarray, real, shape (n_fft // 2 + 1,)
        The normal operator.
    L : float
        Step bound, ``max QK``.
    n_fft : int
    """

    n_fft = 1 << int(math.ceil(math.log2(8 * n_t)))
    impulse = np.zeros(n_fft)
    impulse[0] = 1.0
    h = forward_simulate(model, impulse, fs_hz)
    _, b = signal.sosfreqz(sos, worN=n_fft // 2 + 1, whole=False, fs=fs_hz)
    H = np.fft.rfft(h)
    K = np.abs(b) ** 2 * H
    top = float(np.max(np.abs(K) ** 2))
    lam2 = regularisation ** 2 * top
    QK = np.abs(K) ** 2 + out_of_band_weight * np.abs((1.0 - np.abs(b) ** 2) * H) ** 2 + lam2
    return K, QK, float(np.max(QK)), n_fft


def box_step(K: np.ndarray, QK: np.ndarray, L: float, n_fft: int, error: np.ndarray, current_A: np.ndarray,
             peak_A: float, iterations: int = 150) -> np.ndarray:
    """The correction ``du`` minimising ``|A du - error|^2 + w |A_out du|^2 + lam^2 |du|^2``, ``|current + du| <= peak``.

    Solved by accelerated projected gradient (FISTA) from ``du = 0``, ``A`` applied as the kernel ``K`` of
    :func:`_normal_equations` (the error is compared over the FFT grid, i.e. with its tails after the
    window; they are ~0 for a decayed transient).

    Parameters
    ----------
    K, QK, L, n_fft
        From :func:`_normal_equations`.
    error : ndarray, shape (n_t,)
        The band-passed acceleration error to remove (gain included), m/s^2.
    current_A : ndarray, shape (n_t,)
        The transient now, A.
    peak_A : float
        Current limit of the transient, A.
    iterations : int

    Returns
    -------
    ndarray, shape (n_t,)
        The correction, A (``current_A + du`` within +/- ``peak_A``).
    """
    n = current_A.size
    q = np.fft.irfft(np.conj(K) * np.fft.rfft(error, n_fft), n_fft)[:n]    # A^T error
    lo, hi = -peak_A - current_A, peak_A - current_A
    x = np.clip(np.zeros(n), lo, hi)
    z, t = x.copy(), 1.0
    for _ in range(int(iterations)):
        grad = np.fft.irfft(QK * np.fft.rfft(z, n_fft), n_fft)[:n] - q
        x_new = np.clip(z - grad / L, lo, hi)
        t_new = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
        z = x_new + (t - 1.0) / t_new * (x_new - x)
        x, t = x_new, t_new
    return x
