"""The WoodenHaptics adapter: its USB HID reports through hidapi (no vendor library).

Device string ``woodenhaptics`` (the mbed board's ids 1234:0006), ``woodenhaptics:<vid>:<pid>`` for a
board flashed with other ids, options as every hardware string. Each servo tick writes one command
report and takes the newest input report (the board streams them: older ones queued in the meantime are
dropped, as CWoodenDevice.cpp does); a report whose counter has not advanced is stale and not a new
sample. Forces become motor currents through CWoodenDevice's Jacobian with its gravity compensation
(``gravity=0`` turns it off) and are sent in the wire's units (:mod:`devices.hardware.woodenhaptics.protocol`);
encoders come back through its forward kinematics. The board's own watchdog is 0.5 s; the host watchdog
(20 ms, :mod:`devices.hardware.threedof`) keeps the output zeroed well before it.
"""

from __future__ import annotations

from ...base import DeviceError, Status
from ..threedof import ThreeAxisDevice, three_axis_info
from . import protocol as W

try:  # hidapi is a dependency; without it opening the board is one error, importing this is not
    import hid
except ImportError:  # pragma: no cover
    hid = None

MAX_FORCE_N = 2.0
MAX_PEAK_FORCE_N = 3.0          # the ESCON's 1 A on each motor through the linkage near the centre
SERVO_RATE_HZ = 1000.0
HALF_BOX_M = (0.07, 0.07, 0.07)  # inside default_woody()'s 0.1 m workspace radius
POSITION_RESOLUTION_M = 2e-5
#: reports in a row with the same counter after which the board counts as hung (a device fault)
FROZEN_REPORTS = 20


class WoodenHapticsDevice(ThreeAxisDevice):
    """A WoodenHaptics board (see module doc). ``handle`` is the test seam (a hidapi-like object)."""

    spec_prefix = "woodenhaptics"

    def __init__(self, vid: int = W.VID, pid: int = W.PID, handle=None, gravity: int = 1,
                 cfg: W.Config = W.DEFAULT, **options) -> None:
        super().__init__(**options)
        self.vid, self.pid = int(vid), int(pid)
        self._seam = handle
        self._h = None
        self.cfg = cfg
        self.gravity = bool(gravity)
        self._q = W.inverse((0.0, 0.0, 0.0), cfg)
        self._counter = 0
        self._last_rx_counter = None
        self._same = 0
        self.info = three_axis_info("WoodenHaptics", SERVO_RATE_HZ, tuple(-h for h in HALF_BOX_M), HALF_BOX_M,
                                    MAX_FORCE_N, MAX_PEAK_FORCE_N, cfg.max_linear_stiffness, POSITION_RESOLUTION_M,
                                    linear=False, buttons=0)
        self.stats.update(stale_reports=0, bad_reports=0, report_gaps=0)

    @property
    def name(self) -> str:
        """``woodenhaptics`` (with the ids when they are not the default)."""
        if (self.vid, self.pid) == (W.VID, W.PID):
            return "woodenhaptics"
        return f"woodenhaptics:{self.vid:04x}:{self.pid:04x}"

    def _open_link(self) -> None:
        if self._seam is not None:
            h = self._seam
        else:
            if hid is None or not hasattr(hid, "device"):
                raise DeviceError(f"{self.name}: the hidapi package is missing (pip install hidapi)")
            h = hid.device()
        try:
            h.open(self.vid, self.pid)
        except (OSError, IOError, ValueError) as exc:
            seen = []
            if hid is not None and self._seam is None:
                seen = [f"{d['vendor_id']:04x}:{d['product_id']:04x}" for d in hid.enumerate()]
            raise DeviceError(f"{self.name}: cannot open the board's USB HID device {self.vid:04x}:{self.pid:04x} "
                              f"({exc}): not plugged in, held by another program, or no permission (udev rule, "
                              f"docs/bringup.md); HID devices present: {', '.join(seen) or 'none'}") from None
        self._h = h
        self._last_rx_counter = None
        self._same = 0
        # the first report proves it is the board (an 8-byte report); anything else is refused here
        if not self._transact(0.0, 0.0, 0.0):
            self._close_link()
            raise DeviceError(f"{self.name}: the device at {self.vid:04x}:{self.pid:04x} sends no WoodenHaptics "
                              "reports (8 bytes: three encoder counts and a counter); is the firmware flashed?")

    def _close_link(self) -> None:
        h, self._h = self._h, None
        if h is not None:
            try:
                h.write(b"\x00" + W.encode_command((0, 0, 0), self._counter))
            except Exception:
                pass
            try:
                h.close()
            except Exception:
                pass

    def _link_usable(self) -> bool:
        return self._h is not None

    def _motors_off(self) -> bool:
        """Zero current on every motor (a zero force would still carry the gravity compensation)."""
        return self._transact(0.0, 0.0, 0.0, off=True)

    def _transact(self, fx_N: float, fy_N: float, fz_N: float, off: bool = False) -> bool:
        h = self._h
        if h is None:
            raise OSError("link closed")
        st = self._state
        try:
            amps = (0.0, 0.0, 0.0) if off else W.motor_currents(self._q, (fx_N, fy_N, fz_N), self.cfg, self.gravity)
        except (ValueError, ZeroDivisionError):
            amps = (0.0, 0.0, 0.0)
        ma = W.wire_ma(amps)
        limit = int(W.FIRMWARE_FULL_SCALE_A * 1000)   # the firmware saturates beyond it: scale all three instead
        largest = max(abs(v) for v in ma)
        if largest > limit:
            ma = tuple(int(v * limit / largest) for v in ma)
            self.stats["clipped"] += 1
            st.status |= Status.CLIPPING
        else:
            st.status &= ~Status.CLIPPING
        self._counter = (self._counter + 1) & 0xFFFF
        try:
            n = h.write(b"\x00" + W.encode_command(ma, self._counter))
            if n is not None and n < 0:
                raise OSError(f"hidapi write returned {n}")
            report = None
            wait_ms = max(1, int(self.loss_timeout_s * 1000))
            while True:
                r = h.read(W.REPORT_SIZE + 8, wait_ms if report is None else 0)
                if not r:
                    break
                if len(r) != W.REPORT_SIZE:
                    self.stats["bad_reports"] += 1
                    continue
                report = bytes(r)
        except (OSError, IOError, ValueError) as exc:
            raise OSError(f"USB HID: {exc} (unplugged?)") from None
        if report is None:
            return False
        enc, counter = W.decode_report(report)
        last = self._last_rx_counter
        if last is not None:
            step = (counter - last) & 0xFFFF
            if step == 0:
                self.stats["stale_reports"] += 1
                self._same += 1
                if self._same >= FROZEN_REPORTS:
                    raise OSError(f"device fault: the board's report counter is frozen at {counter} "
                                  f"({self._same} reports): its firmware hung")
                return True
            if step > 1:
                self.stats["report_gaps"] += step - 1
        self._same = 0
        self._last_rx_counter = counter
        q = W.joint_angles(enc, self.cfg)
        self._q = q
        x, y, z = W.forward(q, self.cfg)
        st.x_m, st.y_m, st.position_m = x, y, z
        st.extra["encoders"] = enc
        st.extra["wire_mA"] = ma
        return True

    def jacobian(self):
        """CWoodenDevice's Jacobian at the last sample (columns tA, tB, modified tC)."""
        return W.jacobian(self._q, self.cfg)
