"""The Force Dimension adapter: the vendor's DHD API through ``forcedimension-core`` (an optional extra).

Device string ``dhd:<index>`` (``dhd:0`` the first device the SDK finds). Needs the vendor's SDK (libdrd,
3.16 or newer, from Force Dimension's installer: ``$FDSDK`` or the standard places) and the Python bindings
(``pip install 'hfam-haptics[forcedimension]'``); nothing else in the project imports them, and they are
imported only when a ``dhd`` device opens. Each servo tick sets the force (``dhdSetForce``) and reads
position, linear velocity and buttons (``dhdGetPosition``, ``dhdGetLinearVelocity``, ``dhdGetButtonMask``),
all in the SDK's frame, which is the device frame (x towards the user, y right, z up, metres, newtons).
Opening arms the device's own watchdog (``dhdSetWatchdog``, expert mode: 160 x 125 us = 20 ms, where the
device supports it) besides the host watchdog; a ``MOTOR_SATURATED`` answer is ``Status.CLIPPING``.
"""

from __future__ import annotations

import contextlib
import io

from ...base import DeviceError, Status
from ..threedof import ThreeAxisDevice, three_axis_info

#: dhdSetWatchdog's unit is 125 us: 160 is the contract's 20 ms
WATCHDOG_UNITS = 160
MOTOR_SATURATED = 2            # forcedimension_core.constants.MOTOR_SATURATED
SERVO_RATE_HZ = 1000.0
HALF_BOX_M = (0.08, 0.08, 0.08)  # omega.3 class (a 160 x 110 mm workspace); the SDK publishes none per model
MAX_FORCE_N = 8.0
MAX_PEAK_FORCE_N = 12.0          # omega.3: 12 N
MAX_STIFFNESS_N_M = 14500.0      # omega.3: 14.5 N/mm
POSITION_RESOLUTION_M = 1e-5


def load_bindings():
    """``(dhd, expert)`` modules of forcedimension-core, or DeviceError saying what is missing and why.

    The bindings load the SDK when imported and only write why they could not to stderr: it is caught
    here and put in the error line.
    """
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            import forcedimension_core.dhd as dhd  # deferred: optional bindings + the SDK they load, 0.26 s CPU (mock)
            expert = dhd.expert
    except ImportError as exc:
        why = " ".join(err.getvalue().split()) or str(exc)
        if "forcedimension_core" in str(exc) and "No module" in str(exc):
            raise DeviceError("dhd: the Force Dimension bindings are not installed: pip install "
                              "'hfam-haptics[forcedimension]' (and the vendor's SDK from Force Dimension)") from None
        raise DeviceError(f"dhd: the Force Dimension SDK (libdrd) could not be loaded: {why} "
                          "(install the SDK 3.16 or newer and set FDSDK to its folder)") from None
    return dhd, expert


class ForceDimensionDevice(ThreeAxisDevice):
    """The ``index``-th Force Dimension device (see module doc)."""

    spec_prefix = "dhd"

    def __init__(self, index: int = 0, bindings=None, **options) -> None:
        super().__init__(**options)
        if not (isinstance(index, int) and index >= 0):
            raise ValueError(f"dhd:<index>: index must be a whole number >= 0, got {index!r}")
        self.index = index
        self._bindings = bindings
        self._dhd = None
        self._id = -1
        self._pos = [0.0, 0.0, 0.0]
        self._vel = [0.0, 0.0, 0.0]
        self._force = [0.0, 0.0, 0.0]
        self.system_name = ""
        self.watchdog_armed = False
        self.info = three_axis_info("Force Dimension", SERVO_RATE_HZ, tuple(-h for h in HALF_BOX_M), HALF_BOX_M,
                                    MAX_FORCE_N, MAX_PEAK_FORCE_N, MAX_STIFFNESS_N_M, POSITION_RESOLUTION_M,
                                    linear=False, buttons=2)

    @property
    def name(self) -> str:
        """``dhd:<index>``."""
        return f"dhd:{self.index}"

    def _error(self) -> str:
        try:
            return self._dhd.errorGetLastStr()
        except Exception:
            return "unknown error"

    def _open_link(self) -> None:
        dhd, expert = self._bindings if self._bindings is not None else load_bindings()
        self._dhd = dhd
        count = dhd.getDeviceCount()
        if count is not None and isinstance(count, int) and count <= self.index:
            raise DeviceError(f"{self.name}: the Force Dimension SDK sees {max(count, 0)} device(s); is it plugged "
                              "in, powered, and not opened by another program?")
        ID = dhd.openID(self.index)
        if not isinstance(ID, int) or ID < 0:
            raise DeviceError(f"{self.name}: cannot open the device ({self._error()}); another program may hold it")
        self._id = ID
        self.system_name = dhd.getSystemName(ID) or "Force Dimension device"
        if expert.enableExpertMode() == 0 and expert.setWatchdog(WATCHDOG_UNITS, ID) == 0:
            self.watchdog_armed = True
        if dhd.enableForce(True, ID) < 0:
            err = self._error()
            dhd.close(ID)
            self._id = -1
            raise DeviceError(f"{self.name}: cannot enable forces ({err})")

    def _close_link(self) -> None:
        dhd, ID = self._dhd, self._id
        self._id = -1
        if dhd is None or ID < 0:
            return
        try:
            f = self._force
            f[0] = f[1] = f[2] = 0.0
            dhd.setForce(f, ID)
            dhd.enableForce(False, ID)
        finally:
            dhd.close(ID)

    def _link_usable(self) -> bool:
        return self._id >= 0

    def _transact(self, fx_N: float, fy_N: float, fz_N: float) -> bool:
        dhd, ID = self._dhd, self._id
        if ID < 0:
            raise OSError("device closed")
        f = self._force
        f[0], f[1], f[2] = fx_N, fy_N, fz_N
        r = dhd.setForce(f, ID)
        if r < 0:
            raise OSError(f"dhdSetForce failed: {self._error()}")
        st = self._state
        if r == MOTOR_SATURATED:
            self.stats["clipped"] += 1
            st.status |= Status.CLIPPING
        else:
            st.status &= ~Status.CLIPPING
        if dhd.getPosition(self._pos, ID) < 0 or dhd.getLinearVelocity(self._vel, ID) < 0:
            raise OSError(f"reading the device failed: {self._error()}")
        p, v = self._pos, self._vel
        st.x_m, st.y_m, st.position_m = p[0], p[1], p[2]
        st.vx_m_s, st.vy_m_s, st.vz_m_s = v[0], v[1], v[2]
        b = dhd.getButtonMask(ID)
        st.buttons = b if isinstance(b, int) and b >= 0 else 0
        return True


