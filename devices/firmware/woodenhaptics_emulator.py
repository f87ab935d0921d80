"""An emulated WoodenHaptics behind a hidapi-shaped handle (docs/bringup.md, "WoodenHaptics").

No virtual HID device can be made here, so the seam is the handle hidapi gives (``hid.device``):
:class:`WoodenHapticsHandle` has its ``open``, ``write(report)`` (report id 0 first, as hidapi takes it),
``read(size, timeout_ms)``, ``set_nonblocking`` and ``close``, and behaves as the published firmware
(:mod:`devices.hardware.woodenhaptics.protocol`, cited lines): each command report sets the three motor
currents (``mA * 0.001``, saturating at 3.0, the ESCON's full scale standing for 1 A of motor current as
CWoodenDevice.cpp configures it) and is answered by an 8-byte report of the three encoder counts and the
report counter; no command for 0.5 s disables the amplifiers (the firmware's ``msg_watchdog``).

The real board sends reports as fast as USB takes them; this one sends one per command (host-paced, as the
other emulators), so tests see the same states however loaded the machine is. The linkage is the handle of
:class:`devices.firmware.endpoint.Endpoint` (a hand tapping along z) seen through the device's kinematics:
motor torques minus the linkage's gravity (which CWoodenDevice compensates) become the endpoint force
through ``J^-T``, positions become encoder counts through the inverse kinematics.

Faults: ``unplug()`` (every call then fails as hidapi does for a removed device; ``unplug_after=N``: after
N commands), ``bad_size_every=N``
(every N-th report is 7 bytes), ``freeze_at=N`` (the report counter and encoders stop changing from the
N-th report: a hung firmware), ``stall_at=N, stall_s=S`` (the N-th report comes S seconds late).
"""

from __future__ import annotations

import collections
import threading
import time

from ..hardware.woodenhaptics import protocol as W
from .endpoint import Endpoint, TapPlan

ESCON_FULL_SCALE_A = 1.0


