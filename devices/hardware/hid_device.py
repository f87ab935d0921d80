"""USB HID driver: the protocol of docs/protocol.md carried in 64-byte HID reports (hidapi).

``HidDevice(0x16c0, 0x0486)`` or the device string ``hid:16c0:0486`` (options
as for serial, e.g. ``hid:16c0:0486?mode=on-device``). The report format is in
:mod:`devices.hardware.transport`; everything above the byte stream (handshake, modes,
calibration, faults) is :class:`devices.hardware.serial_device.ProtocolDevice`.

``transport=`` is the seam for tests: any object with hidapi's
``write(bytes) -> int``, ``read(size, timeout_ms) -> list[int]`` and ``close()``
(wrapped in :class:`~devices.hardware.transport.HidTransport`), or a ready Transport.
"""

from __future__ import annotations

from .serial_device import ProtocolDevice, _check_options
from .transport import HidTransport, Transport


class HidDevice(ProtocolDevice):
    """A device on USB HID, vendor/product ids ``vid``/``pid`` (ints)."""

    def __init__(self, vid: int, pid: int, serial_number: str | None = None, transport=None, **options) -> None:
        self.vid = int(vid)
        self.pid = int(pid)
        if not (0 <= self.vid <= 0xFFFF and 0 <= self.pid <= 0xFFFF):
            raise ValueError(f"HID vendor/product ids must be 16-bit, got {vid!r}:{pid!r}")
        self.serial_number = serial_number
        self._transport_seam = transport
        super().__init__(**_check_options(options, f"hid:{self.vid:04x}:{self.pid:04x}"))

    @property
    def name(self) -> str:
        """``hid:<vid>:<pid>`` (hex)."""
        return f"hid:{self.vid:04x}:{self.pid:04x}"

    def _make_transport(self) -> Transport:
        seam = self._transport_seam
        if seam is None:
            return HidTransport.open(self.vid, self.pid, self.serial_number)
        if isinstance(seam, Transport):
            return seam
        return HidTransport(seam, self.name)
