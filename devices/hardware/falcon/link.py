"""The Falcon's USB link over pyftdi: open the FT232R, upload the firmware, exchange 16-byte packets.

The steps and constants are libnifalcon's (:mod:`devices.hardware.falcon.protocol`); the FTDI chip is
driven by pyftdi, pure Python on pyusb (libusb). ``FalconLink(usb_device)`` takes a pyusb device (the
seam tests use: :mod:`devices.firmware.falcon_emulator`); :meth:`FalconLink.find` finds real Falcons.
Every failure is a :class:`FalconError` whose text names what went wrong and what to do.
"""

from __future__ import annotations

import errno
import time
from pathlib import Path

import usb.core
from pyftdi.ftdi import Ftdi, FtdiError
from pyftdi.usbtools import UsbTools, UsbToolsError

from . import protocol as P

#: firmware files a Falcon takes are a few kB (libnifalcon's nVent firmware); anything outside this is no firmware
FIRMWARE_SIZE_RANGE = (512, 64 * 1024)


class FalconError(OSError):
    """The Falcon could not be found, opened, loaded or talked to (the text says which and why)."""


class FalconLink:
    """One Falcon's FTDI link (see module doc). Not thread safe: one servo thread owns it."""

    def __init__(self, usb_device, name: str = "falcon") -> None:
        self.name = name
        self.ftdi = Ftdi()
        self.parser = P.PacketParser()
        self.rx_timeouts = 0
        try:
            self.ftdi.open_from_device(usb_device)
        except (FtdiError, usb.core.USBError, ValueError) as exc:
            raise FalconError(_usb_reason(name, exc, "open")) from None

    @staticmethod
    def find(index: int = 0, serial: str | None = None):
        """The pyusb device of the ``index``-th Falcon (0403:CB48) on this machine, or of serial ``serial``."""
        try:
            found = UsbTools.find_all([(P.FTDI_VID, P.FALCON_PID)], nocache=True)
        except (ValueError, usb.core.NoBackendError, UsbToolsError) as exc:
            raise FalconError(f"falcon:{index}: no USB access ({exc}); pyusb needs libusb-1.0 "
                              "(Debian: apt-get install libusb-1.0-0)") from None
        devices = sorted(found, key=lambda d: (d[0].bus or 0, d[0].address or 0))
        if serial is not None:
            devices = [d for d in devices if d[0].sn == serial]
        if not devices:
            raise FalconError(f"falcon:{index}: no Novint Falcon (USB 0403:cb48) found; is it plugged in and "
                              "powered (its own power supply), and may this user open it (udev rule, "
                              "docs/bringup.md)?")
        if index >= len(devices):
            raise FalconError(f"falcon:{index}: only {len(devices)} Falcon(s) found (falcon:0 .. "
                              f"falcon:{len(devices) - 1})")
        desc = devices[index][0]
        try:
            return UsbTools.get_device(desc)
        except (usb.core.USBError, UsbToolsError, ValueError) as exc:
            raise FalconError(_usb_reason(f"falcon:{index}", exc, "open")) from None

    # -- low level --------------------------------------------------------------------------------
    def _do(self, what: str, fn, *args):
        try:
            return fn(*args)
        except (FtdiError, usb.core.USBError, ValueError) as exc:
            raise FalconError(_usb_reason(self.name, exc, what)) from None

    def write(self, data: bytes) -> None:
        """Send ``data``; FalconError if the device is gone."""
        n = self._do("write", self.ftdi.write_data, data)
        if n != len(data):
            raise FalconError(f"{self.name}: only {n} of {len(data)} bytes written (USB stall)")

    def read(self, size: int, timeout_s: float) -> bytes:
        """Up to ``size`` bytes, waiting at most ``timeout_s``."""
        out = bytearray()
        deadline = time.monotonic() + timeout_s
        while len(out) < size:
            chunk = self._do("read", self.ftdi.read_data_bytes, size - len(out), 1)
            out += chunk
            if len(out) >= size or time.monotonic() >= deadline:
                break
        return bytes(out)

    # -- firmware ---------------------------------------------------------------------------------
    def loader_mode(self) -> None:
        """FTDI set-up for the loader and the DTR pulse that resets the Falcon into it (protocol step 1)."""
        f = self.ftdi
        self._do("purge", f.purge_buffers)
        self._do("set the latency timer", f.set_latency_timer, P.LOADER_LATENCY_MS)
        self._do("set the baud rate", f.set_baudrate, P.LOADER_BAUD)
        self._do("set the line", f.set_line_property, 8, 1, "N")
        self._do("set flow control", f.set_flowctrl, "")
        self._do("set RTS", f.set_rts, False)
        self._do("set DTR", f.set_dtr, False)
        self._do("set DTR", f.set_dtr, True)

    def upload_firmware(self, image: bytes, check_tries: int = 100) -> None:
        """Load ``image`` into the Falcon (protocol steps 1-5); FalconError naming the failing step."""
        self.loader_mode()
        for _ in range(check_tries):
            self.write(P.LOADER_CHECK)
            got = self.read(len(P.LOADER_CHECK_REPLY), 0.1)
            if got == P.LOADER_CHECK_REPLY:
                break
        else:
            raise FalconError(f"{self.name}: the Falcon's loader did not answer its check message (0A 43 0D) at "
                              "9600 baud; power-cycle the Falcon (unplug its power supply) and try again")
        self._do("set DTR", self.ftdi.set_dtr, False)
        self._do("set the baud rate", self.ftdi.set_baudrate, int(round(P.UPLOAD_BAUD)))
        self.write(P.LOADER_SYNC)
        if self.read(1, 0.5) != P.LOADER_SYNC:
            raise FalconError(f"{self.name}: the Falcon's loader did not echo 'A' at 140000 baud")
        for off in range(0, len(image), P.UPLOAD_BLOCK):
            block = image[off:off + P.UPLOAD_BLOCK]
            self.write(block)
            echo = self.read(len(block), 1.0)
            if echo != block:
                raise FalconError(f"{self.name}: firmware upload failed at byte {off + len(echo)} of {len(image)} "
                                  f"(the loader echoed {len(echo)} of {len(block)} bytes{' differently' if len(echo) == len(block) else ''})")
        self.normal_mode()

    def normal_mode(self) -> None:
        """FTDI set-up for the running firmware (protocol step 5)."""
        f = self.ftdi
        self._do("set the latency timer", f.set_latency_timer, P.NORMAL_LATENCY_MS)
        self._do("set the baud rate", f.set_baudrate, P.NORMAL_BAUD)
        self._do("purge", f.purge_buffers)
        self.parser = P.PacketParser()

    def exchange(self, packet: bytes, timeout_s: float) -> bytes | None:
        """Send one command packet and return the next status packet, or None after ``timeout_s``."""
        self.write(packet)
        deadline = time.monotonic() + timeout_s
        while True:
            pkts = self.parser.feed(self._do("read", self.ftdi.read_data_bytes, P.PACKET_SIZE, 1))
            if pkts:
                return pkts[-1]   # a late packet and the fresh one together: the fresh one counts
            if time.monotonic() >= deadline:
                self.rx_timeouts += 1
                return None

    def close(self) -> None:
        """Release the USB interface (errors ignored: the device may be gone)."""
        try:
            self.ftdi.close()
        except Exception:
            pass


