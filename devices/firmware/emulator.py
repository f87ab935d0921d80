"""Firmware emulator: speaks docs/protocol.md on a pseudo-terminal, driven by the sim device's physics.

``python -m devices emulate --pty`` (or :func:`start_emulator` from Python)
opens a pty pair, prints the slave's name (the "port" a host opens with
``serial:<name>``) and behaves like the reference firmware on the master side:
hello/INFO handshake, streaming mode (one CURRENT in, one physics tick, one
STATE out), on-device mode (wall + transient rendered by
:class:`devices.firmware.logic.FirmwareRenderer` at the firmware rate, telemetry
and EVENT frames out), a watchdog, and fault injection on what it sends.

The simulated hand keeps tapping (a :class:`devices.sim.TapTrajectory`,
restarted whenever it ends), so a host sees contacts without setting a user.

Pacing in on-device mode: ``realtime`` runs the firmware ticks against the
wall clock (a real microcontroller); ``host`` runs them as fast as the host
drains the telemetry (at most ``HOST_PACE_BACKLOG`` unread bytes in the tty,
about 2 ms of 10 kHz telemetry), which makes tests fast while keeping every tick
and frame. Either way the firmware reads the host's frames at least once per
millisecond of its own time, so a round trip (a frame out, its ACK back) costs
a few milliseconds of device time, as on a native-USB board.
"""

from __future__ import annotations

import fcntl
import math
import os
import random
import select
import signal
import subprocess
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass, fields, replace

from ..base import DeviceInfo, Status
from ..hardware import wire_protocol as P
from ..hardware.calibration import Calibration
from ..sim import SimDevice, TapTrajectory
from .logic import FirmwareRenderer

FIRMWARE_VERSION = (1, 0, 0)
# ~2 ms of telemetry: a host round trip costs as much device time as a USB link's buffering, not more (a 2 kB
# backlog made each ACK wait ~9 ms of device time behind queued STATEs: a re-armed transient then lagged the
# approach velocity by up to 90 ms)
HOST_PACE_BACKLOG = 512
MAX_TABLE_SAMPLES = 200_000  # emulated board: 800 kB of float samples (a Teensy 4.1-class board has 1 MB RAM)


@dataclass(frozen=True)
class FaultSpec:
    """Faults injected on the device -> host direction (probabilities per frame unless noted).

    ``drop``, ``corrupt`` (flip one byte), ``duplicate``, ``garbage`` (random
    bytes before the frame), ``delay`` (hold the frame ``delay_s`` first),
    ``disconnect_after_s`` (close the pty that many seconds after the first
    frame from a host), ``silent`` (never answer the hello), ``protocol_major`` (claim
    another protocol version in INFO), ``protocol_minor`` (claim another minor version; 0 stands for a
    protocol 1.0 firmware, which takes only the 16-byte WALL, without the passivity observer). Scripted (deterministic, counted over the frames sent):
    ``drop_every=N`` drops every N-th frame, ``corrupt_every=N`` flips a bit in every N-th,
    ``drop_burst=K`` with ``drop_burst_at=N`` drops K frames in a row from the N-th on.
    Malformed but CRC-valid frames: ``bad_length_every=N`` sends every N-th STATE one byte too
    long, ``bad_type_every=N`` sends every N-th STATE as a host-to-device type (CURRENT), both with a
    correct CRC. A broken device: ``clock_back_at=N`` turns the clock 1 s back at the N-th STATE,
    ``clock_freeze_at=N`` stops it there; ``info_servo_rate_hz=X`` claims servo rate X in INFO (the
    physics keeps its own). ``stall_s=X`` with ``stall_at=N``: the device stalls X s before sending its N-th
    frame (a busy firmware or a USB stall: it answers nothing meanwhile, then works off the commands that
    queued up).
    """

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    garbage: float = 0.0
    delay: float = 0.0
    delay_s: float = 0.005
    disconnect_after_s: float | None = None
    silent: bool = False
    protocol_major: int | None = None
    protocol_minor: int | None = None
    drop_every: int = 0
    corrupt_every: int = 0
    drop_burst_at: int = 0
    drop_burst: int = 0
    bad_length_every: int = 0
    bad_type_every: int = 0
    clock_back_at: int = 0
    clock_freeze_at: int = 0
    info_servo_rate_hz: float = 0.0
    stall_at: int = 0
    stall_s: float = 0.0

    @classmethod
    def parse(cls, text: str | None) -> "FaultSpec":
        """``"drop=0.01,corrupt=0.02,disconnect_after_s=2"`` -> FaultSpec; ValueError names the bad key."""
        if not text:
            return cls()
        names = {f.name for f in fields(cls)}
        values: dict = {}
        for item in text.split(","):
            item = item.strip()
            if not item:
                continue
            key, eq, raw = item.partition("=")
            key = key.strip()
            if key not in names:
                raise ValueError(f"--fault: unknown fault {key!r}; valid: {', '.join(sorted(names))}")
            if not eq:
                raise ValueError(f"--fault: {key} needs a value, e.g. {key}=0.01")
            try:
                value = float(raw)
            except ValueError:
                raise ValueError(f"--fault: {key}={raw!r} is not a number") from None
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"--fault: {key}={raw} must be a finite number >= 0")
            if key in ("drop", "corrupt", "duplicate", "garbage", "delay") and value > 1:
                raise ValueError(f"--fault: {key}={raw} is a probability and must be <= 1")
            if key == "silent":
                value = bool(value)
            elif key in ("protocol_major", "protocol_minor", "drop_every", "corrupt_every", "drop_burst_at", "drop_burst",
                         "bad_length_every", "bad_type_every", "clock_back_at", "clock_freeze_at", "stall_at"):
                value = int(value)
            values[key] = value
        return cls(**values)

    def to_text(self) -> str:
        """Inverse of :meth:`parse` (only the non-default fields)."""
        items = []
        for f in fields(self):
            value = getattr(self, f.name)
            if value != f.default:
                items.append(f"{f.name}={int(value) if isinstance(value, bool) else value}")
        return ",".join(items)

    @property
    def any_frame_faults(self) -> bool:
        """True when any fault acts on whole device -> host frames (drop, corrupt, duplicate, garbage, delay)."""
        return bool(self.drop or self.corrupt or self.duplicate or self.garbage or self.delay or self.drop_every
                    or self.corrupt_every or self.drop_burst or (self.stall_at and self.stall_s))


