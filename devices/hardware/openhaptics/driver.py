"""The 3D Systems Touch (Phantom Omni class) adapter: OpenHaptics' HD API through ctypes.

Device string ``touch:<name>`` (``touch:Default Device``, or the name given in 3D Systems' Touch Setup).
Needs OpenHaptics (libHD, 3.0 or newer: the vendor's installer, or ``$HFAM_OPENHAPTICS_LIB``). Opening
initialises the device, enables force output, schedules the servo callback and starts the scheduler. The
callback is compiled by numba (:mod:`devices.hardware.openhaptics.servo`) and runs in OpenHaptics' own
1 kHz thread without Python: it reads position, velocity and buttons into a shared block, applies the
host's latest force (its magnitude limited, a NaN one zeroed) and zeroes it when the host has not
commanded for 20 ticks (its own watchdog, in the servo thread). The host's transaction writes the force
and takes the newest state the callback wrote (the device's clock paces the device; a host at the same
rate sees the occasional repeated sample); no new tick for ``loss_timeout_s`` is a lost reply. A state's
``t_s`` is the servo thread's tick count over its rate, the time the device sampled it: a state read twice
has the same time, and the servo laws' velocity fits skip it (``renderer.ring``).

Frame: HD's x (right), y (up), z (towards the user), millimetres, become the device frame's y, z, x in
metres (``x = z_hd, y = x_hd, z = y_hd``: a cyclic permutation, right-handed), origin at the centre of the
device's usable workspace.
"""

from __future__ import annotations

import ctypes
import time

from ...base import DeviceError, Status
from ..threedof import ThreeAxisDevice, three_axis_info
from . import hdapi as A

SERVO_RATE_HZ = 1000.0
MAX_FORCE_N = 0.88          # Touch: 0.88 N continuous (3D Systems' data sheet)
MAX_PEAK_FORCE_N = 3.3      # Touch: 3.3 N maximum exertable force
MAX_STIFFNESS_N_M = 1260.0  # Touch: x 1.26, y 2.31, z 1.02 N/mm (the mean of x and z, the softer axes)
HALF_BOX_M = (0.035, 0.08, 0.06)
POSITION_RESOLUTION_M = 5.5e-5   # Touch: > 450 dpi
WATCHDOG_TICKS = 20
#: how long opening waits for the servo callback's first tick (1 ms on a working device; a loaded host can delay it)
FIRST_TICK_TIMEOUT_S = 1.0


