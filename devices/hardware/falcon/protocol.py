"""The Novint Falcon's USB protocol (FTDI FT232, VID 0x0403 PID 0xCB48): pure codec and constants, no I/O.

Everything here follows libnifalcon (BSD; Kyle Machulis et al.), the open driver that documents the
protocol: ``FalconFirmwareNovintSDK.cpp`` (the 16-byte packets), ``FalconCommLibUSB.cpp`` (the
FTDI set-up for the firmware upload and for normal mode) and ``FalconFirmware.cpp`` (the upload). A
contract test checks this codec against what that code computes (recorded vectors; tests/devices/hardware/contract/).

Firmware upload (the Falcon keeps no firmware: the host loads it at every power-up; the file is the
user's own, from the Novint driver or libnifalcon, never shipped here):

1. purge both FTDI buffers; latency timer 16 ms; 9600 baud (divisor 0x4138), 8N1, no flow control;
   RTS low; DTR low then high (the DTR pulse resets the Falcon's loader);
2. send ``0A 43 0D``; the loader answers ``0A 44 2C 0D`` (libnifalcon retries up to 100 times);
3. DTR low; 140000 baud (divisor 0x15: 3 MHz / 21 = 142857 baud); send ``41`` ('A'), the loader echoes it;
4. write the firmware in 62-byte blocks (a full-speed USB packet is 64 bytes, of which the FTDI chip uses
   2 for its modem status), each echoed back byte for byte (a mismatch fails the upload);
5. normal mode: latency timer 1 ms, baud divisor 0x2 (1.5 Mbaud; libnifalcon's FTD2XX variant asks for
   1456312), purge both buffers.

Normal mode: the host writes one 16-byte packet per servo cycle and the firmware answers one::

    host -> device:  '<'  c0 c0 c0 c0  c1 c1 c1 c1  c2 c2 c2 c2  ctl  0x41  '>'
    device -> host:  '<'  e0 e0 e0 e0  e1 e1 e1 e1  e2 e2 e2 e2  st   x    '>'

Each of ``c0..c2`` (motor commands) and ``e0..e2`` (encoder counts) is an int16 sent as four nibbles,
least significant first, each nibble plus 0x41 ('A'). ``ctl`` is 0x41 plus the LED and homing bits
(0x02 red, 0x04 green, 0x08 blue, 0x01 homing mode). ``st - 0x41``: bits 4-6 the three legs' homing
status (set: homed), bits 0-3 the grip's buttons.
"""

from __future__ import annotations

FTDI_VID = 0x0403
FALCON_PID = 0xCB48
PACKET_SIZE = 16
NIBBLE_BASE = 0x41
LED_RED, LED_GREEN, LED_BLUE = 0x02, 0x04, 0x08
HOMING_MODE = 0x01
HOMED_ALL = 0x07

# firmware-upload handshake (FalconCommLibUSB::setFirmwareMode)
LOADER_CHECK = bytes((0x0A, 0x43, 0x0D))
LOADER_CHECK_REPLY = bytes((0x0A, 0x44, 0x2C, 0x0D))
LOADER_SYNC = bytes((0x41,))
#: the baud rates libnifalcon's libusb back end programs (its divisors 0x4138, 0x15 and 0x2 on the FTDI's 3 MHz
#: clock; its FTD2XX back end asks for 9600, 140000 and 1456312, which the chip rounds to these)
LOADER_BAUD = 9600
UPLOAD_BAUD = 3_000_000 / 21
NORMAL_BAUD = 1_500_000
LOADER_LATENCY_MS = 16
NORMAL_LATENCY_MS = 1
UPLOAD_BLOCK = 62
#: how far an FTDI's actual baud rate may be from the one asked before the other end sees garbage (a UART
#: tolerates a few per cent; 3 % is the usual design margin)
BAUD_TOLERANCE = 0.03


class ProtocolError(ValueError):
    """A packet that does not decode (wrong length, missing '<' '>', a byte that is no nibble)."""


def _nibbles(value: int) -> bytes:
    v = int(value) & 0xFFFF  # libnifalcon masks the int's low 16 bits: the firmware reads an int16
    return bytes(((v >> s) & 0xF) + NIBBLE_BASE for s in (0, 4, 8, 12))


def _int16(b: bytes) -> int:
    v = 0
    for k, ch in enumerate(b):
        v |= ((ch - NIBBLE_BASE) & 0xF) << (4 * k)
    return v - 0x10000 if v & 0x8000 else v