class Emulator:
    """Firmware emulator state machine on a pty master fd (see module doc).

    Parameters
    ----------
    physics : devices.sim.SimDevice
        The simulated device whose physics the firmware drives (opened here).
    mode : {"streaming", "on-device"}
        Mode at power-up (the host may switch with SET_MODE if capabilities allow).
    faults : FaultSpec
    watchdog_ms : int
        No command for this long -> zero current and WATCHDOG_TRIPPED reported (once more in the
        first STATE after the host resumes).
    pace : {"realtime", "host"}
        On-device tick pacing (module doc).
    """

    def __init__(self, physics, mode: str = "streaming", faults: FaultSpec | None = None, watchdog_ms: int = 100,
                 pace: str = "realtime", seed: int = 0, encoder_offset_counts: int = 0,
                 serial_number: str = "EMU0001", t0_us: int = 0) -> None:
        if mode not in ("streaming", "on-device"):
            raise ValueError(f"mode must be 'streaming' or 'on-device', got {mode!r}")
        if pace not in ("realtime", "host"):
            raise ValueError(f"pace must be 'realtime' or 'host', got {pace!r}")
        self.phys = physics
        self.faults = faults or FaultSpec()
        self.rng = random.Random(seed)
        self.watchdog_ms = int(watchdog_ms)
        self.pace = pace
        self.power_up_mode = mode
        self.mode = P.MODE_STREAMING
        self.encoder_offset = int(encoder_offset_counts)
        self.t0_us = int(t0_us)
        sim_info: DeviceInfo = physics.info
        self.fs = sim_info.servo_rate_hz
        self._ticks_per_ms = max(1, int(self.fs * 1e-3))  # ticks between two reads of the host's frames
        self.res = sim_info.position_resolution_m
        sensors = getattr(getattr(physics, "params", None), "sensors", {}) or {}
        self.accel_scale = float(sensors.get("accel_resolution_m_s2", 0.015))
        self.grip_scale = float(sensors.get("grip_resolution_N", 0.01))
        # a Teensy-class board on native USB (the pty's nominal baud rate is not its link)
        caps = P.CAP_STREAMING | P.CAP_PARAM_TRANSIENT | P.CAP_TABLE_TRANSIENT | P.CAP_REARM_TRANSIENT | P.CAP_NATIVE_USB
        if mode == "on-device":
            caps |= P.CAP_ON_DEVICE
        self.caps = caps
        info = DeviceInfo(
            name=f"hfam-emulator({sim_info.name})", encoder_lines=sim_info.encoder_lines,
            gear_ratio=sim_info.gear_ratio, handle_length_m=sim_info.handle_length_m,
            torque_constant_Nm_A=sim_info.torque_constant_Nm_A, current_continuous_A=sim_info.current_continuous_A,
            current_peak_A=sim_info.current_peak_A, current_amplifier_A=sim_info.current_amplifier_A,
            servo_rate_hz=sim_info.servo_rate_hz, winding_resistance_ohm=sim_info.winding_resistance_ohm,
            thermal_resistance_K_W=sim_info.thermal_resistance_K_W,
            thermal_time_constant_s=sim_info.thermal_time_constant_s,
            winding_max_temp_rise_K=sim_info.winding_max_temp_rise_K, accel_range_m_s2=sim_info.accel_range_m_s2,
            grip_range_N=sim_info.grip_range_N, capabilities=P.capability_names(caps), simulated=False,
            emulated=True)   # the hardware path runs (a link), but no hardware is there: INFO says so
        major = self.faults.protocol_major if self.faults.protocol_major is not None else P.PROTOCOL_VERSION[0]
        minor = self.faults.protocol_minor if self.faults.protocol_minor is not None else P.PROTOCOL_VERSION[1]
        if self.faults.info_servo_rate_hz:  # a broken INFO: the rate the device claims, not the one it runs
            info = replace(info, servo_rate_hz=float(self.faults.info_servo_rate_hz))
        self.wire = P.WireInfo(info, (major, minor), FIRMWARE_VERSION, serial_number,
                               self.accel_scale, 0, self.grip_scale, 0, self.watchdog_ms, caps, MAX_TABLE_SAMPLES)
        self.fw = FirmwareRenderer(self.res, info.force_per_amp_N_A, self.fs, info.current_amplifier_A,
                                   MAX_TABLE_SAMPLES,
                                   thermal=(info.winding_resistance_ohm, info.thermal_resistance_K_W,
                                            info.thermal_time_constant_s, info.winding_max_temp_rise_K))
        self.parser = P.FrameParser()
        self.seq = 0
        self.cmd_seq = 0
        self.applied_A = 0.0
        self.tripped = False
        self.trip_report = False  # WATCHDOG_TRIPPED still to be shown in the next STATE after a resume
        self.event_tripped = False
        self.fault_latched = False
        self.watchdog_armed = False
        self.last_cmd = time.monotonic()
        self.rendering = False
        self.decimation = 1
        self.ticks = 0
        self.tick_base = 0
        self.t_render0 = 0.0
        self.fd: int | None = None
        self.slave_fd: int | None = None
        self.attached_at = None  # time of the first frame from a host
        self.disconnected = False
        self.burst_started = None
        self.last_cmd_after_burst = None
        self.cmds_after_burst = 0   # CURRENT frames received since a scripted drop burst began
        self.states_sent = 0
        self.frozen_t_us = None
        self.stats = {"frames_in": 0, "frames_out": 0, "dropped": 0, "corrupted": 0, "duplicated": 0, "garbage": 0,
                      "delayed": 0, "naks": 0, "watchdog_trips": 0, "write_overflows": 0, "ticks": 0,
                      "malformed": 0}

    # -- pty ---------------------------------------------------------------------
    def open_pty(self) -> str:
        """Create the pty pair; return the slave's path (the port name for the host)."""
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self.fd = master
        self.slave_fd = slave  # kept open so the pty survives host close/reopen
        return os.ttyname(slave)

    def close(self) -> None:
        """Close both ends of the emulator's pseudo-terminal (idempotent)."""
        for name in ("fd", "slave_fd"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    # -- output ---------------------------------------------------------------------
    def send(self, msg_type: int, payload: bytes = b"") -> None:
        """Frame ``payload`` as message ``msg_type`` with the next sequence number and write it to the host.

        Parameters
        ----------
        msg_type : int
            Protocol message type (``devices.hardware.wire_protocol``).
        payload : bytes
            Message payload.

        The configured :class:`FaultSpec` applies here: the frame may be dropped, corrupted, duplicated,
        delayed or preceded by garbage bytes (counted in ``stats``).
        """
        seq = self.seq
        self.seq = (seq + 1) & 0xFF
        frame = P.encode_frame(msg_type, seq, payload)
        f = self.faults
        if f.any_frame_faults:
            rng = self.rng
            k = self._frame_k = getattr(self, "_frame_k", 0) + 1
            if ((f.drop and rng.random() < f.drop) or (f.drop_every and k % int(f.drop_every) == 0)
                    or (f.drop_burst and f.drop_burst_at <= k < f.drop_burst_at + f.drop_burst)):
                self.stats["dropped"] += 1
                if f.drop_burst and k == int(f.drop_burst_at):
                    self.burst_started = time.monotonic()
                return
            if f.corrupt_every and k % int(f.corrupt_every) == int(f.corrupt_every) - 1:  # never on a dropped one
                self.stats["corrupted"] += 1
                buf = bytearray(frame)
                buf[len(buf) // 2] ^= 0x10
                frame = bytes(buf)
            if f.garbage and rng.random() < f.garbage:
                self.stats["garbage"] += 1
                frame = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 24))) + frame
            if f.corrupt and rng.random() < f.corrupt:
                self.stats["corrupted"] += 1
                buf = bytearray(frame)
                k = rng.randrange(2, len(buf))
                buf[k] ^= 1 << rng.randrange(8)
                frame = bytes(buf)
            if f.stall_at and k == f.stall_at and f.stall_s:
                self.stats["stalled_s"] = f.stall_s
                self.stall_started = time.monotonic()
                time.sleep(f.stall_s)
            if f.delay and rng.random() < f.delay:
                self.stats["delayed"] += 1
                time.sleep(f.delay_s)
            if f.duplicate and rng.random() < f.duplicate:
                self.stats["duplicated"] += 1
                frame = frame + frame
        self._write(frame)
        self.stats["frames_out"] += 1

    def _write(self, data: bytes) -> None:
        fd = self.fd
        if fd is None:
            return
        view = memoryview(data)
        deadline = time.monotonic() + 0.2
        while view:
            try:
                n = os.write(fd, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > deadline:  # host not reading: the frame is lost, as on a full USB FIFO
                    self.stats["write_overflows"] += 1
                    return
                select.select((), (fd,), (), 0.01)
            except OSError:
                return

    def _ack(self, frame: P.Frame) -> None:
        self.send(P.ACK, P.ACK_STRUCT.pack(frame.type, frame.seq))

    def _nak(self, frame: P.Frame, code: int, text: str = "") -> None:
        self.stats["naks"] += 1
        self.send(P.NAK, P.NAK_STRUCT.pack(frame.type, frame.seq, code) + text.encode("ascii", "replace")[:200])

    # -- physics <-> raw sensors -------------------------------------------------------
    def _raw(self, st) -> tuple[int, int, int, int]:
        t_us = (self.t0_us + int(round(st.t_s * 1e6))) & 0xFFFFFFFF
        enc = int(round(st.position_m / self.res)) + self.encoder_offset
        a = int(round(st.accel_m_s2 / self.accel_scale))
        a = 32767 if a > 32767 else (-32768 if a < -32768 else a)
        g = int(round(st.grip_N / self.grip_scale))
        g = 65535 if g > 65535 else (0 if g < 0 else g)
        return t_us, enc, a, g

    def _status(self, sim_status: int) -> int:
        s = sim_status & (Status.FAULT | Status.OVER_TEMPERATURE | Status.CLIPPING)
        if self.tripped or self.trip_report:
            s |= Status.WATCHDOG_TRIPPED
        if self.fault_latched:
            s |= Status.FAULT
        if self.fw.unstable:  # the wall's passivity observer stopped the rendering (latched with FAULT)
            s |= Status.FAULT | Status.UNSTABLE
        if self.rendering and self.fw.clipping:
            s |= Status.CLIPPING
        if self.fw.over_temperature:
            s |= Status.OVER_TEMPERATURE
        return s

    def _send_state(self, st) -> None:
        t_us, enc, a, g = self._raw(st)
        mA = int(round(self.applied_A * 1000.0))
        payload = P.encode_state(self._fault_clock(t_us), enc, a, g, self._status(st.status), self.cmd_seq, mA)
        f = self.faults
        self.states_sent += 1
        k = self.states_sent
        if f.bad_length_every and k % f.bad_length_every == 0:
            self.stats["malformed"] += 1
            self.send(P.STATE, payload + b"\0")  # 17 bytes, CRC correct: a firmware bug, not line noise
        elif f.bad_type_every and k % f.bad_type_every == 0:
            self.stats["malformed"] += 1
            self.send(P.CURRENT, payload)  # a host-to-device type from the device
        else:
            self.send(P.STATE, payload)
        self.trip_report = False

    def _fault_clock(self, t_us: int) -> int:
        """The clock a broken device reports (``clock_back_at``, ``clock_freeze_at``); ``t_us`` otherwise."""
        f = self.faults
        k = self.states_sent + 1
        if f.clock_freeze_at and k >= f.clock_freeze_at:
            if self.frozen_t_us is None:
                self.frozen_t_us = t_us
            return self.frozen_t_us
        if f.clock_back_at and k >= f.clock_back_at:
            return (t_us - 1_000_000) & 0xFFFFFFFF
        return t_us

    # -- input ------------------------------------------------------------------------
    def handle(self, frame: P.Frame) -> None:
        """Act on one host frame (the firmware's dispatch); protocol errors become NAKs."""
        self.stats["frames_in"] += 1
        if self.attached_at is None:
            self.attached_at = time.monotonic()
        t = frame.type
        if self.mode == P.MODE_STREAMING and t == P.CURRENT or self.rendering:
            self.last_cmd = time.monotonic()
            if self.tripped:  # the host is back: output resumes, the trip is reported in the next STATE
                self.tripped = False
                self.trip_report = True
        handler = self._HANDLERS.get(t)
        try:
            if handler is None:
                self._nak(frame, P.NAK_UNKNOWN_TYPE)
            else:
                handler(self, frame)
        except MemoryError as exc:
            self._nak(frame, P.NAK_TOO_LARGE, str(exc))
        except P.ProtocolError as exc:
            self._nak(frame, P.NAK_BAD_PAYLOAD, str(exc))

    def _on_current(self, frame: P.Frame) -> None:
        """Streaming: take the current (clamped; NaN latches FAULT), answer with one STATE, one physics tick.

        The sim applies a command one servo period after it is given (docs/architecture.md), so
        the state that answers command n was computed before command n arrived: the reply goes
        out at once and the physics tick runs afterwards, off the round trip (as a real device
        samples its sensors when the command arrives). The sequence of states the host sees is
        exactly that of ``SimDevice.read()/command()`` run directly.
        """
        self.watchdog_armed = True
        self.cmd_seq = frame.seq
        if self.rendering:
            return  # the firmware owns the output while rendering
        i = P.decode_current(frame.payload)
        lim = self.wire.info.current_amplifier_A
        if not math.isfinite(i):
            self.fault_latched = True
            i = 0.0
        i = max(-lim, min(lim, i))
        if self.tripped or self.fault_latched:
            i = 0.0
        phys = self.phys
        phys._send_current(i)  # the current the next period applies (SimDevice's output-delay slot)
        self.applied_A = i
        if self.burst_started is not None:  # scripted drop burst: the host's last command after it began
            self.last_cmd_after_burst = (time.monotonic(), i)
            self.cmds_after_burst += 1
        self._send_state(phys.read())
        phys.command(i)  # next period: applies i; holds i until the next CURRENT replaces it
        self._keep_hand_busy()

    def _on_hello(self, frame: P.Frame) -> None:
        if self.faults.silent:
            return
        if len(frame.payload) != P.HELLO_STRUCT.size:
            self._nak(frame, P.NAK_BAD_PAYLOAD, "HELLO carries the host protocol version (2 bytes)")
            return
        self.send(P.INFO, P.encode_info(self.wire))

    def _on_set_mode(self, frame: P.Frame) -> None:
        mode, dec = P._unpack(P.MODE_STRUCT, frame.payload, "SET_MODE")
        if mode == P.MODE_ON_DEVICE and not self.caps & P.CAP_ON_DEVICE:
            self._nak(frame, P.NAK_BAD_STATE, "on-device rendering not enabled on this device")
            return
        if mode not in (P.MODE_STREAMING, P.MODE_ON_DEVICE) or dec < 1:
            self._nak(frame, P.NAK_BAD_PAYLOAD, f"mode {mode} decimation {dec}")
            return
        if mode == P.MODE_STREAMING:
            self._stop_render()
        self.mode = mode
        self.decimation = dec
        self._ack(frame)

    def _on_set_watchdog(self, frame: P.Frame) -> None:
        (ms,) = P._unpack(P.WATCHDOG_STRUCT, frame.payload, "SET_WATCHDOG")
        if ms < 1:
            self._nak(frame, P.NAK_BAD_PAYLOAD, "watchdog must be >= 1 ms")
            return
        self.watchdog_ms = ms
        self._ack(frame)

    def _on_clear_faults(self, frame: P.Frame) -> None:
        self.tripped = False
        self.fault_latched = False
        self.fw.clear_unstable()
        self.last_cmd = time.monotonic()
        self._ack(frame)

    def _on_calibration(self, frame: P.Frame) -> None:
        self.fw.cal = Calibration.from_payload(frame.payload)
        self._ack(frame)

    def _on_limits(self, frame: P.Frame) -> None:
        cont, peak, amp = P._unpack(P.LIMITS_STRUCT, frame.payload, "LIMITS")
        info = self.wire.info  # never beyond the device's own limits
        self.fw.set_limits(min(cont, info.current_continuous_A), min(peak, info.current_peak_A, amp))
        self._ack(frame)

    def _on_rearm_commit(self, frame: P.Frame) -> None:
        (n,) = P._unpack(P.DATA_OFFSET_STRUCT, frame.payload, "REARM_COMMIT")
        self.fw.rearm_commit(n)
        self._ack(frame)

    def _on_render_start(self, frame: P.Frame) -> None:
        if self.mode != P.MODE_ON_DEVICE:
            self._nak(frame, P.NAK_BAD_STATE, "RENDER_START needs SET_MODE on-device first")
            return
        self._ack(frame)
        if not self.rendering:   # a repeat (the host retried a late ACK): nothing restarts mid-run (hfam_fw.c)
            self._start_render()
        else:
            self.last_cmd = time.monotonic()

    def _on_wall(self, frame: P.Frame) -> None:
        if self.wire.protocol_version < (1, 1) and len(frame.payload) != P.WALL_STRUCT.size:
            # as a protocol 1.0 firmware: WALL is 16 bytes, no passivity observer
            raise P.ProtocolError(f"WALL: {len(frame.payload)} bytes, protocol {self.wire.protocol_version[0]}."
                                  f"{self.wire.protocol_version[1]} takes {P.WALL_STRUCT.size}")
        self.fw.set_wall(*P.decode_wall(frame.payload))
        self._ack(frame)

    def _on_render_stop(self, frame: P.Frame) -> None:
        self._stop_render()
        self._ack(frame)

    def _acked(fw_call):
        """Handler for a configuration frame: decode, hand to the firmware renderer, ACK."""
        def handler(self, frame: P.Frame) -> None:
            fw_call(self.fw, frame.payload)
            self._ack(frame)
        return handler

    _HANDLERS = {
        P.CURRENT: _on_current,
        P.KEEPALIVE: lambda self, frame: None,
        P.HELLO: _on_hello,
        P.PING: lambda self, frame: self.send(P.PONG, frame.payload),
        P.SET_MODE: _on_set_mode,
        P.SET_WATCHDOG: _on_set_watchdog,
        P.CLEAR_FAULTS: _on_clear_faults,
        P.SET_CALIBRATION: _on_calibration,
        P.WALL: lambda self, frame: self._on_wall(frame),
        P.LIMITS: _on_limits,
        P.TRANSIENT_PARAM: _acked(lambda fw, pl: fw.set_param_transient(
            *P._unpack(P.TRANSIENT_PARAM_STRUCT, pl, "TRANSIENT_PARAM"))),
        P.TABLE_BEGIN: _acked(lambda fw, pl: fw.table_begin(*P.decode_table_begin(pl))),
        P.TABLE_DATA: _acked(lambda fw, pl: fw.table_data(*P.decode_data_chunk(pl))),
        P.TABLE_COMMIT: _acked(lambda fw, pl: fw.table_commit()),
        P.REARM_DATA: _acked(lambda fw, pl: fw.rearm_data(*P.decode_data_chunk(pl))),
        P.REARM_COMMIT: _on_rearm_commit,
        P.RENDER_START: _on_render_start,
        P.RENDER_STOP: _on_render_stop,
    }
    del _acked

    # -- on-device rendering ------------------------------------------------------------
    def _start_render(self) -> None:
        self.rendering = True
        self.watchdog_armed = True
        self.last_cmd = time.monotonic()
        self.fw.reset_contact()
        self.fw.events.clear()
        self.t_render0 = time.monotonic()
        self.tick_base = self.ticks

    def _stop_render(self) -> None:
        if not self.rendering:
            return
        self.rendering = False
        fw = self.fw
        if fw.in_event:
            fw._finish_event()
        self._flush_events()
        self.applied_A = 0.0
        self.watchdog_armed = False

    def _flush_events(self) -> None:
        events = self.fw.events
        while events:
            ev = events.pop(0)
            ev["watchdog"] = ev.get("watchdog", False)
            self.send(P.EVENT, P.encode_event(ev))

    def _tick(self) -> None:
        """One firmware servo period: sense (raw), render, actuate (physics advances), maybe report."""
        phys = self.phys
        st = phys.read()
        t_us, enc, a, g = self._raw(st)
        i = self.fw.tick(t_us, enc, a, g)
        if self.fw.unstable:  # as the firmware: the trip latches FAULT, zero output until CLEAR_FAULTS
            self.fault_latched = True
        if self.tripped or self.fault_latched:
            i = 0.0
        self.applied_A = i
        phys.command(i)
        self.ticks += 1
        self.stats["ticks"] += 1
        if self.fw.events:
            self._flush_events()
        if self.ticks % self.decimation == 0:
            self._send_state(phys.read())
        self._keep_hand_busy()

    def _keep_hand_busy(self) -> None:
        phys = self.phys
        if getattr(phys, "trajectory_done", False) and getattr(phys, "trajectory", None) is not None:
            phys.set_user(phys.trajectory, grip_N=self._grip_N, hand=getattr(self, "_hand", None))

    def _run_due_ticks(self, now: float) -> float:
        """Run the ticks that are due; return how long select may sleep."""
        if self.pace == "realtime":
            due = int((now - self.t_render0) * self.fs) - (self.ticks - self.tick_base)
            cap = int(0.05 * self.fs)
            if due > cap:  # fell >50 ms behind (machine busy): skip the rest, as an overrun counter would
                self.tick_base -= due - cap   # the skipped ticks count as done: the device never runs ahead
                due = cap
            burst = self._ticks_per_ms
            for _ in range(min(due, burst)):
                self._tick()
            return 0.0 if due > burst else 0.5 / self.fs
        # host pacing: keep at most HOST_PACE_BACKLOG unread bytes in the tty; back to select (the host's
        # frames) after a millisecond of ticks at most
        for _ in range(self._ticks_per_ms):
            if self._unread() > HOST_PACE_BACKLOG:
                return 0.0002
            self._tick()
        return 0.0

    def _unread(self) -> int:
        try:
            buf = fcntl.ioctl(self.slave_fd, termios.FIONREAD, b"\0\0\0\0")
            return int.from_bytes(buf, sys.byteorder)
        except OSError:
            return 0

    # -- watchdog --------------------------------------------------------------------------
    def _check_watchdog(self, now: float) -> None:
        if self.watchdog_armed and not self.tripped and now - self.last_cmd > self.watchdog_ms * 1e-3:
            self.tripped = True
            self.applied_A = 0.0
            self.stats["watchdog_trips"] += 1
            self.fw.watchdog_during_event = self.fw.in_event
            if not self.rendering:
                # zero the held current now (a real amplifier output drops at once), and report it
                self.phys.zero()
                self._send_state(self.phys.read())

    # -- main loop ---------------------------------------------------------------------------
    def set_hand(self, trajectory, grip_N: float = 2.0, hand=None) -> None:
        """The emulated device's simulated hand (``hand`` as :meth:`devices.sim.SimDevice.set_user`)."""
        self._grip_N = grip_N
        self._hand = hand
        self.phys.set_user(trajectory, grip_N=grip_N, hand=hand)

    def serve(self, stop: threading.Event) -> None:
        """Run until ``stop`` is set or the disconnect fault fires."""
        if not getattr(self.phys, "is_open", True):
            self.phys.open()
        if not hasattr(self, "_grip_N"):
            self._grip_N = 2.0
        fd = self.fd
        f = self.faults
        wait = 0.01
        while not stop.is_set():
            try:
                ready, _, _ = select.select((fd,), (), (), wait)
            except (OSError, ValueError):
                break
            if ready:
                try:
                    data = os.read(fd, 65536)
                except BlockingIOError:
                    data = b""
                except OSError:  # EIO: no host has the slave open right now
                    data = b""
                    time.sleep(0.005)
                if data:
                    for frame in self.parser.feed(data):
                        self.handle(frame)
            now = time.monotonic()
            self._check_watchdog(now)
            if (f.disconnect_after_s is not None and self.attached_at is not None
                    and now - self.attached_at > f.disconnect_after_s):
                self.disconnected = True
                self.close()
                break
            if self.rendering:
                wait = self._run_due_ticks(now)
            else:
                wait = 0.002 if self.watchdog_armed and not self.tripped else 0.02


class EmulatorHandle:
    """What :func:`start_emulator` returns: stop it with ``stop()`` (also a context manager)."""

    def __init__(self, port: str, emulator: Emulator | None = None, thread: threading.Thread | None = None,
                 stop_event: threading.Event | None = None, process: subprocess.Popen | None = None) -> None:
        self.port = port
        self.emulator = emulator
        self._thread = thread
        self._stop = stop_event
        self.process = process

    @property
    def alive(self) -> bool:
        """True while the emulator (child process or thread) runs."""
        if self.process is not None:
            return self.process.poll() is None
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the emulator: SIGTERM to a child process (killed after ``timeout_s`` s), or end the thread."""
        if self.process is not None:
            if self.process.poll() is None:
                self.process.send_signal(signal.SIGTERM)
                try:
                    self.process.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait(timeout_s)
            if self.process.stdout:
                self.process.stdout.close()
            return
        if self._stop is not None:
            self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self.emulator is not None:
            self.emulator.close()

    def __enter__(self) -> "EmulatorHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def build_emulator(mode: str = "streaming", faults: FaultSpec | str | None = None, sim: str | None = None,
                   taps_m_s=(0.05, 0.1, 0.2), grip_N: float = 2.0, sample: str = "placeholder",
                   watchdog_ms: int = 100, pace: str = "realtime", seed: int = 0, t0_us: int = 0,
                   rate_hz: float | None = None) -> Emulator:
    """An :class:`Emulator` over a fresh :class:`devices.sim.SimDevice` whose hand taps ``taps_m_s`` forever.

    ``rate_hz``: the firmware servo rate (the sim advances 1/rate_hz per tick); default: the sim's
    own rate (10 kHz, Table 3.1) for ``on-device``, 1 kHz for ``streaming`` (what a USB link carries).
    """
    if isinstance(faults, str) or faults is None:
        faults = FaultSpec.parse(faults)
    phys = SimDevice.from_spec(sim, seed=seed)
    if rate_hz is None and mode == "streaming":
        rate_hz = 1000.0
    if rate_hz is not None and rate_hz != phys.info.servo_rate_hz:
        if not (math.isfinite(rate_hz) and 100.0 <= rate_hz <= 100_000.0):
            raise ValueError(f"rate_hz must be within 100..100000 Hz, got {rate_hz}")
        phys = SimDevice(phys.params.replace(device={"servo_rate_hz": float(rate_hz)}), seed=seed)
    phys.set_sample(sample)
    phys.open()
    phys.command(0.0)  # compile/load the physics kernel now, not inside the host's first round trip
    emu = Emulator(phys, mode=mode, faults=faults, watchdog_ms=watchdog_ms, pace=pace, seed=seed, t0_us=t0_us)
    if taps_m_s:
        # the test harness's tapping hand: the prescribed (velocity-source) hand, one clean event per tap
        # (the default simulated person bounces and its taps depend on its reflex state)
        emu.set_hand(TapTrajectory(list(taps_m_s), n_taps=len(taps_m_s)), grip_N=grip_N, hand="prescribed")
    else:
        emu.set_hand(0.01, grip_N=grip_N)
    return emu


def start_emulator(mode: str = "streaming", faults: FaultSpec | str | None = None, *, process: bool = False,
                   sim: str | None = None, taps_m_s=(0.05, 0.1, 0.2), grip_N: float = 2.0,
                   sample: str = "placeholder", watchdog_ms: int = 100, pace: str = "realtime", seed: int = 0,
                   t0_us: int = 0, rate_hz: float | None = None, rt_priority: int | None = None,
                   startup_timeout_s: float = 30.0) -> tuple[str, EmulatorHandle]:
    """Start an emulator on a new pty; return ``(port_name, handle)``.

    ``process=False`` runs it in a daemon thread of this process (fast to
    start; shares the GIL), ``process=True`` in a child ``python -m devices
    emulate`` (a separate core, as a real microcontroller would be);
    ``rt_priority`` (child process only) runs it under SCHED_FIFO.
    """
    spec = faults if isinstance(faults, FaultSpec) else FaultSpec.parse(faults)  # validates, clear error
    fault_text = spec.to_text()
    if process:
        cmd = [sys.executable, "-m", "devices", "emulate", "--pty", "--mode", mode, "--watchdog-ms", str(watchdog_ms),
               "--pace", pace, "--seed", str(seed), "--grip-N", str(grip_N), "--sample", sample,
               "--t0-us", str(t0_us), "--taps", ",".join(str(v) for v in taps_m_s)]
        if fault_text:
            cmd += ["--fault", fault_text]
        if sim:
            cmd += ["--sim", sim]
        if rate_hz is not None:
            cmd += ["--rate-hz", str(rate_hz)]
        if rt_priority is not None:
            cmd += ["--rt-priority", str(int(rt_priority))]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=None, text=True,
                                cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        ready, _, _ = select.select((proc.stdout,), (), (), startup_timeout_s)
        line = proc.stdout.readline() if ready else ""
        if not line.startswith("PORT "):
            proc.kill()
            proc.wait()
            raise RuntimeError(f"emulator process did not report its port within {startup_timeout_s} s: {line!r}")
        return line.split(None, 1)[1].strip(), EmulatorHandle(line.split()[1], process=proc)
    emu = build_emulator(mode, spec, sim, taps_m_s, grip_N, sample, watchdog_ms, pace, seed, t0_us, rate_hz)
    port = emu.open_pty()
    stop = threading.Event()
    thread = threading.Thread(target=emu.serve, args=(stop,), name="hfam-emulator", daemon=True)
    thread.start()
    return port, EmulatorHandle(port, emu, thread, stop)
