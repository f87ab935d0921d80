"""An emulated Novint Falcon behind an emulated FTDI FT232R, as a pyusb back end (docs/bringup.md, "Novint Falcon").

No virtual USB device can be made on these machines, so the seam is pyusb's own back-end interface
(``usb.backend.IBackend``): :class:`VirtualFalconBackend` enumerates one FT232R with the Falcon's ids
(0403:CB48) and answers the control and bulk transfers pyftdi makes (the FTDI vendor requests: reset and
purge, modem control, flow control, baud rate, line properties, latency timer, bit mode, modem status;
bulk IN packets carry the chip's two modem-status bytes). The driver above it is the real pyftdi
(``Ftdi.open_from_device``), unchanged.

Behind the FTDI is :class:`FalconModel`, the Falcon's microcontroller as libnifalcon describes it
(:mod:`devices.hardware.falcon.protocol`): at power-up a loader that answers the check message at
9600 baud after a DTR pulse, takes 'A' at 142857 baud and echoes every firmware byte; after the host
switches to normal mode it runs the firmware it was given, if that is the image it accepts (``firmware=``:
the emulator stands for one Falcon with one correct firmware file; any other file leaves it silent, as a
real Falcon is with a wrong file). Running, it answers each 16-byte command packet with one status
packet and advances the handle one servo period (1 ms): motor commands become a Cartesian force through
libnifalcon's kinematics (:func:`devices.hardware.falcon.kinematics.force_from_commands`), the handle is
:class:`devices.firmware.endpoint.Endpoint` (a hand tapping along y, the Falcon's vertical axis), and the
encoders come back through the inverse kinematics. The model runs in the caller's thread, inside the
transfers (deterministic, nothing to schedule), plus a watchdog thread: no command for ``watchdog_ms``
zeroes the motors (emulated behaviour; the real firmware's is not published).

Faults: ``unplug()`` (every later transfer fails with ENODEV, as a pulled cable; ``unplug_after=N``: after
N command packets), ``busy=True`` (the
interface is claimed by another program: EBUSY), ``garbage_every=N`` (random bytes before every N-th
status packet), ``stall_at=N, stall_s=S`` (the N-th reply comes S seconds late), ``corrupt_echo_at=N`` (the
loader echoes firmware byte N wrongly, as a noisy cable would: the host must stop the upload).
"""

from __future__ import annotations

import array
import errno
import math
import random
import threading
import time
from types import SimpleNamespace

import usb.backend
import usb.core

from ..hardware.falcon import kinematics as K
from ..hardware.falcon import protocol as P
from .endpoint import Endpoint, TapPlan

# FTDI vendor requests (libftdi's ftdi.h / pyftdi.ftdi.Ftdi)
SIO_RESET, SIO_SET_MODEM_CTRL, SIO_SET_FLOW_CTRL, SIO_SET_BAUDRATE, SIO_SET_DATA = 0, 1, 2, 3, 4
SIO_POLL_MODEM_STATUS, SIO_SET_LATENCY_TIMER, SIO_GET_LATENCY_TIMER, SIO_SET_BITMODE, SIO_READ_PINS = 5, 9, 10, 11, 12
MAX_PACKET = 64
STATUS_BYTES = bytes((0x01, 0x60))  # FT232R modem status: CTS/DSR low, TX empty (THRE, TEMT)
MAX_FORCE_N = 9.0  # what the emulated Falcon's amplifiers reach at the centre (Novint quotes about 2 lb, 8.9 N)


