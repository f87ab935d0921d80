"""The apparatus: device, servo loops per sample, homing, and (sim mode) the simulated hand and samples.

One :class:`renderer.ServoLoop` per catalog sample is created once and reused
for every attempt (no re-preparation or re-jitting per attempt); the winding
temperature of the thermal model is carried from loop to loop.

Saturation (section 4.5.3): for virtual samples, the amplifier limit was hit
during an event (``ContactEvent.clipped``, or the device's CLIPPING status bit
seen during the window). For real samples the motor is off, so the check is
the thesis' "forces known to exceed the amplifier's current limit (had the
controller been in use)": the measured contact force exceeds
``force_per_amp_N_A * current_amplifier_A``. The sim device supplies the
contact force through ``true_state()``; a hardware device supplies it as
``state.extra["contact_force_N"]`` (a force sensor under the stand). A device
with neither cannot detect real-sample saturation, which session.json records
(``real_saturation_detection``).
"""

from __future__ import annotations

import numpy as np

from devices.sim import DEFAULT_PERSON, ScriptedTrajectory, TapTrajectory
from renderer import RendererConfig, ServoLoop
from renderer.homing import SAFETY_STOPS, HomingConfig, HomingController

from .rater import REFERENCE_SAMPLE, Reference, tap_features

# full-rate channels kept in the per-attempt trace files (float32 except t_s)
TRACE_CHANNELS = ("position_m", "force_prop_N", "force_transient_N", "current_A", "accel_m_s2", "grip_N")
REFERENCE_VELOCITIES_M_S = (0.04, 0.06, 0.08, 0.10, 0.13, 0.17, 0.22, 0.28)


class ServoStopped(RuntimeError):
    """The servo loop or homing stopped itself (watchdog, invalid sensors, disconnect, an unstable or run-away
    homing PD); the output is already zero."""


class TapResult:
    """Outcome of one tapping window."""

    def __init__(self, events, log, window_start_s, saturated, max_contact_force_N, fs_hz, sample,
                 timing=None) -> None:
        self.events = events
        self.velocities = [float(e.incoming_velocity_m_s) for e in events]
        self.penetrations = [float(e.max_penetration_m) for e in events]
        self.window_start_s = window_start_s
        self.saturated = saturated
        self.max_contact_force_N = max_contact_force_N
        self.fs_hz = fs_hz
        self.log = log
        self.sample = sample
        self.timing = timing or {}

    @property
    def trace(self) -> dict:
        """Arrays for the per-attempt trace file (see docs/study.md)."""
        log = self.log
        out = {"t_s": np.asarray(log["t_s"], np.float64)}
        for name in TRACE_CHANNELS:
            out[name] = np.asarray(log[name], np.float32)
        out["clipped"] = np.asarray(log["clipped"], np.uint8)
        out["event_t_s"] = np.array([e.t_s for e in self.events], np.float64)
        out["event_incoming_velocity_m_s"] = np.array(self.velocities, np.float64)
        out["event_max_penetration_m"] = np.array(self.penetrations, np.float64)
        out["event_clipped"] = np.array([bool(e.clipped) for e in self.events], bool)
        objects = [getattr(e, "object", "") for e in self.events]
        if any(objects):   # the 3-D renderer's events name the surface touched (study.session.apparatus3)
            out["event_object"] = np.array(objects)
        out["fs_hz"] = np.float64(self.fs_hz)
        out["window_start_s"] = np.float64(self.window_start_s if self.window_start_s is not None else np.nan)
        out["max_contact_force_N"] = np.float64(self.max_contact_force_N)
        out["sample"] = np.array(self.sample)
        for key in ("realtime", "period_p50_us", "period_p99_us", "period_max_us", "overruns"):
            if key in self.timing:
                out[f"timing_{key}"] = np.float64(self.timing[key])
        return out


