"""What the adapters of the 3-DOF research devices share: one force/state transaction per servo tick, the
safety path, the link's timing, and the 1-DOF view a 1-DOF scene renders through.

:class:`ThreeAxisDevice` is a :class:`devices.base.Device` with ``info.axes == 3`` (docs/architecture.md,
"Multi-axis device interface"). A driver subclass implements the device's own transaction in its native
frame and units (:meth:`ThreeAxisDevice._transact`: send a force, receive the state that answers it) and
its frame conversion (``_to_native_force``, ``_from_native``). This class adds, for every driver:

* **one transaction per tick**: ``command_force`` sends the force and waits for the device's reply (what
  every one of these devices does: the Inverse3's force request is answered by its state, the Falcon's
  packet by its packet, the WoodenHaptics' report by the next report; the vendor libraries' calls return
  at once); ``read()`` returns that state without waiting (the first ``read()`` after opening makes a
  zero-force transaction). The reply's wall-clock time is the sample's ``t_s`` (the devices send no clock;
  a driver that knows its device's own sample clock gives that instead: :meth:`ThreeAxisDevice._sample_time`).
* **losses**: a reply not back within ``loss_timeout_s`` is a lost frame: the last state is held
  (``extra["held"]``), counted; ``max_consecutive_losses`` in a row, or the link failing, ends the link
  with ``Status.DISCONNECTED`` and an error text in ``extra["error"]`` (the first ``read()`` reports it, as
  the serial board's driver does), after a last zero-force attempt.
* **the host watchdog**: a thread switches the motors off when no ``command_force`` came for ``watchdog_ms``
  (20 ms: the contract's command timeout, for devices whose own timeout is unknown or longer) and keeps
  them off (a transaction every ``watchdog_ms``) until the host commands again; the next state carries
  ``Status.WATCHDOG_TRIPPED``. Before the host's first command since opening it keeps them off the same way
  without a trip (no flag, no count in ``link_stats()``): a device opened and not yet driven (a session
  setting up its views before it homes) has no command to stop, and its link is no less healthy. A fault
  (lost link, a device fault) switches them off too. ``zero()`` and ``close()`` command zero *force* (a
  device whose driver compensates gravity keeps holding its linkage).
* **the link's figures** for ``run.json``: ``link_stats()`` (transactions, losses, garbage bytes, watchdog
  trips, command-to-state round trip median/p99/max, longest gap between replies) and
  ``restart_link_timing()``, the same names as the serial board's driver.

:class:`VerticalAxisDevice` is the 1-DOF view of a 3-axis device: a 1-axis :class:`Device` whose handle
position is the endpoint's z and whose "current" is the force along z (1 N per A), while x and y are held
by a stiff spring-damper to where the endpoint was when the view opened (docs/architecture.md, "A 1-DOF
scene on a 3-DOF device"). Every 1-DOF command (``renderer run``, ``study run``) runs on it unchanged.
"""

from __future__ import annotations

import array
import math
import threading
import time
from dataclasses import replace

from ..base import Device, DeviceError, DeviceInfo, DeviceState, Status
from plumbing.stopsignals import holding

RTT_RING = 65536
#: time constant (s) of the lateral velocity estimate of the 1-DOF view's holding damper
VELOCITY_TAU_S = 0.005
#: the contract's command timeout (docs/architecture.md "Watchdog and zero-on-exit")
HOST_WATCHDOG_MS = 20.0


def three_axis_info(name: str, servo_rate_hz: float, workspace_min_m, workspace_max_m, max_force_N: float,
                    max_peak_force_N: float, max_stiffness_N_m: float, position_resolution_m: float,
                    linear: bool, buttons: int) -> DeviceInfo:
    """A 3-axis :class:`DeviceInfo`. Its 1-DOF fields describe a unit actuator (1 N per A, the motor
    constants 1) with the continuous and peak "currents" equal to the forces, the encoder lines giving
    ``position_resolution_m``, and a winding model that never limits (the devices protect their own motors):
    only the 1-DOF view reads them."""
    lines = max(1, int(round(2.0 * math.pi / (4.0 * position_resolution_m))))
    return DeviceInfo(name=name, encoder_lines=lines, gear_ratio=1.0, handle_length_m=1.0, torque_constant_Nm_A=1.0,
                      current_continuous_A=max_force_N, current_peak_A=max_peak_force_N,
                      current_amplifier_A=max_peak_force_N, servo_rate_hz=servo_rate_hz,
                      winding_resistance_ohm=1.0, thermal_resistance_K_W=1e-3, thermal_time_constant_s=30.0,
                      winding_max_temp_rise_K=1000.0, accel_range_m_s2=490.0, grip_range_N=(0.0, 0.0),
                      capabilities=("streaming",), simulated=False, axes=3, workspace_min_m=tuple(workspace_min_m),
                      workspace_max_m=tuple(workspace_max_m), max_force_N=max_force_N,
                      max_peak_force_N=max_peak_force_N, max_stiffness_N_m=max_stiffness_N_m, linear=linear,
                      buttons=buttons)