def read_firmware_file(path, name: str = "falcon") -> bytes:
    """The firmware image in ``path``; FalconError when it is missing or cannot be a Falcon firmware."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise FalconError(f"{name}: firmware file {p} not found (the Falcon loads its firmware from the host at "
                          "every power-up: give the nVent firmware of the Novint driver or libnifalcon, "
                          "e.g. falcon:0?firmware=/path/to/nvent_firmware.bin)") from None
    except OSError as exc:
        raise FalconError(f"{name}: cannot read firmware file {p}: {exc}") from None
    lo, hi = FIRMWARE_SIZE_RANGE
    if not lo <= len(data) <= hi:
        raise FalconError(f"{name}: {p} is {len(data)} bytes, not a Falcon firmware ({lo}-{hi} bytes)")
    return data


def _usb_reason(name: str, exc: BaseException, what: str) -> str:
    code = getattr(exc, "errno", None) or getattr(getattr(exc, "__cause__", None), "errno", None)
    text = str(exc)
    if code == errno.EBUSY or "busy" in text.lower():
        return (f"{name}: the Falcon is in use by another program (its USB interface is claimed): close the "
                "other program (a Novint driver, another session) and try again")
    if code in (errno.ENODEV, errno.EIO) or "no such device" in text.lower():
        return f"{name}: the Falcon disconnected during {what} (USB: {text})"
    if code in (errno.EACCES, errno.EPERM) or "access denied" in text.lower():
        return (f"{name}: permission denied opening the Falcon's USB device: install the udev rule in "
                "docs/bringup.md or run as a member of its group")
    return f"{name}: USB {what} failed ({text})"