def link_summary(device) -> str:
    """Format a device's link counters as one line (see :meth:`Apparatus.link_status`).

    Parameters
    ----------
    device : devices.base.Device
        An open device; ``link_stats()`` is used when it has one.

    Returns
    -------
    str
        The status line.
    """
    stats_fn = getattr(device, "link_stats", None)
    if stats_fn is None:
        return "sim (no link)" if device.info.simulated else f"{type(device).__name__} (no link counters)"
    st = stats_fn()
    faults = {"lost": st.get("losses", 0), "CRC": st.get("crc_errors", 0),
              "malformed": st.get("malformed_frames", 0), "timeouts": st.get("timeouts", 0),
              "watchdog": st.get("watchdog_trips", 0)}
    p99 = st.get("rtt_p99_s")
    rtt = "rtt p99 -" if p99 is None else f"rtt p99 {p99 * 1e3:.1f} ms"
    if not any(faults.values()):
        return f"ok · {rtt}"
    return "FAULTS: " + ", ".join(f"{n} {k}" for k, n in faults.items()) + f" · {rtt}"


class Apparatus:
    """Device + renderer loops + homing for a catalog.

    Parameters
    ----------
    device : devices.base.Device
        Opened device.
    catalog : list of stimuli.CatalogSample
    protocol : study.session.config.ProtocolConfig
    library_dir : path or None
        Passed to ``CatalogSample.make_transient``.
    sim_participant : study.session.participants.SimulatedParticipant or None
        Drives the sim device's hand (sim devices only).
    realtime : bool or None
        Pace the tapping window to wall-clock time (None: hardware yes, sim no).
    """

    def __init__(self, device, catalog, protocol, library_dir=None, sim_participant=None, realtime=None) -> None:
        self.device = device
        self.realtime = realtime   # None: the renderer's default (paced on hardware, as fast as possible in sim)
        self.info = device.info
        self.protocol = protocol
        self.samples = {s.name: s for s in catalog}
        self.sim_participant = sim_participant
        self.simulated_hand = sim_participant is not None
        self.is_sim = bool(self.info.simulated) and hasattr(device, "set_sample")
        self.fs_hz = float(self.info.servo_rate_hz)
        self.force_limit_N = self.info.force_per_amp_N_A * self.info.current_amplifier_A
        # homing runs under the same host watchdog as the tapping windows (servo_watchdog_s), not a stricter one
        self.homing = HomingController(device, HomingConfig(
            home_height_m=protocol.home_height_m, kp_N_m=protocol.homing_kp_N_m, kd_N_s_m=protocol.homing_kd_N_s_m),
                                       safety_config=RendererConfig(watchdog_overrun_s=protocol.servo_watchdog_s))
        # the log ring keeps the last window + 1 s: enough for 50 ms before the first impact, and a 16 s
        # ring (timeout + window) per attempt would only cost allocation time
        self._capacity_s = max(protocol.tap_window_s, protocol.familiarization_window_s) + 1.0
        self.library_dir = library_dir
        self.loops = {}
        for s in catalog:
            self.add_sample(s)
        self.temp_rise_K = 0.0
        self.current = None
        self.reference: Reference | None = None
        # polled by every homing and servo loop here (with their stop checks); it raises to abort the loop,
        # whose output is then zeroed on the way out (the servo process: its parent died, study.session.isolated)
        self.stop_check = None
        #: the Lab Streaming Layer's servo callback (plumbing.lsl.ServoStream) when the session streams, else None
        self.monitor = None
        if self.is_sim:
            self.real_saturation_detection = "sim contact force (true_state)"
        else:
            self.real_saturation_detection = ("device extra['contact_force_N']" if "contact_force_N" in
                                              getattr(device.read(), "extra", {}) else "none (no force sensor)")

    def add_sample(self, sample) -> None:
        """Make the servo loop of a catalog sample (once per name; an adaptive psychophysics session adds the
        stimuli its staircases ask for as they come).

        Parameters
        ----------
        sample : stimuli.CatalogSample

        Raises
        ------
        ValueError
            The sample cannot be rendered on this device (raised now, not mid-window).
        """
        if sample.name in self.loops:
            return
        transient = sample.make_transient(library_dir=self.library_dir) if sample.kind == "virtual" else None
        cfg = RendererConfig(stiffness_N_m=sample.stiffness_N_m if sample.kind == "virtual" else 0.0,
                             motor_enabled=sample.kind == "virtual", log_capacity_s=self._capacity_s,
                             until_every=4 if sample.kind == "real" else 16,
                             watchdog_overrun_s=self.protocol.servo_watchdog_s)
        loop = ServoLoop(self.device, cfg, transient)
        loop.prepare()  # raises ValueError now (e.g. a library unusable on this device), not mid-session
        self.samples[sample.name] = sample
        self.loops[sample.name] = loop

    def drop_sample(self, name: str) -> None:
        """Release the servo loop of a sample added for a while (the method of adjustment's comparisons: each
        loop holds its log, ~6 MB with 5 s windows); the catalog's own samples are kept. No-op if unknown."""
        if name in self.loops and self.current is not self.samples.get(name):
            del self.loops[name]
            del self.samples[name]

    def wait_streams(self, timeout_s: float) -> bool:
        """Wait for consumers of the servo's Lab Streaming Layer streams (True: connected, or none streamed)."""
        return True if self.monitor is None else self.monitor.publisher.wait_for_consumers(timeout_s)

    def close_streams(self) -> dict | None:
        """Stop the Lab Streaming Layer's servo streams (pushing what is queued); their record, or None."""
        if self.monitor is None:
            return None
        record, self.monitor = self.monitor.publisher.close(), None
        return record

    def link_status(self) -> str:
        """One line on the device link's health for the operator page.

        Returns
        -------
        str
            ``"sim (no link)"`` for a simulated device; for a device that counts its link (serial,
            fw-sim) ``"ok · rtt p99 <ms> ms"`` while no fault has been counted, else
            ``"FAULTS: <n> lost, <n> CRC, <n> timeouts, <n> watchdog · rtt p99 <ms> ms"`` (session
            totals, so a fault stays visible after it happened); ``"<kind> (no link counters)"`` for
            a device without them (HID).
        """
        return link_summary(self.device)

    def now_s(self) -> float:
        """Device time (s): simulated time in sim mode, the device clock on hardware."""
        return float(self.device.read().t_s)

    # -- sample and hand --------------------------------------------------
    def set_sample(self, name: str) -> None:
        """Select the sample; in sim mode also put the matching simulated sample under the stylus."""
        smp = self.samples[name]
        self.current = smp
        if self.is_sim:
            self.device.set_sample(smp.real_sample if smp.kind == "real" else "placeholder")
            self.device.motor_enabled = True  # homing needs the motor; the tap window sets it per sample

    def start_hand(self, plan, window_s: float) -> None:
        """Give the simulated hand the attempt's taps (sim only); an overpowering tap comes after ``window_s``."""
        h = self.protocol.home_height_m
        window = window_s
        cfg = self.sim_participant.config
        common = dict(approach_height_m=h, dwell_s=cfg.dwell_s)
        traj = TapTrajectory(list(plan.velocities_m_s), len(plan.velocities_m_s), **common)
        # the hand stops tapping before the window ends (taps that would cross the surface later are dropped)
        first = traj.surface_times_s[0]
        n_fit = sum(1 for ts in traj.surface_times_s if ts < first + window - 0.3)
        if n_fit < len(plan.velocities_m_s):
            traj = TapTrajectory(list(plan.velocities_m_s[:max(n_fit, 1)]), max(n_fit, 1), **common)
        grip = plan.grip_N
        if plan.overpower:
            # one more tap, starting after the window, with a firm grip (stiffer hand) against the homing
            # a determined push (deep press target) that the homing force cannot hold back
            late = TapTrajectory([max(plan.velocities_m_s)], 1, approach_height_m=h, dwell_s=cfg.dwell_s,
                                 press_depth_m=cfg.overpower_press_depth_m)
            first = traj.surface_times_s[0]
            t_late = max(traj.duration_s, first + window) + 0.05
            fs = self.fs_hz
            x1 = traj.sample(fs)
            n_gap = int(round(t_late * fs)) - len(x1)
            x = np.concatenate([x1, np.full(max(n_gap, 0), h), late.sample(fs)])
            t = np.arange(len(x)) / fs
            traj = ScriptedTrajectory(t, x)
            g_hi = self.sim_participant.config.overpower_grip_N
            grip = lambda ts, g0=grip, t1=t_late, g1=g_hi: np.where(np.asarray(ts) >= t1 - 0.05, g1, g0)  # noqa: E731
        hand = None
        params = getattr(self._tap_device(), "params", None)
        if plan.overpower and params is not None and params.model == "nonlinear":
            # a determined push: the simulated person co-contracts (stiff, damped muscles), so the
            # homing force cannot hold the late tap back (the default person is compliant)
            hand = DEFAULT_PERSON.replace(muscle_stiffness_N_m=1500.0, muscle_damping_Ns_m=12.0)
        self._give_hand(traj, grip, hand)

    def _tap_device(self):
        """The 1-DOF simulated device along which the hand taps (this device; a 3-DOF sim's tap axis)."""
        return self.device

    def _give_hand(self, traj, grip, hand) -> None:
        """Hand the simulated person its plan (the 3-DOF apparatus also says where it taps)."""
        self.device.set_user(traj, grip, hand=hand)

    # -- homing -------------------------------------------------------------
    def _home(self, duration_s: float, **kw) -> int:
        """Run homing with the apparatus' winding temperature; a safety stop ends the session."""
        check = self.stop_check
        if check is not None:
            inner = kw.get("until")
            kw["until"] = lambda: check() or (inner is not None and inner())
        self.homing.temp_rise_K = self.temp_rise_K
        res = self.homing.run(duration_s, **kw)
        self.temp_rise_K = self.homing.temp_rise_K
        if res.stop_reason in SAFETY_STOPS:
            raise ServoStopped(f"homing stopped ({res.stop_reason}) after {res.duration_s:.2f} s: {res.message}")
        return res.contacts

    def home(self, max_s: float) -> None:
        """Pre-trial homing: until settled at the home height (at most ``max_s``)."""
        self._home(max_s, until_settled=True, min_duration_s=min(0.05, max_s), realtime=bool(self.realtime))

    def after_window(self, duration_s: float) -> int:
        """Post-window homing; returns the number of taps on the surface (overpowering).

        With the simulated hand, homing may end early once the hand's scripted
        trajectory is over (it holds still at the home height and cannot tap
        again); a person can tap at any time, so hardware always homes the
        full ``duration_s``.
        """
        if self.simulated_hand and self.is_sim:
            dev = self.device
            return self._home(duration_s, until=lambda: dev.trajectory_done, check_every=100,
                              realtime=bool(self.realtime))
        return self._home(duration_s, realtime=bool(self.realtime))

    def hold(self, until, max_s: float = 24 * 3600.0) -> int:
        """Hold home until ``until()`` (keyboard sessions); returns surface contacts meanwhile."""
        return self._home(max_s, until=until, realtime=True)

    # -- the tapping window ---------------------------------------------------
    def tap_window(self, window_s: float, first_tap_timeout_s: float, on_clip=None) -> TapResult:
        """Render the current sample from now until ``window_s`` after the first impact.

        ``on_clip()`` is called once, as soon as saturation is seen (the low tone).
        """
        smp = self.current
        loop = self.loops[smp.name]
        dev = self.device
        real = smp.kind == "real"
        if self.is_sim:
            dev.motor_enabled = not real
        # read() once, here, outside the loop: it returns the same state object, updated in place by the loop's
        # own reads, so the callback below looks at the latest sample without an extra (on hardware: blocking) read
        st = dev.read()
        force_of = None
        if real:
            if self.is_sim:
                # the 1-DOF sim reads the one value (polled every few ticks); another sim builds its true state
                force_of = getattr(dev, "contact_force_N", None) or (lambda: dev.true_state()["contact_force_N"])
            elif "contact_force_N" in st.extra:
                force_of = lambda: st.extra["contact_force_N"]  # noqa: E731
        flim = self.force_limit_N
        clip_bit = 8  # devices.base.Status.CLIPPING
        t_start = st.t_s
        check = self.stop_check
        state = {"sat": False, "fmax": 0.0, "checked": 0}
        toned = set()

        def saturation(index: int) -> None:
            # one low tone per saturating tap, as soon as it is seen (section 4.5.3)
            state["sat"] = True
            if index not in toned:
                toned.add(index)
                if on_clip is not None:
                    on_clip()

        monitor = self.monitor

        # called every few servo ticks (renderer.loop: RendererConfig.until_every), so it does little when
        # nothing happened: the events closed since the last call are looked at only when there are some
        def until(lp) -> bool:
            if check is not None:
                check()
            if monitor is not None:
                monitor(lp)
            evs = lp.events
            current = len(evs) - 1
            if force_of is not None:
                f = force_of()
                if f > state["fmax"]:
                    state["fmax"] = f
                if f > flim:
                    saturation(current)
            elif st.status & clip_bit:
                saturation(current)
            if evs:
                checked = state["checked"]
                if current > checked:
                    for j in range(checked, current):  # events closed since the last call
                        if evs[j].clipped:
                            saturation(j)
                    state["checked"] = current
                return lp.time_s - evs[0].t_s >= window_s
            return lp.time_s - t_start >= first_tap_timeout_s

        loop.temp_rise_K = self.temp_rise_K
        if monitor is not None:
            monitor.begin(loop)
        try:
            result = loop.run(duration_s=first_tap_timeout_s + window_s + 0.5, until=until, realtime=self.realtime)
        finally:
            if monitor is not None:
                monitor.flush(loop)
            self.temp_rise_K = loop.temp_rise_K
            if self.is_sim:
                dev.motor_enabled = True
        if result.stop_reason not in ("until", "duration"):
            raise ServoStopped(f"servo loop stopped ({result.stop_reason}): {result.error}")
        events = list(result.events)
        for j, e in enumerate(events):
            if e.clipped:   # clipped in the last moments of the window, or between two checks
                saturation(j)
        log = result.log
        window_start = events[0].t_s if events else None
        if window_start is not None:
            # keep 50 ms before the first impact: the approach is not needed for figures
            keep = log["t_s"] >= window_start - 0.05
            log = {k: v[keep] for k, v in log.items()}
        saturated = state["sat"] or any(e.clipped for e in events) or bool(np.any(log["clipped"] & 4))
        if real and force_of is None:
            saturated = state["sat"]
        # on-device telemetry may carry every n-th tick: the log's own rate, not the servo rate
        log_fs = float(result.timing.get("log_rate_hz", self.fs_hz))
        return TapResult(events, log, window_start, bool(saturated), state["fmax"], log_fs, smp.name,
                         result.timing)

    # -- synthetic rater support (sim) ------------------------------------------
    def features(self, tap: TapResult) -> np.ndarray:
        """The rater's features of a tap window (acceleration spectrum around the impacts; :func:`study.session.rater.tap_features`)."""
        return tap_features(tap.log["t_s"], tap.log["accel_m_s2"], [e.t_s for e in tap.events], tap.fs_hz)

    def record_reference(self, reference_sample: str = REFERENCE_SAMPLE) -> Reference:
        """Tap the real reference sample (sim; the rater's :data:`study.session.rater.REFERENCE_SAMPLE`, the real wood) at
        several velocities with the motor off; fit the rater's reference."""
        dev = self.device
        dev.set_sample(reference_sample)
        dev.motor_enabled = False
        grip = self.sim_participant.grip_N if self.sim_participant else 2.0
        traj = TapTrajectory(list(REFERENCE_VELOCITIES_M_S), len(REFERENCE_VELOCITIES_M_S),
                             approach_height_m=self.protocol.home_height_m)
        dev.set_user(traj, grip)
        loop = ServoLoop(dev, RendererConfig(stiffness_N_m=0.0, motor_enabled=False,
                                             log_capacity_s=traj.duration_s + 1.0))
        check = self.stop_check
        try:
            result = loop.run(duration_s=traj.duration_s + 0.2,
                              until=None if check is None else (lambda lp: check()))
        finally:
            dev.motor_enabled = True
            dev.set_sample("placeholder")
        events = result.events
        feats = tap_features(result.log["t_s"], result.log["accel_m_s2"], [e.t_s for e in events],
                             float(result.timing.get("log_rate_hz", self.fs_hz)))
        self.reference = Reference.fit([e.incoming_velocity_m_s for e in events], feats)
        return self.reference