class FalconModel:
    """The Falcon's microcontroller (loader, firmware) and the handle (see module doc)."""

    def __init__(self, firmware: bytes, plan: TapPlan | None = TapPlan(), watchdog_ms: float = 50.0,
                 garbage_every: int = 0, stall_at: int = 0, stall_s: float = 0.0, seed: int = 0,
                 rate_hz: float = 1000.0, unplug_after: int = 0, corrupt_echo_at: int | None = None) -> None:
        if not firmware:
            raise ValueError("the emulated Falcon needs the firmware image it accepts")
        self.accepted = bytes(firmware)
        self.endpoint = Endpoint(K.WORKSPACE_CENTRE, vertical=1, plan=plan, mass_kg=0.12)
        self.dt_s = 1.0 / rate_hz
        self.watchdog_s = watchdog_ms * 1e-3
        self.garbage_every, self.stall_at, self.stall_s = int(garbage_every), int(stall_at), float(stall_s)
        self.unplug_after = int(unplug_after)
        self.corrupt_echo_at = None if corrupt_echo_at is None else int(corrupt_echo_at)
        self.backend = None   # set by VirtualFalconBackend (the unplug fault pulls its cable)
        self.rng = random.Random(seed)
        self.state = "off"          # off -> loader -> checked -> uploading -> running | dead
        self.image = bytearray()
        self.rx = bytearray()       # host -> device bytes not yet acted on (normal mode)
        self.tx = bytearray()       # device -> host bytes (the FTDI's receive FIFO)
        self.baud = 9600.0
        self.dtr = False
        self.homed = 0
        self.leds = 0
        self.commands = (0, 0, 0)
        self.last_cmd_t: float | None = None
        self.tripped = False
        self.lock = threading.Lock()
        self.stats = {"packets_in": 0, "packets_out": 0, "watchdog_trips": 0, "uploads": 0, "garbage_sent": 0,
                      "bad_packets": 0}
        self.commands_received: list = []

    # -- what the FTDI delivers -------------------------------------------------------------
    def set_dtr(self, high: bool) -> None:
        """A DTR edge: low -> high at the loader's baud rate resets the Falcon into its loader."""
        if high and not self.dtr and P.baud_matches(self.baud, P.LOADER_BAUD):
            self.state = "loader"
            self.image.clear()
            self.rx.clear()
            self.homed = 0
            self.endpoint.set_force(0.0, 0.0, 0.0)
        self.dtr = high

    def set_baud(self, baud: float) -> None:
        """A new baud rate; switching to normal speed after an upload starts the firmware (or not)."""
        self.baud = baud
        if self.state == "uploading" and P.baud_matches(baud, P.NORMAL_BAUD):
            self.stats["uploads"] += 1
            self.state = "running" if bytes(self.image) == self.accepted else "dead"
            self.rx.clear()

    def receive(self, data: bytes) -> None:
        """Bytes the host sent (after the FTDI's UART)."""
        with self.lock:
            st = self.state
            if st == "loader" and P.baud_matches(self.baud, P.LOADER_BAUD):
                self.rx += data
                if self.rx.endswith(P.LOADER_CHECK):
                    self.rx.clear()
                    self.tx += P.LOADER_CHECK_REPLY
                    self.state = "checked"
            elif st == "checked" and P.baud_matches(self.baud, P.UPLOAD_BAUD) and not self.dtr:
                if data[:1] == P.LOADER_SYNC:
                    self.tx += P.LOADER_SYNC
                    self.state = "uploading"
                    data = data[1:]
                if self.state == "uploading" and data:
                    self._upload(data)
            elif st == "uploading" and P.baud_matches(self.baud, P.UPLOAD_BAUD):
                self._upload(data)
            elif st == "running" and P.baud_matches(self.baud, P.NORMAL_BAUD):
                self.rx += data
                while len(self.rx) >= P.PACKET_SIZE:
                    k = self.rx.find(b"<")
                    if k < 0:
                        self.rx.clear()
                        break
                    del self.rx[:k]
                    if len(self.rx) < P.PACKET_SIZE:
                        break
                    packet = bytes(self.rx[:P.PACKET_SIZE])
                    del self.rx[:P.PACKET_SIZE]
                    self._on_packet(packet)
            # anything else (wrong baud rate, a dead firmware, powered off) goes unanswered

    def _upload(self, data: bytes) -> None:
        """Firmware bytes: kept, and echoed back byte for byte (the ``corrupt_echo_at`` fault flips one)."""
        off = len(self.image)
        self.image += data
        echo = bytearray(data)
        k = self.corrupt_echo_at
        if k is not None and off <= k < off + len(echo):
            echo[k - off] ^= 0x5A
        self.tx += echo

    def _on_packet(self, packet: bytes) -> None:
        try:
            cmds, leds, homing = P.decode_command(packet)
        except P.ProtocolError:
            self.stats["bad_packets"] += 1
            return
        self.stats["packets_in"] += 1
        self.commands_received.append(cmds)
        if len(self.commands_received) > 100_000:
            del self.commands_received[:50_000]
        self.leds = leds
        if homing:
            self.homed = P.HOMED_ALL  # the emulated user has moved the grip through its range
        self.last_cmd_t = time.monotonic()
        self.tripped = False
        ep = self.endpoint
        c = [max(-K.MAX_COMMAND, min(K.MAX_COMMAND, v)) for v in cmds]  # the firmware's own limit
        self.commands = tuple(c)
        try:
            fx, fy, fz = K.force_from_commands(ep.pos, c)
        except K.OutOfWorkspace:
            fx = fy = fz = 0.0
        norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        if norm > MAX_FORCE_N:
            fx, fy, fz = (v * MAX_FORCE_N / norm for v in (fx, fy, fz))
        ep.set_force(fx, fy, fz)
        ep.step(self.dt_s)
        try:
            enc = tuple(K.encoder_from_theta(t) for t in K.ik(ep.pos)[0])
        except K.OutOfWorkspace:
            enc = (0, 0, 0)
        n = self.stats["packets_in"]
        if self.unplug_after and n > self.unplug_after and self.backend is not None:
            self.backend.unplug()
            return
        if self.stall_at and n == self.stall_at:
            time.sleep(self.stall_s)
        out = P.encode_status(enc, self.homed, 0)
        if self.garbage_every and n % self.garbage_every == 0:
            junk = bytes(self.rng.choice((0x00, 0x3E, 0x41, 0x7F)) for _ in range(self.rng.randrange(1, 5)))
            self.stats["garbage_sent"] += len(junk)
            out = junk + out
        self.tx += out
        self.stats["packets_out"] += 1

    def applied_force(self) -> tuple:
        """The force the motors produce now (N)."""
        return tuple(self.endpoint.force)

    def check_watchdog(self, now: float) -> None:
        """No command for ``watchdog_ms`` while running: the motors are switched off."""
        with self.lock:
            if self.state == "running" and self.last_cmd_t is not None and not self.tripped \
                    and now - self.last_cmd_t > self.watchdog_s:
                self.tripped = True
                self.stats["watchdog_trips"] += 1
                self.endpoint.set_force(0.0, 0.0, 0.0)