class WoodenHapticsHandle:
    """A hidapi-like handle to the emulated board (see module doc)."""

    def __init__(self, plan: TapPlan | None = TapPlan(), cfg: W.Config = W.DEFAULT, rate_hz: float = 1000.0,
                 bad_size_every: int = 0, freeze_at: int = 0, stall_at: int = 0, stall_s: float = 0.0,
                 watchdog: bool = True, unplug_after: int = 0) -> None:
        self.cfg = cfg
        self.endpoint = Endpoint((0.0, 0.0, 0.0), vertical=2, plan=plan, mass_kg=0.2)
        self.dt_s = 1.0 / rate_hz
        self.bad_size_every, self.freeze_at = int(bad_size_every), int(freeze_at)
        self.stall_at, self.stall_s = int(stall_at), float(stall_s)
        self.unplug_after = int(unplug_after)
        self.opened = False
        self.unplugged = False
        self.enabled = False          # the ESCONs' enable line
        self.currents_A = (0.0, 0.0, 0.0)
        self.counter = 0
        self.reports: collections.deque = collections.deque(maxlen=64)
        self.commands_received: collections.deque = collections.deque(maxlen=100_000)
        self._q = (0.0, 0.4, 0.4)
        self._frozen = None
        self.last_cmd_t = None
        self.stats = {"commands": 0, "reports": 0, "watchdog_trips": 0}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wd = None
        if watchdog:
            self._wd = threading.Thread(target=self._watchdog, name="woodenhaptics-watchdog", daemon=True)
            self._wd.start()

    # -- hidapi's surface -------------------------------------------------------------------------
    def open(self, vid: int, pid: int, serial=None) -> None:
        """As ``hid.device().open``: OSError unless the ids are the board's."""
        if self.unplugged or (vid, pid) != (W.VID, W.PID):
            raise OSError("open failed")
        self.opened = True

    def set_nonblocking(self, flag) -> int:
        """Accepted (the driver reads with timeouts)."""
        return 0

    def get_product_string(self) -> str:
        """mbed's USBHID product string."""
        return "HID DEVICE"

    def write(self, data) -> int:
        """An output report: report id 0, then 8 bytes (hidapi's convention)."""
        self._alive()
        data = bytes(data)
        if len(data) != W.REPORT_SIZE + 1 or data[0] != 0:
            return -1
        ma, _ = W.decode_command(data[1:])
        if self.unplug_after and self.stats["commands"] >= self.unplug_after:
            self.unplug()
            self._alive()
        with self._lock:
            self.commands_received.append(ma)
            self.stats["commands"] += 1
            self.last_cmd_t = time.monotonic()
            self.enabled = True
            self.currents_A = tuple(W.firmware_current_A(v) / W.FIRMWARE_FULL_SCALE_A * ESCON_FULL_SCALE_A
                                    for v in ma)
            self._step()
        return len(data)

    def read(self, size: int, timeout_ms: int = 0) -> list:
        """The oldest queued input report (a list of ints, as hidapi), or [] after ``timeout_ms``."""
        self._alive()
        deadline = time.monotonic() + max(0, timeout_ms) * 1e-3
        while True:
            with self._lock:
                if self.reports:
                    return list(self.reports.popleft()[:size])
            if time.monotonic() >= deadline:
                return []
            time.sleep(0.0002)

    def close(self) -> None:
        """Release the handle (the board keeps running: its watchdog will zero it)."""
        self.opened = False

    # -- the board ------------------------------------------------------------------------------------
    def _alive(self) -> None:
        if self.unplugged or not self.opened:
            raise OSError("read error" if self.unplugged else "not open")

    def unplug(self) -> None:
        """Pull the cable: no USB power, no amplifiers, every call fails."""
        self.unplugged = True
        with self._lock:
            self.enabled = False
            self.endpoint.set_force(0.0, 0.0, 0.0)

    def stop(self) -> None:
        """End the watchdog thread."""
        self._stop.set()

    def _watchdog(self) -> None:
        while not self._stop.wait(0.01):
            with self._lock:
                if self.enabled and self.last_cmd_t is not None and \
                        time.monotonic() - self.last_cmd_t > W.FIRMWARE_WATCHDOG_S:
                    self.enabled = False   # escon_timeout(): amplifiers off, PWM 0
                    self.stats["watchdog_trips"] += 1
                    self.endpoint.set_force(0.0, 0.0, 0.0)

    def applied_force(self) -> tuple:
        """The endpoint force the motors produce now (N)."""
        return tuple(self.endpoint.force)

    def _step(self) -> None:
        cfg, ep = self.cfg, self.endpoint
        q = self._q
        if self.enabled:
            kt = cfg.kt
            mt = [kt[i] * self.currents_A[i] for i in range(3)]
            t = (mt[0] * cfg.diameter_body_a / cfg.diameter_capstan_a,
                 -mt[1] * cfg.diameter_body_b / cfg.diameter_capstan_b,
                 -mt[2] * cfg.diameter_body_c / cfg.diameter_capstan_c)
            g = W.gravity_torques(q, cfg)   # the linkage's weight: the negative of what the host compensates
            t = [t[i] - g[i] for i in range(3)]
            j = W.jacobian(q, cfg)
            jt = [[j[r][c] for r in range(3)] for c in range(3)]
            try:
                f = W._solve3(jt, t)
            except ValueError:
                f = (0.0, 0.0, 0.0)
            ep.set_force(*f)
        else:
            ep.set_force(0.0, 0.0, 0.0)
        ep.step(self.dt_s)
        try:
            self._q = W.inverse(ep.pos, cfg, guess=q)
        except ValueError:
            pass
        self.counter = (self.counter + 1) & 0xFFFF
        n = self.stats["reports"] + 1
        self.stats["reports"] = n
        enc = W.encoders_from_angles(self._q, cfg)
        if self.freeze_at and n >= self.freeze_at:
            if self._frozen is None:
                self._frozen = W.encode_report(enc, self.counter)
            report = self._frozen
        else:
            report = W.encode_report(enc, self.counter)
        if self.bad_size_every and n % self.bad_size_every == 0:
            report = report[:7]
        if self.stall_at and n == self.stall_at:
            time.sleep(self.stall_s)
        self.reports.append(report)


def motor_torque_check(handle: WoodenHapticsHandle) -> float:
    """The largest motor current (A) the board applies now (tests: the ESCON's 1 A is never exceeded)."""
    return max(abs(a) for a in handle.currents_A) if handle.enabled else 0.0