class TouchDevice(ThreeAxisDevice):
    """A Touch/Phantom named ``device_name`` (see module doc). ``hd`` is the test seam (an :class:`hdapi.HD`)."""

    spec_prefix = "touch"

    def __init__(self, device_name: str = "Default Device", hd: A.HD | None = None, **options) -> None:
        super().__init__(**options)
        self.device_name = str(device_name)
        self._hd = hd
        self._handle = None
        self._sched = None
        self._cb = None
        self._block = None
        self._mv = None
        self._buttons = None
        self.model = ""
        self._origin_hd_mm = (0.0, 0.0, 0.0)
        self._last_tick = -1.0
        self._last_tick_t = 0.0
        self.info = three_axis_info("3D Systems Touch", SERVO_RATE_HZ, tuple(-h for h in HALF_BOX_M), HALF_BOX_M,
                                    MAX_FORCE_N, MAX_PEAK_FORCE_N, MAX_STIFFNESS_N_M, POSITION_RESOLUTION_M,
                                    linear=False, buttons=2)
        self.stats.update(callback_ticks=0)

    @property
    def name(self) -> str:
        """``touch:<name>``."""
        return f"touch:{self.device_name}"

    def _check_error(self, what: str) -> None:
        info = self._hd.lib.hdGetError()
        if info.errorCode != A.HD_SUCCESS:
            raise DeviceError(f"{self.name}: {what}: {A.error_text(self._hd, info)}")

    def _open_link(self) -> None:
        if self._hd is None:
            try:
                self._hd = A.load()
            except A.HDLibraryError as exc:
                raise DeviceError(f"{self.name}: {exc}") from None
        hd = self._hd
        lib = hd.lib
        h = lib.hdInitDevice(self.device_name.encode())
        if h == A.HD_INVALID_HANDLE:
            info = lib.hdGetError()
            raise DeviceError(f"{self.name}: cannot initialise the device ({A.error_text(hd, info)}); is it plugged "
                              "in, configured in Touch Setup under this name, and not used by another program?")
        self._handle = h
        try:
            raw = lib.hdGetString(A.HD_DEVICE_MODEL_TYPE)
            self.model = raw.decode("ascii", "replace") if raw else "Touch"
            dims = (ctypes.c_double * 6)()
            lib.hdGetDoublev(A.HD_USABLE_WORKSPACE_DIMENSIONS, dims)
            self._origin_hd_mm = tuple(0.5 * (dims[i] + dims[i + 3]) for i in range(3))
            lib.hdEnable(A.HD_FORCE_OUTPUT)
            self._check_error("enabling force output")
            from .servo import compile_callback, new_block  # deferred: numba, 0.3 s CPU to import, only for a Touch
            self._cb = compile_callback(hd)
            self._block, self._buttons = new_block(MAX_PEAK_FORCE_N, WATCHDOG_TICKS)
            self._mv = memoryview(self._block)   # plain Python floats in and out: no numpy scalar on the servo path
            self._sched = lib.hdScheduleAsynchronous(ctypes.c_void_p(self._cb.address),
                                                     ctypes.c_void_p(self._block.ctypes.data),
                                                     A.HD_MAX_SCHEDULER_PRIORITY)
            lib.hdStartScheduler()
            self._check_error("starting the scheduler")
            # no state exists before the callback's first tick (the block holds zeros, not a position): wait for it,
            # so that the first read is a real sample
            self._last_tick, deadline = -1.0, time.monotonic() + FIRST_TICK_TIMEOUT_S
            while self._block[7] < 1.0:
                if time.monotonic() > deadline:
                    raise DeviceError(f"{self.name}: the servo loop did not run within {FIRST_TICK_TIMEOUT_S:g} s "
                                      "of starting the scheduler; is the device powered and calibrated (Touch Setup)?")
                time.sleep(0.0005)
        except BaseException:
            self._close_link()
            raise

    def _close_link(self) -> None:
        hd, h = self._hd, self._handle
        self._handle = None
        if hd is None or h is None:
            return
        b = self._block
        if b is not None:
            b[8] = b[9] = b[10] = 0.0
            b[11] += 1.0
            t = b[7]
            deadline = time.monotonic() + 0.05
            while b[7] < t + 2 and time.monotonic() < deadline:   # the zero reached the device
                time.sleep(0.001)
        lib = hd.lib
        lib.hdStopScheduler()
        if self._sched is not None:
            lib.hdUnschedule(self._sched)
            self._sched = None
        lib.hdDisableDevice(h)

    def _link_usable(self) -> bool:
        return self._handle is not None

    def _sample_time(self, now: float) -> float:
        """The newest state's time on the device's own clock: its servo tick count over the servo rate (s)."""
        return self._last_tick / SERVO_RATE_HZ

    def read(self):
        """As the base class's, with the callback's own watchdog reported (it zeroes the force in the servo thread)."""
        st = super().read()
        mv = self._mv if self._block is not None else None
        if mv is not None and mv[15]:
            st.status |= Status.WATCHDOG_TRIPPED
        return st

    def _transact(self, fx_N: float, fy_N: float, fz_N: float) -> bool:
        b = self._mv if self._block is not None else None
        if b is None or self._handle is None:
            raise OSError("device closed")
        # device frame -> HD: x_hd = y, y_hd = z, z_hd = x
        b[8], b[9], b[10] = fy_N, fz_N, fx_N
        b[11] += 1.0
        # the servo thread runs on the device's own 1 kHz clock: take its newest state without waiting for the
        # next tick (waiting would pace the host loop twice); no new tick for loss_timeout_s is a lost reply
        tick = b[7]
        now = time.monotonic()
        if tick != self._last_tick:
            self._last_tick, self._last_tick_t = tick, now
        elif now - self._last_tick_t > self.loss_timeout_s:
            return False
        info = self._hd.lib.hdGetError()
        if info.errorCode != A.HD_SUCCESS:
            raise OSError(f"device fault: {A.error_text(self._hd, info)}")
        st = self._state
        o = self._origin_hd_mm
        st.x_m, st.y_m, st.position_m = (b[2] - o[2]) * 1e-3, (b[0] - o[0]) * 1e-3, (b[1] - o[1]) * 1e-3
        st.vx_m_s, st.vy_m_s, st.vz_m_s = b[5] * 1e-3, b[3] * 1e-3, b[4] * 1e-3
        st.buttons = int(self._buttons[0])   # (an int32 cell: numpy's int, converted)
        if b[15]:
            st.status |= Status.WATCHDOG_TRIPPED
        self.stats["callback_ticks"] = int(b[7])
        return True
