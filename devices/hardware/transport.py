"""Byte transports under the protocol: a serial/CDC port (pyserial) and USB HID reports (hidapi).

A transport moves raw bytes; framing lives in :mod:`devices.hardware.wire_protocol`. Both
transports raise :class:`TransportClosed` when the other end is gone, so the
device driver can turn every kind of disconnect into one clear error.

HID report format (64-byte reports, report id 0): byte 0 is the number of
stream bytes that follow (0..63), bytes 1..n carry the protocol byte stream,
the rest is zero padding. :func:`pack_reports` / :func:`unpack_report` are the
seam tests use with recorded report bytes (no virtual HID exists here).
"""

from __future__ import annotations

import os
import select
import time

import serial

try:  # hidapi is optional: without it, opening a HID device is one error (below), importing this is not
    import hid
except ImportError as _exc:  # pragma: no cover - hidapi is a dependency
    hid = None
    _HID_MISSING = str(_exc)

HID_REPORT_SIZE = 64
HID_DATA_PER_REPORT = HID_REPORT_SIZE - 1


class TransportClosed(OSError):
    """The device end of the link disappeared (unplugged, port closed, emulator gone)."""


class Transport:
    """Minimal byte pipe. ``read(timeout_s)`` returns b"" on timeout, never blocks longer."""

    name = "transport"

    def write(self, data: bytes) -> None:
        """Send all of ``data``; TransportClosed if the link is gone."""
        raise NotImplementedError

    def read(self, timeout_s: float) -> bytes:
        """Bytes received within ``timeout_s`` seconds (possibly none); TransportClosed if the link is gone."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the link (idempotent)."""
        raise NotImplementedError


class SerialTransport(Transport):
    """A pyserial port. On POSIX, reads and writes go straight to the file descriptor with ``select``
    (pyserial's per-call timeout setter reconfigures the tty, which costs more than a servo tick)."""

    def __init__(self, port: str, baudrate: int = 921600) -> None:
        self.name = port
        try:
            self._ser = serial.Serial(port, baudrate, timeout=0, write_timeout=1.0)
        except (serial.SerialException, OSError) as exc:
            raise TransportClosed(f"cannot open serial port {port}: {exc}") from None
        try:
            self._fd = self._ser.fileno()
        except Exception:  # pragma: no cover - non-POSIX pyserial backends
            self._fd = None
        try:
            self._ser.reset_input_buffer()
        except Exception:
            pass

    def write(self, data: bytes) -> None:
        """Send all of ``data`` on the port; TransportClosed if the port is gone (unplugged)."""
        try:
            if self._fd is not None:
                view = memoryview(data)
                while view:
                    n = os.write(self._fd, view)
                    view = view[n:]
            else:  # pragma: no cover
                self._ser.write(data)
        except OSError as exc:
            raise TransportClosed(f"write to {self.name} failed: {exc}") from None

    def read(self, timeout_s: float) -> bytes:
        """Whatever arrived within ``timeout_s`` s (``select`` on the descriptor); TransportClosed if the port is gone."""
        fd = self._fd
        if fd is None:  # pragma: no cover
            self._ser.timeout = timeout_s
            return self._ser.read(max(1, self._ser.in_waiting))
        try:
            ready, _, _ = select.select((fd,), (), (), max(0.0, timeout_s))
            if not ready:
                return b""
            data = os.read(fd, 65536)
        except OSError as exc:  # EIO: the pty master (or USB CDC device) is gone
            raise TransportClosed(f"read from {self.name} failed: {exc}") from None
        if not data:
            raise TransportClosed(f"{self.name} reported readiness but returned no data (disconnected)")
        return data

    def close(self) -> None:
        """Close the port (errors ignored: it may already be gone)."""
        try:
            self._ser.close()
        except Exception:
            pass


def pack_reports(data: bytes) -> list[bytes]:
    """Split a byte stream into 64-byte HID output reports (length byte + data + zero padding)."""
    reports = []
    for start in range(0, len(data), HID_DATA_PER_REPORT):
        chunk = data[start:start + HID_DATA_PER_REPORT]
        reports.append(bytes((len(chunk),)) + chunk + bytes(HID_DATA_PER_REPORT - len(chunk)))
    return reports


def unpack_report(report: bytes) -> bytes:
    """Stream bytes carried by one 64-byte input report; ValueError names what is wrong."""
    if len(report) != HID_REPORT_SIZE:
        raise ValueError(f"HID report must be {HID_REPORT_SIZE} bytes, got {len(report)}")
    n = report[0]
    if n > HID_DATA_PER_REPORT:
        raise ValueError(f"HID report length byte {n} exceeds {HID_DATA_PER_REPORT}")
    return bytes(report[1:1 + n])


class HidTransport(Transport):
    """USB HID through a device handle with hidapi's ``write(list)`` / ``read(size, timeout_ms)`` API.

    ``handle`` is the seam: a ``hid.device()`` for real hardware, or any object
    with the same two methods and ``close()`` (tests pass recorded reports).
    Output reports are written with report id 0 prepended (65 bytes), as hidapi expects.
    """

    def __init__(self, handle, name: str = "hid") -> None:
        self._h = handle
        self.name = name
        self.bad_reports = 0

    @classmethod
    def open(cls, vid: int, pid: int, serial_number: str | None = None) -> "HidTransport":
        """Open the USB HID device ``vid:pid`` (first match, or the given ``serial_number``).

        Raises
        ------
        TransportClosed
            hidapi is missing, or no such device can be opened (the message names the device).
        """
        if hid is None:  # pragma: no cover - hidapi is a dependency
            raise TransportClosed(f"hidapi is not installed: {_HID_MISSING}")
        name = f"hid:{vid:04x}:{pid:04x}"
        if not hasattr(hid, "device"):
            raise TransportClosed("the installed 'hid' module is not hidapi (pip install hidapi, not hid)")
        handle = hid.device()
        try:
            if serial_number:
                handle.open(vid, pid, serial_number)
            else:
                handle.open(vid, pid)
        except (OSError, IOError) as exc:
            found = [f"{d['vendor_id']:04x}:{d['product_id']:04x}" for d in hid.enumerate()]
            raise TransportClosed(f"cannot open {name}: {exc}; HID devices present: {found or 'none'}") from None
        return cls(handle, name)

    def write(self, data: bytes) -> None:
        """Send ``data`` as 64-byte HID output reports (:func:`pack_reports`); TransportClosed on failure."""
        for report in pack_reports(data):
            try:
                n = self._h.write(b"\x00" + report)
            except (OSError, IOError, ValueError) as exc:
                raise TransportClosed(f"write to {self.name} failed: {exc}") from None
            if n is not None and n < 0:
                raise TransportClosed(f"write to {self.name} failed (hidapi returned {n})")

    def read(self, timeout_s: float) -> bytes:
        """Protocol bytes from the input reports that arrive within ``timeout_s`` s; TransportClosed on failure."""
        deadline = time.monotonic() + timeout_s
        out = b""
        while True:
            ms = max(0, int((deadline - time.monotonic()) * 1000))
            try:
                report = self._h.read(HID_REPORT_SIZE, ms if not out else 0)
            except (OSError, IOError, ValueError) as exc:
                raise TransportClosed(f"read from {self.name} failed: {exc}") from None
            if not report:
                return out
            try:
                out += unpack_report(bytes(report))
            except ValueError:
                self.bad_reports += 1
            if len(out) > 4096 or time.monotonic() > deadline:
                return out

    def close(self) -> None:
        """Close the HID handle (errors ignored)."""
        try:
            self._h.close()
        except Exception:
            pass