class VirtualFalconBackend(usb.backend.IBackend):
    """A pyusb back end with one FT232R whose UART is wired to a :class:`FalconModel` (see module doc)."""

    def __init__(self, model: FalconModel, serial: str = "FTEMU049", busy: bool = False) -> None:
        self.model = model
        model.backend = self
        self.serial = serial
        self.busy = busy
        self.unplugged = False
        self.latency_ms = 16
        self.claimed = False
        self.control_log: list[tuple[int, int, int]] = []  # (bRequest, wValue, wIndex) of every vendor request
        self._dev = SimpleNamespace(name="falcon-emulator")
        self._stop = threading.Event()
        self._wd = threading.Thread(target=self._watchdog, name="falcon-watchdog", daemon=True)
        self._wd.start()

    def _watchdog(self) -> None:
        while not self._stop.wait(0.005):
            self.model.check_watchdog(time.monotonic())

    def stop(self) -> None:
        """End the watchdog thread."""
        self._stop.set()

    def unplug(self) -> None:
        """Pull the cable: every later transfer fails with ENODEV; the motors stop (no power over USB)."""
        self.unplugged = True
        self.model.endpoint.set_force(0.0, 0.0, 0.0)
        self.model.state = "off"
        self.model.tx.clear()

    def _check(self) -> None:
        if self.unplugged:
            raise usb.core.USBError("No such device (it may have been disconnected)", errno.ENODEV, errno.ENODEV)

    # -- descriptors ------------------------------------------------------------------------------
    def enumerate_devices(self):
        """pyusb: the one emulated FT232R (none once unplugged)."""
        if not self.unplugged:
            yield self._dev

    def get_device_descriptor(self, dev):
        """pyusb: an FT232R's device descriptor with the Falcon's ids (bcdDevice 0x0600)."""
        return SimpleNamespace(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
                               bDeviceProtocol=0, bMaxPacketSize0=8, idVendor=P.FTDI_VID, idProduct=P.FALCON_PID,
                               bcdDevice=0x0600, iManufacturer=1, iProduct=2, iSerialNumber=3,
                               bNumConfigurations=1, address=7, bus=1, port_number=2, port_numbers=(2,), speed=2)

    def get_configuration_descriptor(self, dev, config):
        """pyusb: one configuration, one interface."""
        return SimpleNamespace(bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=1,
                               bConfigurationValue=1, iConfiguration=0, bmAttributes=0xA0, bMaxPower=45,
                               extra_descriptors=[])

    def get_interface_descriptor(self, dev, intf, alt, config):
        """pyusb: the FTDI's vendor-specific interface 0."""
        if intf != 0 or alt != 0:
            raise IndexError("no such interface")
        return SimpleNamespace(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                               bNumEndpoints=2, bInterfaceClass=0xFF, bInterfaceSubClass=0xFF,
                               bInterfaceProtocol=0xFF, iInterface=2, extra_descriptors=[])

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        """pyusb: bulk IN 0x81 and bulk OUT 0x02, 64-byte packets."""
        addr = (0x81, 0x02)[ep]
        return SimpleNamespace(bLength=7, bDescriptorType=5, bEndpointAddress=addr, bmAttributes=2,
                               wMaxPacketSize=MAX_PACKET, bInterval=0, bRefresh=0, bSynchAddress=0,
                               extra_descriptors=[])

    def get_parent(self, dev):
        """pyusb: no hub above it."""
        return None

    # -- handles and interfaces --------------------------------------------------------------------
    def open_device(self, dev):
        """pyusb: the handle is the device itself (ENODEV once unplugged)."""
        self._check()
        return dev

    def close_device(self, dev_handle):
        """pyusb: releases the interface."""
        self.claimed = False

    def set_configuration(self, dev_handle, config_value):
        """pyusb: accepted."""
        self._check()

    def get_configuration(self, dev_handle):
        """pyusb: configuration 1."""
        self._check()
        return 1

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        """pyusb: accepted."""
        self._check()

    def claim_interface(self, dev_handle, intf):
        """pyusb: EBUSY when another program holds it (``busy=True``)."""
        self._check()
        if self.busy:
            raise usb.core.USBError("Resource busy", errno.EBUSY, errno.EBUSY)
        self.claimed = True

    def release_interface(self, dev_handle, intf):
        """pyusb: releases it."""
        self.claimed = False

    def is_kernel_driver_active(self, dev_handle, intf):
        """pyusb: no kernel driver (ftdi_sio) bound."""
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        """pyusb: nothing to detach."""
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        """pyusb: nothing to attach."""
        pass

    def reset_device(self, dev_handle):
        """pyusb: accepted."""
        self._check()

    def clear_halt(self, dev_handle, ep):
        """pyusb: accepted."""
        self._check()

    # -- transfers ----------------------------------------------------------------------------------
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        """pyusb: string descriptors and the FTDI vendor requests (see module doc)."""
        self._check()
        m = self.model
        if bmRequestType == 0x80 and bRequest == 6:  # GET_DESCRIPTOR (strings)
            kind, idx = wValue >> 8, wValue & 0xFF
            if kind != 3:
                raise usb.core.USBError("Pipe error", errno.EPIPE, errno.EPIPE)
            if idx == 0:
                raw = bytes((4, 3, 0x09, 0x04))
            else:
                text = {1: "Novint", 2: "FALCON HAPTIC", 3: self.serial}.get(idx, "")
                enc = text.encode("utf-16-le")
                raw = bytes((2 + len(enc), 3)) + enc
            n = min(len(data), len(raw))
            data[:n] = array.array("B", raw[:n])
            return n
        if bmRequestType & 0x80:  # vendor IN
            if bRequest == SIO_POLL_MODEM_STATUS:
                out = STATUS_BYTES
            elif bRequest == SIO_GET_LATENCY_TIMER:
                out = bytes((self.latency_ms,))
            elif bRequest == SIO_READ_PINS:
                out = b"\x00"
            else:
                out = bytes(len(data))
            n = min(len(data), len(out))
            data[:n] = array.array("B", out[:n])
            return n
        self.control_log.append((bRequest, wValue, wIndex))
        with m.lock:
            if bRequest == SIO_RESET and wValue == 1:
                m.tx.clear()   # purge RX (what the host would receive)
            elif bRequest == SIO_SET_BAUDRATE:
                m.set_baud(P.ftdi_baud_from_divisor(wValue, wIndex))
            elif bRequest == SIO_SET_MODEM_CTRL and wValue & 0x0100:
                m.set_dtr(bool(wValue & 0x0001))
            elif bRequest == SIO_SET_LATENCY_TIMER:
                self.latency_ms = wValue & 0xFF
        return len(data) if data is not None else 0

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        """pyusb: bytes to the Falcon through the UART."""
        self._check()
        payload = bytes(data)
        self.model.receive(payload)
        return len(payload)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        """pyusb: the receive FIFO in 64-byte packets, each led by the two modem-status bytes."""
        self._check()
        m = self.model
        with m.lock:
            pending = bytes(m.tx)
        if not pending:
            # an FTDI sends its status bytes alone when its latency timer expires with nothing to say
            time.sleep(min(self.latency_ms, timeout or self.latency_ms) * 1e-3)
            with m.lock:
                pending = bytes(m.tx)
        size = len(buff)
        out = bytearray()
        taken = 0
        while len(out) + 2 <= size:
            chunk = pending[taken:taken + MAX_PACKET - 2]
            room = size - len(out) - 2
            chunk = chunk[:room]
            out += STATUS_BYTES + chunk
            taken += len(chunk)
            if taken >= len(pending) or len(chunk) < MAX_PACKET - 2:
                break
        with m.lock:
            del m.tx[:taken]
        buff[:len(out)] = array.array("B", out)
        return len(out)


def falcon_usb_device(backend: VirtualFalconBackend) -> usb.core.Device:
    """The emulated FT232R as the pyusb device pyftdi opens (``Ftdi.open_from_device``)."""
    return usb.core.Device(next(iter(backend.enumerate_devices())), backend)


def stand_in_firmware(size: int = 3000, seed: int = 49) -> bytes:
    """A stand-in firmware image for the emulator (the real one is the user's own and is never shipped)."""
    rng = random.Random(seed)
    return bytes(rng.randrange(256) for _ in range(size))
