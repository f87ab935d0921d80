"""An emulated Force Dimension device behind forcedimension-core's own mock mode (docs/bringup.md, "Force Dimension").

forcedimension-core loads the vendor's SDK when imported, unless ``__fdsdkpy_unittest__=True`` is set: then
its library handle is a ``unittest.mock.Mock`` (the package's own test mode) and every ``dhd`` function
still runs its Python side (argument conversion, the ctypes calls) against that Mock. :class:`DhdEmulator`
gives the Mock's ``dhd*`` functions the behaviour of a device: ``dhdSetForce`` applies the force to
:class:`devices.firmware.endpoint.Endpoint` (clamped to 12 N, answering ``MOTOR_SATURATED`` when it clamps)
and advances it one servo period; ``dhdGetPosition`` / ``dhdGetLinearVelocity`` write the state into the
``c_double`` objects the bindings pass; ``dhdSetWatchdog`` arms a device watchdog (no force for its
duration: forces off). The Mock keeps every call, so tests check the adapter's call order on it.

Faults: ``unplug()`` (every call then fails with -1 and "device not available", as the SDK answers a
device that went away; ``unplug_after=N``: after N forces), ``open_fails=True`` (``dhdOpenID`` returns -1: held by another program).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
import unittest.mock

from ..hardware.forcedimension.driver import load_bindings
from .endpoint import Endpoint, TapPlan

MOCK_ENV = "__fdsdkpy_unittest__"
MAX_FORCE_N = 12.0
MOTOR_SATURATED = 2


def mock_bindings():
    """``(dhd, expert, lib)``: forcedimension-core imported in its mock mode, and the Mock that stands for libdrd.

    RuntimeError when the package was already imported with the real SDK in this process (its mode is
    fixed at import)."""
    if "forcedimension_core" not in sys.modules:
        os.environ[MOCK_ENV] = "True"
    dhd, expert = load_bindings()
    lib = sys.modules["forcedimension_core.runtime"]._libdhd
    if not isinstance(lib, unittest.mock.Mock):
        raise RuntimeError("forcedimension-core was loaded with the real Force Dimension SDK in this process; "
                           "the emulator needs its mock mode (start a new process)")
    return dhd, expert, lib


class DhdEmulator:
    """Wires a device's behaviour onto forcedimension-core's Mock (see module doc)."""

    def __init__(self, plan: TapPlan | None = TapPlan(), rate_hz: float = 1000.0, open_fails: bool = False,
                 unplug_after: int = 0) -> None:
        self.dhd, self.expert, self.lib = mock_bindings()
        self.endpoint = Endpoint((0.0, 0.0, 0.0), vertical=2, plan=plan, mass_kg=0.2)
        self.dt_s = 1.0 / rate_hz
        self.open_fails = open_fails
        self.unplug_after = int(unplug_after)
        self.unplugged = False
        self.forces_enabled = False
        self.watchdog_s = 0.0
        self.last_force_t = None
        self.tripped = False
        self.error = b"no error"
        self.forces_received: list = []
        self.stats = {"set_force": 0, "watchdog_trips": 0, "saturated": 0}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        lib = self.lib
        lib.reset_mock(return_value=True, side_effect=True)
        f = self._fn
        lib.dhdGetDeviceCount.side_effect = f(lambda: 1)
        lib.dhdOpenID.side_effect = f(self._open)
        lib.dhdGetSystemName.side_effect = f(lambda ID: b"omega.3 (emulated)")
        lib.dhdEnableExpertMode.side_effect = f(lambda: 0)
        lib.dhdSetWatchdog.side_effect = f(self._set_watchdog)
        lib.dhdEnableForce.side_effect = f(self._enable_force)
        lib.dhdSetForce.side_effect = f(self._set_force)
        lib.dhdGetPosition.side_effect = f(self._get3(lambda: self.endpoint.pos))
        lib.dhdGetLinearVelocity.side_effect = f(self._get3(lambda: self.endpoint.vel))
        lib.dhdGetButtonMask.side_effect = f(lambda ID: 0)
        lib.dhdClose.side_effect = f(lambda ID: 0)
        lib.dhdErrorGetLastStr.side_effect = lambda: self.error
        # the watchdog's thread starts when the driver sets a watchdog (a device that never opens runs none)
        self._wd = None

    def _fn(self, body):
        def call(*args):
            if self.unplugged:
                self.error = b"device not available"
                return -1
            with self._lock:
                return body(*args)
        return call

    def _open(self, index):
        if self.open_fails or index != 0:
            self.error = b"cannot open device (device busy)" if self.open_fails else b"no such device"
            return -1
        return 0

    def _set_watchdog(self, units, ID):
        self.watchdog_s = units * 125e-6
        if self.watchdog_s and self._wd is None and not self._stop.is_set():
            self._wd = threading.Thread(target=self._watchdog, name="dhd-watchdog", daemon=True)
            self._wd.start()
        return 0

    def _enable_force(self, flag, ID):
        self.forces_enabled = bool(flag)
        if not flag:
            self.endpoint.set_force(0.0, 0.0, 0.0)
        return 0

    def _set_force(self, fx, fy, fz, ID):
        self.stats["set_force"] += 1
        if self.unplug_after and self.stats["set_force"] > self.unplug_after:
            self.unplugged = True
            self.endpoint.set_force(0.0, 0.0, 0.0)
            self.error = b"device not available"
            return -1
        self.forces_received.append((fx, fy, fz))
        if len(self.forces_received) > 100_000:
            del self.forces_received[:50_000]
        self.last_force_t = time.monotonic()
        self.tripped = False
        r = 0
        norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        if norm > MAX_FORCE_N:
            fx, fy, fz = (v * MAX_FORCE_N / norm for v in (fx, fy, fz))
            self.stats["saturated"] += 1
            r = MOTOR_SATURATED
        if self.forces_enabled:
            self.endpoint.set_force(fx, fy, fz)
        self.endpoint.step(self.dt_s)
        return r

    @staticmethod
    def _get3(source):
        def get(px, py, pz, ID):
            v = source()
            px.value, py.value, pz.value = v[0], v[1], v[2]
            return 0
        return get

    def _watchdog(self) -> None:
        while not self._stop.wait(0.002):
            with self._lock:
                if self.watchdog_s and self.last_force_t is not None and not self.tripped and \
                        time.monotonic() - self.last_force_t > self.watchdog_s:
                    self.tripped = True
                    self.stats["watchdog_trips"] += 1
                    self.endpoint.set_force(0.0, 0.0, 0.0)

    def applied_force(self) -> tuple:
        """The force the device produces now (N)."""
        return tuple(self.endpoint.force)

    def unplug(self) -> None:
        """The device goes away: no power to the motors, every call fails."""
        self.unplugged = True
        self.endpoint.set_force(0.0, 0.0, 0.0)

    def stop(self) -> None:
        """End the watchdog thread."""
        self._stop.set()

    def calls(self) -> list[str]:
        """The names of the ``dhd*`` functions called on the Mock, in order."""
        return [c[0] for c in self.lib.mock_calls if c[0].startswith("dhd")]
