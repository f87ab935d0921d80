"""An emulator of the Haply Inverse3's serial protocol on a pseudo-terminal (docs/bringup.md, "Haply Inverse3").

It answers the requests of :mod:`devices.hardware.haply.protocol` on the master side of a pty, as the
device does on its USB CDC port: wake-up -> device information, end-effector force -> end-effector state
(position and velocity), status queries -> temperature, motor currents, power, device id and firmware
UUIDs. The handle is :class:`devices.firmware.endpoint.Endpoint` (a point mass held by a simulated hand
that taps along the vertical axis, z here: Haply's base frame has z up), advanced one device tick per
force request (host-paced, as the serial board's emulator in streaming mode), so a test sees the same
states however loaded the machine is.

Emulated behaviour the vendor does not publish (docs/bringup.md says so): the device clamps a force to
``max_force_N`` per axis-vector norm and zeroes it when no force request came for ``watchdog_ms``
(reported as a zero force in ``applied_force``); a request whose floats are not finite is ignored (the
last force is held to zero).

Faults for tests (``faults=`` dict): ``garbage_every=N`` puts random bytes before every N-th reply,
``silent=1`` never answers, ``wrong_device=1`` answers the wake-up with a reply of another size (another
device on the port), ``disconnect_after=N`` closes the pty after N force requests (an unplugged cable),
``stall_at=N, stall_s=S`` stops answering for S seconds before the N-th force reply, ``freeze_at=N``
repeats the same state from the N-th force reply on (a device whose sensing stopped).
"""

from __future__ import annotations

import fcntl
import math
import os
import random
import select
import threading
import time
import tty
import uuid
from collections import deque

from ..hardware.haply import protocol as H
from .endpoint import Endpoint, TapPlan

#: the Inverse3's workspace centre in its base frame (m); the emulated hand taps through it along z
CENTRE_M = (0.0, -0.17, 0.17)
MAX_FORCE_N = 10.0   # what the emulated device clamps to (Haply quotes up to 10 N peak; docs/bringup.md)
FAULT_KEYS = ("garbage_every", "silent", "wrong_device", "disconnect_after", "stall_at", "stall_s", "freeze_at")