def encode_command(commands, leds: int = 0, homing: bool = False) -> bytes:
    """The host's 16-byte packet: three motor commands (int16, libnifalcon's units), LEDs, homing bit."""
    if len(commands) != 3:
        raise ValueError(f"three motor commands, got {len(commands)}")
    for c in commands:
        if not -0x8000 <= int(c) <= 0x7FFF:
            raise ValueError(f"motor command {c} does not fit an int16")
    ctl = (int(leds) & 0x0E) | (HOMING_MODE if homing else 0)
    return b"<" + b"".join(_nibbles(c) for c in commands) + bytes((ctl + NIBBLE_BASE, NIBBLE_BASE)) + b">"


def decode_command(packet: bytes) -> tuple[tuple[int, int, int], int, bool]:
    """``(commands, leds, homing)`` from a host packet (the device's side; the emulator uses it)."""
    _check(packet)
    cmds = tuple(_int16(packet[1 + 4 * i:5 + 4 * i]) for i in range(3))
    ctl = packet[13] - NIBBLE_BASE
    return cmds, ctl & 0x0E, bool(ctl & HOMING_MODE)


def encode_status(encoders, homed: int = HOMED_ALL, buttons: int = 0) -> bytes:
    """The device's 16-byte packet: three encoder counts, homing status bits, grip buttons."""
    st = ((int(homed) & 0x7) << 4) | (int(buttons) & 0xF)
    return b"<" + b"".join(_nibbles(e) for e in encoders) + bytes((st + NIBBLE_BASE, NIBBLE_BASE)) + b">"


def decode_status(packet: bytes) -> tuple[tuple[int, int, int], int, int]:
    """``(encoders, homing_status, buttons)`` of a device packet (FalconFirmwareNovintSDK::formatOutput)."""
    _check(packet)
    enc = tuple(_int16(packet[1 + 4 * i:5 + 4 * i]) for i in range(3))
    st = packet[13] - NIBBLE_BASE
    return enc, (st >> 4) & 0x7, st & 0xF


def _check(packet: bytes) -> None:
    if len(packet) != PACKET_SIZE:
        raise ProtocolError(f"Falcon packet of {len(packet)} bytes, expected {PACKET_SIZE}")
    if packet[0] != 0x3C or packet[15] != 0x3E:
        raise ProtocolError(f"Falcon packet without '<' ... '>': {packet.hex()}")


class PacketParser:
    """Splits the device's byte stream into 16-byte packets, resynchronising on '<' after garbage.

    libnifalcon takes every 16 bytes as a packet and drops one whose ends are not '<' '>'; this parser
    instead skips bytes up to the next '<' whose packet ends in '>', so one stray byte costs one packet,
    not every packet after it. ``garbage_bytes`` counts what was skipped.
    """

    def __init__(self) -> None:
        self.buf = bytearray()
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Append ``data``; return the whole packets now available."""
        buf = self.buf
        buf += data
        out = []
        while len(buf) >= PACKET_SIZE:
            if buf[0] == 0x3C and buf[PACKET_SIZE - 1] == 0x3E and all(
                    NIBBLE_BASE <= b <= NIBBLE_BASE + 0x7F for b in buf[1:PACKET_SIZE - 1]):
                out.append(bytes(buf[:PACKET_SIZE]))
                del buf[:PACKET_SIZE]
                continue
            k = buf.find(b"<", 1)
            drop = k if k > 0 else len(buf)
            self.garbage_bytes += drop
            del buf[:drop]
        return out


def ftdi_baud_from_divisor(value: int, index: int = 0) -> float:
    """The baud rate an FT232R/BM makes from ``SIO_SET_BAUDRATE``'s wValue (and wIndex): 3 MHz over the
    14-bit divisor plus its eighths (AN232B-05: fraction code in bits 14-15 of wValue and bit 0 of wIndex;
    divisor 0 is 3 Mbaud, 1 is 2 Mbaud)."""
    div = value & 0x3FFF
    code = ((value >> 14) & 0x3) | ((index & 0x1) << 2)
    frac = (0.0, 0.5, 0.25, 0.125, 0.375, 0.625, 0.75, 0.875)[code]
    if div == 0 and code == 0:
        return 3_000_000.0
    if div == 1 and code == 0:
        return 2_000_000.0
    return 3_000_000.0 / (div + frac)


def baud_matches(actual: float, wanted: float) -> bool:
    """Whether a UART at ``actual`` baud reads one at ``wanted`` (within :data:`BAUD_TOLERANCE`)."""
    return abs(actual - wanted) <= BAUD_TOLERANCE * wanted