class ThreeAxisDevice(Device):
    """Base of the 3-DOF adapters (see module doc).

    Parameters
    ----------
    loss_timeout_s : float
        A reply later than this is a lost frame (default 5 ms, as the serial board's driver).
    max_consecutive_losses : int
        Lost frames in a row that end the link (default 10: 50 ms, beyond the 20 ms watchdog).
    watchdog_ms : float
        Host watchdog period (default 20 ms); 0 turns it off (tests of the device's own watchdog).
    """

    spec_prefix = "device"

    def __init__(self, loss_timeout_s: float = 0.005, max_consecutive_losses: int = 10,
                 watchdog_ms: float = HOST_WATCHDOG_MS) -> None:
        super().__init__()
        for key, value in (("loss_timeout_s", loss_timeout_s), ("watchdog_ms", watchdog_ms)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be a number >= 0, got {value!r}")
        if not loss_timeout_s > 0:
            raise ValueError(f"loss_timeout_s must be > 0 s, got {loss_timeout_s!r}")
        if not (isinstance(max_consecutive_losses, int) and max_consecutive_losses >= 1):
            raise ValueError(f"max_consecutive_losses must be a whole number >= 1, got {max_consecutive_losses!r}")
        self.loss_timeout_s = float(loss_timeout_s)
        self.max_consecutive_losses = int(max_consecutive_losses)
        self.watchdog_s = float(watchdog_ms) * 1e-3
        self._state = DeviceState()
        self._state.accel_m_s2 = math.nan   # no accelerometer on these devices
        self._state.extra.update(held=False)
        self._lock = threading.RLock()
        self._have_state = False
        self._disconnected = False
        self._disconnect_reported = False
        self.last_error = ""
        self._t0 = time.monotonic()
        self._last_cmd = time.monotonic()
        self._commanded = False     # a command_force since opening: before it, the watchdog's zeroing is no trip
        self._tripped = False
        self._trip_report = False
        #: the device advances one servo period per transaction, its clock waiting for the host (the built-in
        #: emulators, ``devices.lab_devices``): a state's time is then that count of periods (:meth:`_sample_time`)
        self.lockstep = False
        self._replies = 0
        self._consecutive = 0
        self._wd_thread: threading.Thread | None = None
        self._wd_stop = threading.Event()
        self._rtt = array.array("d", bytes(8 * RTT_RING))
        self._rtt_n = 0
        self._last_reply: float | None = None
        self._longest_gap_s = 0.0
        self.owned: list = []   # things to stop after the link closes (an emulator this device started)
        self.stats = {"transactions": 0, "losses": 0, "max_consecutive_losses": 0, "garbage_bytes": 0,
                      "watchdog_trips": 0, "watchdog_zeros": 0, "clipped": 0}

    # -- what a driver implements ---------------------------------------------------------------
    @property
    def name(self) -> str:
        """The device string this driver was opened with."""
        return self.spec_prefix

    def _open_link(self) -> None:
        """Open the vendor link (DeviceError naming what failed)."""
        raise NotImplementedError

    def _close_link(self) -> None:
        """Release the vendor link (errors ignored)."""
        raise NotImplementedError

    def _transact(self, fx_N: float, fy_N: float, fz_N: float) -> bool:
        """Send a force (device frame, already validated) and receive the answering state into ``self._state``
        (position, velocity, buttons, in the device frame). False when no reply came within
        ``loss_timeout_s``; DeviceError (or OSError) when the link failed."""
        raise NotImplementedError

    # -- lifecycle --------------------------------------------------------------------------------
    def _open(self) -> None:
        self._disconnected = False
        self._disconnect_reported = False
        self.last_error = ""
        self._have_state = False
        self._state.status = 0
        self._state.extra.pop("error", None)
        self._t0 = time.monotonic()
        self._open_link()
        self._last_cmd = time.monotonic()
        self._commanded = False
        if self.watchdog_s > 0:
            self._wd_stop.clear()
            self._wd_thread = threading.Thread(target=self._watchdog_loop, name=f"{self.name}-watchdog",
                                               daemon=True)
            self._wd_thread.start()

    def _close(self) -> None:
        self._wd_stop.set()
        t = self._wd_thread
        if t is not None and t is not threading.current_thread():
            t.join(1.0)
        self._wd_thread = None
        try:
            with self._lock:
                self._close_link()
        finally:
            for thing in self.owned:
                try:
                    thing.stop()
                except Exception:
                    pass

    def close(self) -> None:
        """Zero the output (one zero-force transaction while the link works), then release the device."""
        with holding():
            super().close()

    # -- the servo cycle ----------------------------------------------------------------------------
    def read(self) -> DeviceState:
        """The state answering the last force command (see module doc); the first read makes one."""
        if self._disconnected:
            if not self._disconnect_reported:
                self._disconnect_reported = True
                return self._state
            raise DeviceError(self.last_error or f"{self.name}: disconnected; reopen the device")
        if not self._is_open:
            raise DeviceError(f"{self.name}: device is not open")
        if not self._have_state:
            self._exchange(0.0, 0.0, 0.0)
            if self._disconnected:
                self._disconnect_reported = True
        st = self._state
        if self._tripped or self._trip_report:   # while tripped, and once more in the first state after it
            st.status |= Status.WATCHDOG_TRIPPED
            self._trip_report = False
        else:
            st.status &= ~Status.WATCHDOG_TRIPPED
        return st

    def _send_force(self, fx_N: float, fy_N: float, fz_N: float) -> None:
        self._last_cmd = time.monotonic()
        self._commanded = True
        if self._tripped:
            self._tripped = False
            self._trip_report = True
        self._exchange(fx_N, fy_N, fz_N)

    def _send_zero(self) -> None:
        if self._disconnected or not self._link_usable():
            return
        self._exchange(0.0, 0.0, 0.0)

    def _link_usable(self) -> bool:
        return True

    def _sample_time(self, now: float) -> float:
        """The time (s) of the state a transaction just took, from ``time.monotonic()`` at its reply: that
        reply's time since opening; on a :attr:`lockstep` device, the replies so far times its servo period. A
        driver whose device keeps its own sample clock returns that clock's time, so a sample the host reads
        twice carries the same time (the servo laws' velocity rings go by it: ``renderer.ring``)."""
        if self.lockstep:
            return self._replies / self.info.servo_rate_hz
        return now - self._t0

    def _motors_off(self) -> bool:
        """Switch every motor off (no current at all), as a transaction; default: a zero-force transaction.
        A driver whose zero force still drives its motors (gravity compensation) overrides it."""
        return self._transact(0.0, 0.0, 0.0)

    def _exchange(self, fx_N: float, fy_N: float, fz_N: float, off: bool = False) -> None:
        if self._disconnected:
            return
        with self._lock:
            t0 = time.monotonic()
            try:
                ok = self._motors_off() if off else self._transact(fx_N, fy_N, fz_N)
            except (DeviceError, OSError) as exc:
                self._fail(str(exc).removeprefix(f"{self.name}: "))
                return
            now = time.monotonic()
            self.stats["transactions"] += 1
            st = self._state
            if ok:
                self._rtt[self._rtt_n % RTT_RING] = now - t0
                self._rtt_n += 1
                if self._last_reply is not None and now - self._last_reply > self._longest_gap_s:
                    self._longest_gap_s = now - self._last_reply
                self._last_reply = now
                self._consecutive = 0
                self._replies += 1
                st.t_s = self._sample_time(now)
                st.extra["held"] = False
                self._have_state = True
                return
            self.stats["losses"] += 1
            self._consecutive += 1
            self.stats["max_consecutive_losses"] = max(self.stats["max_consecutive_losses"], self._consecutive)
            st.extra["held"] = True
            if self._consecutive >= self.max_consecutive_losses:
                # the silence as measured: a driver that reads a servo thread's newest state (the Touch) counts
                # a loss per host tick once the thread has been silent for the timeout, not one per timeout
                since = self._last_reply if self._last_reply is not None else self._t0
                self._fail(f"{self._consecutive} replies lost in a row, no reply for {(now - since) * 1000:.0f} ms "
                           f"(a reply later than {self.loss_timeout_s * 1000:.0f} ms counts as lost); "
                           "device not responding")
            elif not self._have_state:
                self._fail(f"no answer within {self.loss_timeout_s * 1000:.0f} ms to the first force command")

    def _fail(self, why: str) -> None:
        """The link is dead: try one last zero, mark DISCONNECTED, keep the error for the next read()."""
        if self._disconnected:
            return
        self._disconnected = True
        try:
            self._motors_off()
        except Exception:
            pass
        self.last_command_A = 0.0
        self.last_force_N = (0.0, 0.0, 0.0)
        self.last_error = f"{self.name}: {why}; output zeroed"
        self._state.status |= Status.DISCONNECTED
        self._state.extra["error"] = self.last_error

    def _watchdog_loop(self) -> None:
        period = self.watchdog_s
        while not self._wd_stop.wait(period / 4):
            if self._disconnected:
                return
            if time.monotonic() - self._last_cmd < period:
                continue
            with self._lock:
                if time.monotonic() - self._last_cmd < period or self._disconnected:
                    continue
                if not self._tripped and self._commanded:
                    self._tripped = True
                    self.stats["watchdog_trips"] += 1
                self.stats["watchdog_zeros"] += 1
                self._exchange(0.0, 0.0, 0.0, off=True)
                self._last_cmd = time.monotonic()  # the next zero one period later: the device stays zeroed

    # -- figures ------------------------------------------------------------------------------------
    def restart_link_timing(self) -> None:
        """Start the round-trip, gap and watchdog figures afresh (the servo loop calls it after its priming cycle:
        the host watchdog switching the motors off while the loop was being set up is no fault of the run)."""
        self._rtt_n = 0
        self._last_reply = None
        self._longest_gap_s = 0.0
        self.stats["watchdog_trips"] = self.stats["watchdog_zeros"] = 0

    def link_stats(self) -> dict:
        """Transactions, losses, watchdog trips and the force->state round trip (s), for run.json."""
        out = dict(self.stats)
        # the serial board's names too, so run.json, the printed table and the timing verdict read them alike:
        # a transaction is one frame each way; a reply that failed its format check counts as a CRC error
        out.update(frames_tx=self.stats["transactions"], frames_rx=self.stats["transactions"] - self.stats["losses"],
                   crc_errors=self.stats.get("bad_reports", 0) + self.stats.get("bad_packets", 0),
                   malformed_frames=self.stats.get("bad_reports", 0))
        n = min(self._rtt_n, RTT_RING)
        rtt = sorted(self._rtt[:n]) if n else []
        out.update(rtt_samples=n, rtt_median_s=rtt[n // 2] if n else None,
                   rtt_p99_s=rtt[min(n - 1, int(0.99 * n))] if n else None, rtt_max_s=rtt[-1] if n else None,
                   longest_gap_s=self._longest_gap_s, loss_timeout_s=self.loss_timeout_s,
                   watchdog_ms=self.watchdog_s * 1000)
        return out


class VerticalAxisDevice(Device):
    """The 1-DOF view of a 3-axis device: z is the handle, x and y are held (see module doc).

    Parameters
    ----------
    inner : ThreeAxisDevice
        The 3-axis device (opened and closed with the view).
    hold_stiffness_N_m, hold_damping_N_s_m : float
        The spring-damper holding x and y (default 2000 N/m and 5 N s/m, capped at the device's
        ``max_stiffness_N_m``).
    hold_force_fraction : float
        The holding force's magnitude is limited to this share of the continuous force (default 0.5), so
        the z channel keeps its share of the device's force.
    grip_N : float
        The grip force reported (N): these devices sense none, and the HFAM lookup needs one.
    """

    def __init__(self, inner: ThreeAxisDevice, hold_stiffness_N_m: float = 2000.0, hold_damping_N_s_m: float = 5.0,
                 hold_force_fraction: float = 0.5, grip_N: float = 2.0) -> None:
        super().__init__()
        for key, value in (("hold_stiffness_N_m", hold_stiffness_N_m), ("hold_damping_N_s_m", hold_damping_N_s_m),
                           ("grip_N", grip_N)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be a number >= 0, got {value!r}")
        if not 0 < hold_force_fraction <= 1:
            raise ValueError(f"hold_force_fraction must be in (0, 1], got {hold_force_fraction!r}")
        self.inner = inner
        self.hold_k = float(hold_stiffness_N_m)
        self.hold_b = float(hold_damping_N_s_m)
        self.hold_fraction = float(hold_force_fraction)
        self.grip_N = float(grip_N)
        self._info: DeviceInfo | None = None
        self._state = DeviceState()
        self._anchor = (0.0, 0.0)
        self._prev = None
        self._v_filt = (0.0, 0.0)
        self._hold_max = 0.0

    @property
    def name(self) -> str:
        """The inner device's name."""
        return self.inner.name

    @property
    def info(self) -> DeviceInfo:
        """A 1-axis DeviceInfo: the inner device's, with axes=1 (1 N per A; a continuous "current" of the
        continuous force left after the holding channel's share)."""
        if self._info is None:
            inner = self.inner.info
            spec = inner.specs()
            self._info = replace(inner, name=f"{inner.name} (vertical axis)", axes=1, workspace_min_m=None,
                                  workspace_max_m=None, grip_range_N=(0.0, 10.0), accel_range_m_s2=490.0,
                                  max_force_N=spec.max_force_N, max_peak_force_N=spec.max_peak_force_N,
                                  max_stiffness_N_m=spec.max_stiffness_N_m)
        return self._info

    def _open(self) -> None:
        self.inner.open()
        spec = self.inner.info.specs()
        self.hold_k = min(self.hold_k, spec.max_stiffness_N_m)
        self._hold_max = self.hold_fraction * spec.max_force_N
        st = self.inner.read()
        self._anchor = (st.x_m, st.y_m)
        self._prev = None

    def _close(self) -> None:
        self.inner.close()

    def read(self) -> DeviceState:
        """The endpoint's z as the handle position; x, y, velocities and status carried along."""
        s = self.inner.read()
        st = self._state
        st.t_s = s.t_s
        st.position_m = s.position_m
        st.x_m, st.y_m = s.x_m, s.y_m
        st.vx_m_s, st.vy_m_s, st.vz_m_s = s.vx_m_s, s.vy_m_s, s.vz_m_s
        st.buttons = s.buttons
        st.status = s.status
        st.accel_m_s2 = 0.0          # no accelerometer: the 1-DOF law reads 0, never NaN (a sensor fault)
        st.grip_N = self.grip_N
        st.extra = s.extra
        return st

    def _lateral_velocity(self, st: DeviceState) -> tuple[float, float]:
        """The endpoint's x, y velocity: the device's own when it measures one, else differences of positions
        low-passed over ``VELOCITY_TAU_S`` (an encoder count per tick is 40 mm/s on a Falcon: unfiltered, the
        damper would turn quantisation into force noise)."""
        vx, vy = st.vx_m_s, st.vy_m_s
        if vx == vx and vy == vy:
            return vx, vy
        prev = self._prev
        self._prev = (st.t_s, st.x_m, st.y_m)
        if prev is None or st.t_s <= prev[0]:
            return self._v_filt
        dt = st.t_s - prev[0]
        a = dt / (VELOCITY_TAU_S + dt)
        fx, fy = self._v_filt
        self._v_filt = (fx + a * ((st.x_m - prev[1]) / dt - fx), fy + a * ((st.y_m - prev[2]) / dt - fy))
        return self._v_filt

    def _send_current(self, current_A: float) -> None:
        st = self.inner._state
        vx, vy = self._lateral_velocity(st)
        fx = -self.hold_k * (st.x_m - self._anchor[0]) - self.hold_b * vx
        fy = -self.hold_k * (st.y_m - self._anchor[1]) - self.hold_b * vy
        m = math.sqrt(fx * fx + fy * fy)
        if m > self._hold_max:  # also catches NaN: m != m is handled by command_force's check below
            fx *= self._hold_max / m
            fy *= self._hold_max / m
        self.inner.command_force(fx, fy, current_A * 1.0)   # 1 N per A

    def _send_zero(self) -> None:
        if self.inner.is_open:
            self.inner.zero()

    def restart_link_timing(self) -> None:
        """As the inner device's."""
        self.inner.restart_link_timing()

    def link_stats(self) -> dict:
        """As the inner device's."""
        return self.inner.link_stats()
