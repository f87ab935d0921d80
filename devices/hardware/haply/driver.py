"""The Haply Inverse3 adapter: its serial protocol spoken over pyserial (no vendor library needed).

Device string ``inverse3:<port>`` (e.g. ``inverse3:/dev/ttyACM0``; options as every hardware string,
``inverse3:/dev/ttyACM0?loss_timeout_s=0.01``). Opening wakes the device (0x0A) and checks its answer;
each servo tick is one end-effector force request answered by the end effector's state
(:mod:`devices.hardware.haply.protocol`), shared machinery in :mod:`devices.hardware.threedof`.

Frame: the Inverse3 reports its end effector in its base frame (metres, z up). The device frame here is
that frame shifted to the workspace centre :data:`CENTRE_M` (x, y as the Inverse3 reports them: whether
its x points at the user depends on how the device is set on the desk; docs/bringup.md). Forces are sent
in the same axes.
"""

from __future__ import annotations

import errno
import os
import select
import time

import serial

from ...base import DeviceError
from ..threedof import ThreeAxisDevice, three_axis_info
from . import protocol as H

#: the Inverse3's workspace centre in its base frame (m) and the box around it it reaches (m), from Haply's
#: published workspace (a sphere of ~0.4 m diameter in front of the base): a conservative box
CENTRE_M = (0.0, -0.17, 0.17)
HALF_BOX_M = (0.12, 0.10, 0.10)
MAX_FORCE_N = 3.0        # continuous (Haply quotes 3.3 N continuous)
MAX_PEAK_FORCE_N = 10.0  # Haply quotes about 10 N peak
MAX_STIFFNESS_N_M = 3000.0
SERVO_RATE_HZ = 1000.0   # the host loop; the device itself runs faster (Haply quotes 4 kHz)
WAKEUP_TIMEOUT_S = 1.0


class Inverse3Device(ThreeAxisDevice):
    """The Inverse3 on serial port ``port`` (see module doc)."""

    spec_prefix = "inverse3"

    def __init__(self, port: str, baudrate: int = 115200, **options) -> None:
        super().__init__(**options)
        self.port = str(port)
        self.baudrate = int(baudrate)
        self._ser = None
        self._fd = None
        self._parser = H.ReplyParser()
        self.wakeup: H.WakeupInfo | None = None
        lo = tuple(-h for h in HALF_BOX_M)
        self.info = three_axis_info("Haply Inverse3", SERVO_RATE_HZ, lo, HALF_BOX_M, MAX_FORCE_N, MAX_PEAK_FORCE_N,
                                    MAX_STIFFNESS_N_M, 1e-5, linear=False, buttons=0)

    @property
    def name(self) -> str:
        """``inverse3:<port>``."""
        return f"inverse3:{self.port}"

    # -- link ---------------------------------------------------------------------------------------
    def _open_link(self) -> None:
        try:
            self._ser = serial.Serial(self.port, self.baudrate, timeout=0, write_timeout=1.0, exclusive=True)
        except serial.SerialException as exc:
            raise _open_error(self.name, exc) from None
        self._fd = self._ser.fileno()
        try:
            self._ser.reset_input_buffer()
        except Exception:
            pass
        self._parser = H.ReplyParser()
        try:
            self._write(H.encode_wakeup())
            replies = self._await((H.WAKEUP_REPLY,), WAKEUP_TIMEOUT_S)
        except OSError as exc:
            self._close_link()
            raise _device_error(f"{self.name}: wake-up failed ({exc})") from None
        if not replies:
            garbage = self._parser.garbage_bytes + self._parser.pending()
            self._close_link()
            raise _device_error(f"{self.name}: no answer to the Inverse3 wake-up within {WAKEUP_TIMEOUT_S:g} s "
                                f"({garbage} bytes of something else received); is it an Inverse3 on the right "
                                "port, powered and out of its vendor service's hands?")
        try:
            self.wakeup = H.decode_wakeup_reply(replies[-1][1])
        except H.ProtocolError as exc:
            self._close_link()
            raise _device_error(f"{self.name}: bad wake-up reply ({exc})") from None
        self._state.extra["device_id"] = self.wakeup.device_id

    def _close_link(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:
                pass
        self._ser = None
        self._fd = None

    def _link_usable(self) -> bool:
        return self._fd is not None

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self._fd, view):]

    def _await(self, headers: tuple, timeout_s: float) -> list:
        """Replies with one of ``headers`` arriving within ``timeout_s`` (the first whole one ends the wait)."""
        deadline = time.monotonic() + timeout_s
        got = []
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return got
            ready, _, _ = select.select((self._fd,), (), (), left)
            if not ready:
                return got
            data = os.read(self._fd, 4096)
            if not data:
                raise OSError(errno.EIO, "the port reported data but returned none (disconnected)")
            for head, payload in self._parser.feed(data):
                if head in headers:
                    got.append((head, payload))
            if got:
                return got

    def _transact(self, fx_N: float, fy_N: float, fz_N: float) -> bool:
        if self._fd is None:
            raise OSError(errno.EBADF, "port closed")
        self._write(H.encode_force(fx_N, fy_N, fz_N))
        replies = self._await((H.EE_STATE,), self.loss_timeout_s)
        self.stats["garbage_bytes"] = self._parser.garbage_bytes
        if not replies:
            self._parser.reset()  # a partial reply whose rest never came: its bytes are not the next reply's
            return False
        (x, y, z), (vx, vy, vz) = H.decode_state(replies[-1][1])
        st = self._state
        c = CENTRE_M
        st.x_m, st.y_m, st.position_m = x - c[0], y - c[1], z - c[2]
        st.vx_m_s, st.vy_m_s, st.vz_m_s = vx, vy, vz
        return True


def _device_error(text: str) -> DeviceError:
    return DeviceError(text)


def _open_error(name: str, exc: Exception):
    text = str(exc)
    if "No such file" in text or "could not open port" in text and "Errno 2" in text:
        return _device_error(f"cannot open {name}: no such port ({text}); list ports with 'python -m devices list'")
    if "Errno 13" in text or "Permission denied" in text:
        return _device_error(f"cannot open {name}: permission denied; add yourself to the 'dialout' group")
    if "Errno 11" in text or "Resource temporarily unavailable" in text or "exclusive" in text.lower():
        return _device_error(f"cannot open {name}: the port is held by another program (Haply's Inverse Service, "
                             "a terminal, another session): close it and try again")
    return _device_error(f"cannot open {name}: {text}")
