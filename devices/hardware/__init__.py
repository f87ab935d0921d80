"""Drivers for real devices: serial and USB HID, their byte transports, the wire protocol, calibration.

``wire_protocol``  frames, CRC-16 and the streaming parser (docs/protocol.md)
``transport``      raw byte transports (pyserial, hidapi)
``serial_device``  :class:`ProtocolDevice` and the serial driver :class:`SerialDevice`
``hid_device``     the USB HID driver :class:`HidDevice`
``calibration``    raw-to-SI calibration uploaded to a device (:class:`Calibration`)

Nothing here imports the firmware mirror or the emulator (:mod:`devices.firmware`).
"""