class Inverse3Emulator:
    """The emulated device on a pty master (see module doc). ``open_pty()`` returns the port's path."""

    def __init__(self, plan: TapPlan | None = TapPlan(), rate_hz: float = 1000.0, watchdog_ms: float = 50.0,
                 faults: dict | None = None, seed: int = 0, device_id: int = 0x1A2B,
                 max_force_N: float = MAX_FORCE_N) -> None:
        faults = dict(faults or {})
        unknown = sorted(set(faults) - set(FAULT_KEYS))
        if unknown:
            raise ValueError(f"unknown Inverse3 emulator fault(s) {', '.join(unknown)}; valid: {', '.join(FAULT_KEYS)}")
        self.faults = faults
        self.endpoint = Endpoint(CENTRE_M, vertical=2, plan=plan)
        self.dt_s = 1.0 / float(rate_hz)
        self.watchdog_s = float(watchdog_ms) * 1e-3
        self.max_force_N = float(max_force_N)
        self.rng = random.Random(seed)
        self.info = H.WakeupInfo(device_id, 3, 2, 7, uuid.UUID(int=0x1A2B3C4D5E6F00112233445566778899 + seed))
        self.firmware_uuid = uuid.UUID(int=0x0F1E2D3C4B5A69788796A5B4C3D2E1F0)
        self.parser = H.RequestParser()
        self.fd: int | None = None
        self.slave_fd: int | None = None
        self.awake = False
        self.last_force_t = None
        self.tripped = False
        # the last force requests as decoded and the states answered (for tests; bounded)
        self.forces_received: deque = deque(maxlen=100_000)
        self.states_sent: deque = deque(maxlen=100_000)
        self.currents_sent: deque = deque(maxlen=1000)   # (currents (A), whether the watchdog had zeroed the motors)
        self.stats = {"requests": 0, "force_requests": 0, "replies": 0, "watchdog_trips": 0, "garbage_sent": 0,
                      "bad_requests": 0, "ticks": 0}
        self.disconnected = False
        self._frozen = None

    # -- pty ----------------------------------------------------------------------------
    def open_pty(self) -> str:
        """Create the pty pair (both ends raw); return the slave's path (the host's port)."""
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        fcntl.fcntl(master, fcntl.F_SETFL, fcntl.fcntl(master, fcntl.F_GETFL) | os.O_NONBLOCK)
        self.fd, self.slave_fd = master, slave
        return os.ttyname(slave)

    def close(self) -> None:
        """Close both ends (idempotent): the host then sees its port fail, as when a cable is pulled."""
        for name in ("fd", "slave_fd"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    def _write(self, data: bytes) -> None:
        fd = self.fd
        if fd is None:
            return
        view = memoryview(data)
        deadline = time.monotonic() + 0.2
        while view:
            try:
                view = view[os.write(fd, view):]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    return
                select.select((), (fd,), (), 0.01)
            except OSError:
                return

    def _reply(self, data: bytes) -> None:
        f = self.faults
        self.stats["replies"] += 1
        if f.get("garbage_every") and self.stats["replies"] % int(f["garbage_every"]) == 0:
            junk = bytes(self.rng.choice((0x00, 0x11, 0x3C, 0x7F, 0xFE)) for _ in range(self.rng.randrange(1, 6)))
            self.stats["garbage_sent"] += len(junk)
            data = junk + data
        self._write(data)

    # -- the device -----------------------------------------------------------------------
    def applied_force(self) -> tuple[float, float, float]:
        """The force the emulated motors produce now (N)."""
        return tuple(self.endpoint.force)

    def handle(self, code: int, payload: bytes) -> None:
        """Act on one request (the device's dispatch)."""
        self.stats["requests"] += 1
        f = self.faults
        if f.get("silent"):
            return
        ep = self.endpoint
        if code == H.WAKEUP:
            self.awake = True
            if f.get("wrong_device"):
                self._reply(bytes((H.WAKEUP_REPLY,)) + bytes(7))  # too short: another device's answer
            else:
                self._reply(H.encode_wakeup_reply(self.info))
            return
        if code in (H.EE_FORCE, H.EE_POSITION, H.JOINT_TORQUES, H.JOINT_ANGLES):
            x, y, z = H.VEC3.unpack(payload)
            if code == H.EE_FORCE:
                self.stats["force_requests"] += 1
                self.forces_received.append((x, y, z))
                if not all(math.isfinite(v) for v in (x, y, z)):
                    self.stats["bad_requests"] += 1
                    x = y = z = 0.0
                norm = math.sqrt(x * x + y * y + z * z)
                if norm > self.max_force_N:
                    s = self.max_force_N / norm
                    x, y, z = x * s, y * s, z * s
                ep.set_force(x, y, z)
                self.last_force_t = time.monotonic()
                self.tripped = False
                n = self.stats["force_requests"]
                if f.get("disconnect_after") and n > int(f["disconnect_after"]):
                    self.disconnected = True
                    self.close()
                    return
                if f.get("stall_at") and n == int(f["stall_at"]):
                    time.sleep(float(f.get("stall_s", 0.1)))
            ep.step(self.dt_s)
            self.stats["ticks"] += 1
            if f.get("freeze_at") and self.stats["force_requests"] >= int(f["freeze_at"]):
                if self._frozen is None:
                    self._frozen = (tuple(ep.pos), tuple(ep.vel))
                pos, vel = self._frozen
            else:
                pos, vel = ep.pos, ep.vel
            header = H.EE_STATE if code in (H.EE_FORCE, H.EE_POSITION) else H.JOINT_STATES
            self.states_sent.append((tuple(pos), tuple(vel)))
            self._reply(H.encode_state(pos, vel, header))
            return
        if code == H.TEMPERATURE:
            self._reply(bytes((H.TEMPERATURE,)) + H.F32.pack(31.5))
        elif code == H.CURRENTS:
            fx, fy, fz = ep.force
            self.currents_sent.append(((0.1 * fx, 0.1 * fy, 0.1 * fz), self.tripped))
            self._reply(bytes((H.CURRENTS,)) + H.VEC3.pack(0.1 * fx, 0.1 * fy, 0.1 * fz))
        elif code == H.POWER:
            self._reply(bytes((H.POWER, 1)))
        elif code == H.DEVICE_INFO_EXT:
            sub = payload[0]
            if sub == H.INFO_EXT_DEVICE_ID:
                self._reply(H.encode_info_ext_reply(sub, self.info.uuid))
            elif sub == H.INFO_EXT_FIRMWARE:
                self._reply(H.encode_info_ext_reply(sub, self.firmware_uuid))
            else:
                self.stats["bad_requests"] += 1

    def _check_watchdog(self, now: float) -> None:
        if self.last_force_t is not None and not self.tripped and now - self.last_force_t > self.watchdog_s:
            self.tripped = True
            self.stats["watchdog_trips"] += 1
            self.endpoint.set_force(0.0, 0.0, 0.0)

    def serve(self, stop: threading.Event) -> None:
        """Answer requests until ``stop`` is set or the disconnect fault fires."""
        while not stop.is_set() and self.fd is not None:
            try:
                ready, _, _ = select.select((self.fd,), (), (), 0.005)
            except (OSError, ValueError):
                break
            if ready:
                try:
                    data = os.read(self.fd, 65536)
                except BlockingIOError:
                    data = b""
                except OSError:  # EIO: no host has the port open right now
                    data = b""
                    time.sleep(0.005)
                for code, payload in self.parser.feed(data):
                    self.handle(code, payload)
                    if self.disconnected:
                        return
            self._check_watchdog(time.monotonic())


class EmulatorThread:
    """An :class:`Inverse3Emulator` serving its pty from a daemon thread; ``stop()`` ends it (a context manager)."""

    def __init__(self, emulator: Inverse3Emulator) -> None:
        self.emulator = emulator
        self.port = emulator.open_pty()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=emulator.serve, args=(self._stop,), name="inverse3-emulator",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving and release the pty."""
        self._stop.set()
        self._thread.join(2.0)
        self.emulator.close()

    def __enter__(self) -> "EmulatorThread":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def start_inverse3_emulator(**kwargs) -> EmulatorThread:
    """Start an emulator thread (keywords as :class:`Inverse3Emulator`); connect with ``inverse3:<.port>``."""
    return EmulatorThread(Inverse3Emulator(**kwargs))
