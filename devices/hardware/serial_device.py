"""Hardware drivers speaking the binary protocol (docs/protocol.md): the shared :class:`ProtocolDevice`
and :class:`SerialDevice` (pyserial). :class:`devices.hardware.hid_device.HidDevice` reuses ProtocolDevice.

Two operating modes, chosen when the device is created (``mode=`` or the
device string ``serial:/dev/ttyACM0?mode=on-device``):

* ``streaming``: the host runs the servo loop; each ``command()`` sends a
  CURRENT frame, the device applies it and answers with one STATE frame, which
  the next ``read()`` returns (``read()`` then ``command()``, as for every device).
* ``on-device``: the microcontroller renders wall + transient at its native
  rate (the hook in docs/architecture.md): ``configure_rendering`` uploads the
  wall, limits and transient, every ``read()`` returns the next telemetry
  STATE frame, ``pop_events()`` returns the contact events the firmware reported.

Faults: garbage and partial frames are skipped by the parser's resync, CRC
failures and sequence gaps are counted (``link_stats()``), a missing reply
is retried, and a device that stops answering or disappears raises
:class:`DeviceError` naming the port, with the output zeroed (the device's
watchdog zeroes the motor when commands stop; the host never leaves a
non-zero ``last_command_A`` behind).
"""

from __future__ import annotations

import array
import collections
import inspect
import json
import math
import os
import stat
import time
import warnings
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..base import Device, DeviceError, DeviceInfo, DeviceState, Status
from plumbing.fileio import atomic_write_text, read_text_utf8
from plumbing.stopsignals import holding
from plumbing.validation import is_finite_number, shown_value
from . import wire_protocol as P
from .calibration import Calibration
from .transport import SerialTransport, Transport, TransportClosed

MODES = ("streaming", "on-device")
#: bytes of one STATE frame on the wire (header, payload, CRC: 23)
STATE_FRAME_BYTES = P.OVERHEAD + P.STATE_STRUCT.size
#: share of a UART's bandwidth the on-device telemetry may take by default: the rest carries ACKs, EVENT
#: frames and re-arm replies, and leaves slack for the firmware's transmit timing
TELEMETRY_LINK_BUDGET = 0.5
#: decimation when the link's rate is unknown (a transport other than a serial port, e.g. HID)
CONSERVATIVE_DECIMATION = 2


def default_telemetry_decimation(servo_rate_hz: float, link_bytes_per_s: float | None,
                                 frame_bytes: int = STATE_FRAME_BYTES,
                                 budget: float = TELEMETRY_LINK_BUDGET) -> int:
    """The smallest on-device telemetry decimation whose STATE frames take at most ``budget`` of the link.

    ``d = ceil(frame_bytes * servo_rate_hz / (budget * link_bytes_per_s))``, at least 1. Example: the
    4 kHz ATmega328P board at 1 Mbaud (8N1: 100 kB/s) needs 92 kB/s for a frame every tick; half the
    link allows 50 kB/s, so every 2nd tick (46 %). A link whose rate is unknown gets
    :data:`CONSERVATIVE_DECIMATION`.

    Parameters
    ----------
    servo_rate_hz : float
        The firmware's tick rate (Hz), from INFO.
    link_bytes_per_s : float or None
        What the device can send per second (bytes/s; a UART: baud / 10 for 8N1); None if unknown.
    frame_bytes : int
        Bytes per STATE frame on the wire.
    budget : float
        Share of the link the telemetry may take (0-1].

    Returns
    -------
    int
    """
    if link_bytes_per_s is None or not link_bytes_per_s > 0:
        return CONSERVATIVE_DECIMATION
    need = frame_bytes * float(servo_rate_hz) / (budget * float(link_bytes_per_s))
    return max(1, math.ceil(need - 1e-9))
RTT_RING = 65536  # round-trip samples kept for the link statistics (preallocated)
#: fresh state frames in a row with the same device time after which the device's clock counts as frozen
#: (a device fault). One repeat can be honest (a watchdog's unsolicited STATE before the next reply);
#: a STATE frame takes >= 100 us on a 1 Mbaud link, far beyond a clock tick
CLOCK_FREEZE_STATES = 3
CALIBRATION_ENV = "HFAM_CALIBRATION"
#: Lockstep devices (INFO flags bit 1): wall-clock seconds a reply may take before the link counts as dead. The
#: simulator ran 0.2-3x real time here, by load (a 1 ms host period: 0.3-5 ms of wall time), so 10 s
#: is only ever reached by a hung simulator; it bounds how long a host waits for one.
LOCKSTEP_TIMEOUT_S = 10.0


# -- calibration file ----------------------------------------------------------
def load_calibration(path, device_id: str, defaults: Calibration) -> Calibration:
    """Per-device calibration from a JSON file ``{"devices": {"<name>/<serial>": {...}}}``.

    Missing file or missing device entry: ``defaults`` (the INFO reply's factory scales).
    Raises ValueError naming the file and key for malformed content.
    """
    path = Path(path)
    if not path.exists():
        return defaults
    text = read_text_utf8(path, "calibration file")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a calibration file must hold a JSON object {{\"devices\": {{...}}}}, "
                         f"got {type(data).__name__}")
    devices = data.get("devices", {})
    if not isinstance(devices, dict):
        raise ValueError(f"{path}: devices must be an object {{\"<name>/<serial>\": {{...}}}}, "
                         f"got {type(devices).__name__}")
    entry = devices.get(device_id)
    if entry is None:
        return defaults
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: devices.{device_id} must be an object of calibration values, "
                         f"got {type(entry).__name__} {entry!r}")
    values = asdict(defaults)
    for key, value in entry.items():
        if key not in values:
            raise ValueError(f"{path}: devices.{device_id}.{key} is not a calibration key ({', '.join(values)})")
        if not is_finite_number(value):
            raise ValueError(f"{path}: devices.{device_id}.{key} must be a finite number, got {shown_value(value)}")
        values[key] = value
    if values["encoder_sign"] not in (1, -1):
        raise ValueError(f"{path}: devices.{device_id}.encoder_sign must be 1 or -1")
    for key in ("accel_scale_m_s2_per_count", "grip_scale_N_per_count"):
        if values[key] <= 0:
            raise ValueError(f"{path}: devices.{device_id}.{key} must be > 0")
    values["encoder_zero_counts"] = int(values["encoder_zero_counts"])
    values["encoder_sign"] = int(values["encoder_sign"])
    return Calibration(**values)



def save_calibration(path, device_id: str, cal: Calibration) -> Path:
    """Write/replace one device's entry, keeping the others; atomic (temp file + rename)."""
    path = Path(path)
    data = {"format": "hfam-calibration", "version": 1, "devices": {}}
    if path.exists():
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON, refusing to overwrite ({exc})") from None
        data.setdefault("devices", {})
    data["devices"][device_id] = asdict(cal)
    return atomic_write_text(path, json.dumps(data, indent=2))


def _transient_upload_kind(transient, caps: int) -> str:
    """Which upload the firmware gets for a stimuli transient: 'none', 'param', 'table' or 'rearm'."""
    name = getattr(transient, "name", "none") if transient is not None else "none"
    if name == "none":
        return "none"
    if name in ("pulse", "sinusoid") and hasattr(transient, "amplitude_Ns_m") and caps & P.CAP_PARAM_TRANSIENT:
        return "param"
    if hasattr(transient, "currents_A") and hasattr(transient, "velocities_m_s") and caps & P.CAP_TABLE_TRANSIENT:
        return "table"
    if caps & P.CAP_REARM_TRANSIENT:
        return "rearm"
    raise ValueError(f"device cannot render transient {name!r} on board (capabilities {P.capability_names(caps)})")


class ProtocolDevice(Device):
    """A :class:`Device` over any byte :class:`Transport` speaking docs/protocol.md.

    Parameters
    ----------
    mode : {"streaming", "on-device"}
    timeout_s : float
        How long ``read()`` first waits for a state frame before retrying (streaming:
        re-sends the last command); each retry doubles the wait (20, 40, 80, 160 ms by
        default: a lost frame costs 20 ms, a stalled link has 300 ms), then DeviceError.
    hello_timeout_s : float
        How long the hello handshake may take (the hello is repeated meanwhile).
    calibration : path or None
        JSON calibration file (default: ``$HFAM_CALIBRATION`` if set).
    watchdog_ms : int or None
        Device watchdog period to request (None: the firmware default from INFO).
    telemetry_decimation : int or None
        On-device mode: one telemetry STATE frame every this many firmware ticks. None (default): the
        smallest that keeps the STATE frames within half the link (:func:`default_telemetry_decimation`,
        from INFO's servo rate, the frame size and the link's rate: a serial port's baud rate; a link
        whose rate is unknown gets 2); 1 when the board reports the ``native_usb`` capability (its link
        is USB, not a UART: the baud rate means nothing there). The value used is
        ``telemetry_decimation`` once rendering is configured.
    loss_timeout_s : float
        Streaming, once the link runs: a state frame not back this long after its command is a *lost*
        frame (dropped or corrupt). The device keeps applying the last command, ``read()`` returns the
        last state (``extra["held"]`` True) and the loss is counted; no retransmit, so the servo loop is
        delayed by at most this. Default 5 ms: on a pty the round trip measured median 0.08-0.1 ms,
        p99 0.2-0.5 ms with rare 3-4 ms spikes on a loaded machine (docs/protocol.md), so 5 ms is
        above every honest reply and far below the renderer's 20 ms watchdog.
    max_consecutive_losses : int
        Stop (link declared dead, zero current sent, ``Status.DISCONNECTED``) after this many lost
        frames in a row. Default 10: 10 x 5 ms = 50 ms, half the firmware's 100 ms watchdog, so the
        host stops before the device would; at 1 kHz an isolated loss holds one 1 ms command. 0 turns
        tolerance off (every late frame is retransmitted with backoff, ``retries`` times, as before).
    max_loss_rate, loss_window : float, int
        Also stop when more than ``max_loss_rate`` of the last ``loss_window`` frames were lost
        (default 5 % of 1000: a link that bad is not rendering the sample any more).
    rearm_interval_s : float
        On-device rendering of a sampled transient (one the firmware cannot compute itself): while the
        handle approaches the wall, the host re-uploads the transient for the approach velocity and grip
        at most this often, by the host's clock or by the device's (from its telemetry), whichever runs
        faster: a simulated board may run faster than the wall clock, and re-arms paced by the host alone
        then came too seldom in device time (the transient a contact played was armed at 8 % of the contact's
        speed). One upload is in flight at a time. Default 20 ms.
    lockstep_timeout_s : float
        Used only when the device's INFO says lockstep (``fw-sim``: its clock advances only with the host's
        frames, docs/protocol.md "Lockstep"): a reply is waited for this long in wall-clock time before the
        link counts as dead (a hung simulator; a killed one closes the pty and is seen at once). A late reply
        there is the simulator's slowness, never a lost frame: no loss tolerance, no retransmit. Default 10 s.
    """

    spec_prefix = "protocol"

    def __init__(self, *, mode: str = "streaming", timeout_s: float = 0.02, hello_timeout_s: float = 1.0,
                 retries: int = 3, calibration=None, watchdog_ms: int | None = None,
                 telemetry_decimation: int | None = None, rearm_interval_s: float = 0.02, loss_timeout_s: float = 0.005,
                 max_consecutive_losses: int = 10, max_loss_rate: float = 0.05, loss_window: int = 1000,
                 lockstep_timeout_s: float = LOCKSTEP_TIMEOUT_S) -> None:
        super().__init__()
        if not (isinstance(lockstep_timeout_s, (int, float)) and math.isfinite(lockstep_timeout_s)
                and lockstep_timeout_s > 0):
            raise ValueError(f"lockstep_timeout_s must be a positive number of seconds, got {lockstep_timeout_s!r}")
        self.lockstep_timeout_s = float(lockstep_timeout_s)
        mode = str(mode).replace("_", "-")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        for key, value in (("timeout_s", timeout_s), ("hello_timeout_s", hello_timeout_s)):
            if not (isinstance(value, (int, float)) and math.isfinite(float(value)) and float(value) > 0):
                raise ValueError(f"{key} must be a positive number of seconds, got {value!r}")
        self.mode = mode
        self.timeout_s = float(timeout_s)
        self.hello_timeout_s = float(hello_timeout_s)
        self.retries = int(retries)
        self.calibration_path = calibration if calibration is not None else os.environ.get(CALIBRATION_ENV)
        self.watchdog_ms = None if watchdog_ms is None else int(watchdog_ms)
        if telemetry_decimation is not None and not (int(telemetry_decimation) >= 1):
            raise ValueError(f"telemetry_decimation must be >= 1 tick, got {telemetry_decimation!r}")
        self.telemetry_decimation_option = None if telemetry_decimation is None else int(telemetry_decimation)
        self.telemetry_decimation = self.telemetry_decimation_option  # resolved by configure_rendering
        self.rearm_interval_s = float(rearm_interval_s)
        self._info: DeviceInfo | None = None
        self.wire_info: P.WireInfo | None = None
        self.cal = Calibration()
        self._t: Transport | None = None
        self._parser = P.FrameParser()
        self._seq = 0
        self._rx_seq = None
        self._state = DeviceState()
        self._state.extra.update(t_us=0, encoder=0, current_A=0.0, accel_raw=0, grip_raw=0)
        self._have_state = False
        self._cmd_pending = False
        self._last_cmd_seq = -1
        self._last_current = 0.0
        self._states: collections.deque = collections.deque()
        self._replies: dict = {}
        self._info_payload: bytes | None = None
        self._pongs: collections.deque = collections.deque(maxlen=64)
        self._events: list[dict] = []
        self._rendering = False
        self._disconnected = False
        self._disconnect_reported = False
        self.last_error = ""
        self._last_tx = 0.0
        # the device's clock (s) at the newest telemetry and at the last frame sent: keepalives follow it too
        self._dev_t_s = 0.0
        self._last_tx_dev_t_s = 0.0
        self._t_wraps = 0
        self._t_last_us = None
        self._transient = None
        self._transient_name = "none"
        self._rearm = False
        self._rearm_truncation_warned = False
        self._last_rearm = 0.0
        self._last_rearm_dev_t_s = 0.0  # device clock of the last re-arm (see rearm_interval_s)
        self._upload_q: collections.deque = collections.deque()  # re-arm frames not yet sent (one in flight)
        self._upload_key = None  # (type, seq) of the re-arm frame in flight
        self._upload_sent = 0.0
        self._rearm_ages: collections.deque = collections.deque(maxlen=4096)  # see link_stats: rearm_age_*
        self._vel_ring = [(0.0, 0.0)] * 10
        self._vel_i = 0
        self._wall_height_m = 0.0
        self.stats = {"crc_errors": 0, "garbage_bytes": 0, "seq_gaps": 0, "duplicates": 0, "timeouts": 0,
                      "retransmits": 0, "stale_states": 0, "frames_rx": 0, "frames_tx": 0, "naks": 0,
                      "watchdog_trips": 0, "losses": 0, "max_consecutive_losses": 0, "rearms": 0,
                      "malformed_frames": 0}
        self._newer_minor = False  # the device speaks a newer minor version: fixed payloads may grow
        self._clock_repeats = 0
        self._unreported = 0  # one-time status reports (a watchdog trip) carried by a stale reply, not yet returned
        self._raw_status = 0  # the last reply's status as the device sent it (a trip is counted on its first flag)
        if not (isinstance(loss_timeout_s, (int, float)) and 0 < loss_timeout_s < 1):
            raise ValueError(f"loss_timeout_s must be within (0, 1) s, got {loss_timeout_s!r}")
        if not (0 < float(max_loss_rate) <= 1) or int(loss_window) < 1 or int(max_consecutive_losses) < 0:
            raise ValueError("max_loss_rate must be in (0, 1], loss_window >= 1, max_consecutive_losses >= 0")
        self.loss_timeout_s = float(loss_timeout_s)
        self.max_consecutive_losses = int(max_consecutive_losses)
        self.max_loss_rate = float(max_loss_rate)
        self.loss_window = int(loss_window)
        self._loss_ring = bytearray(self.loss_window)  # preallocated: no allocation per tick
        self._loss_i = 0
        self._loss_sum = 0
        self._consecutive = 0
        self._rtt_ring = array.array("d", bytes(8 * RTT_RING))
        self._rtt_n = 0
        self._last_rx_state = None
        self._longest_gap_s = 0.0

    # -- identity ------------------------------------------------------------------
    @property
    def name(self) -> str:
        """The device string prefix this driver was opened with."""
        return self.spec_prefix

    @property
    def info(self) -> DeviceInfo:
        """DeviceInfo from the hello handshake; DeviceError before ``open()``."""
        if self._info is None:
            raise DeviceError(f"{self.name}: info comes from the hello handshake; open the device first")
        return self._info

    @info.setter
    def info(self, value: DeviceInfo) -> None:
        """DeviceInfo from the hello handshake; DeviceError before ``open()``."""
        self._info = value

    @property
    def on_device_rendering(self) -> bool:
        """True when the firmware renders the wall and transient itself (``mode=on-device``)."""
        return self.mode == "on-device"

    def _make_transport(self) -> Transport:
        raise NotImplementedError

    def link_bytes_per_s(self) -> float | None:
        """Bytes per second the device can send over this link, or None when the transport does not say."""
        return None

    # -- lifecycle ---------------------------------------------------------------------
    def _reset_link(self) -> None:
        """Forget everything about a previous connection (the object may be reopened after a disconnect)."""
        self._parser = P.FrameParser()
        self._rx_seq = None
        self._states.clear()
        self._replies.clear()
        self._upload_q.clear()
        self._upload_key = None
        self._info_payload = None
        self._have_state = False
        self._cmd_pending = False
        self._rendering = False
        self._disconnected = False
        self._disconnect_reported = False
        self.last_error = ""
        self._state.status = 0
        self._state.extra.pop("error", None)
        self._t_wraps = 0
        self._t_last_us = None
        self._newer_minor = False
        self._clock_repeats = 0
        self._unreported = 0
        self._raw_status = 0

    def _open(self) -> None:
        self._reset_link()
        try:
            self._t = self._make_transport()
        except TransportClosed as exc:
            raise DeviceError(str(exc)) from None
        try:
            self._handshake()
        except BaseException:
            self._t.close()
            self._t = None
            raise

    def _handshake(self) -> None:
        deadline = time.monotonic() + self.hello_timeout_s
        next_hello = 0.0
        while self._info_payload is None:
            now = time.monotonic()
            if now >= deadline:
                raise DeviceError(
                    f"{self.name}: no answer to the hello within {self.hello_timeout_s:g} s "
                    f"({self._parser.garbage_bytes} garbage bytes, {self._parser.crc_errors} bad CRCs received); "
                    "is it a hfam-protocol device on the right port?")
            if now >= next_hello:
                self._tx(P.HELLO, P.HELLO_STRUCT.pack(*P.PROTOCOL_VERSION))
                next_hello = now + 0.2
            self._poll(min(0.05, deadline - now))
            for key, (ok, text) in list(self._replies.items()):
                if key[0] == P.HELLO and not ok:
                    raise DeviceError(f"{self.name}: {text}")
        try:
            wire = P.decode_info(self._info_payload)
        except P.ProtocolError as exc:
            raise DeviceError(f"{self.name}: bad INFO reply: {exc}") from None
        if wire.protocol_version[0] != P.PROTOCOL_VERSION[0]:
            raise DeviceError(
                f"{self.name}: device speaks protocol {wire.protocol_version[0]}.{wire.protocol_version[1]}, this host "
                f"speaks {P.PROTOCOL_VERSION[0]}.{P.PROTOCOL_VERSION[1]}; update the firmware or the host")
        if self.on_device_rendering and not wire.capability_bits & P.CAP_ON_DEVICE:
            raise DeviceError(f"{self.name}: mode on-device requested but the device only offers "
                              f"{wire.info.capabilities}")
        self.wire_info = wire
        self._info = wire.info
        if wire.info.lockstep_ticks and not self._may_run_lockstep():
            raise DeviceError(f"{self.name}: the device's INFO says lockstep (flags bit 1: a simulated clock that "
                              "waits for the host), but only a simulator on a pseudo-terminal may run so; a board "
                              "must report flags bit 1 clear. Refused: lockstep turns off the host's loss "
                              "detection and the renderer's wall-clock watchdog (docs/protocol.md 'Lockstep')")
        if wire.info.lockstep_ticks:
            # the device's clock is simulated and waits for the host (docs/protocol.md "Lockstep"): its replies
            # come when the simulator gets there, so wall-clock waits are long and a late reply is no loss
            self.max_consecutive_losses = 0
            self.timeout_s = max(self.timeout_s, self.lockstep_timeout_s)
            self.retries = 0
        self._newer_minor = wire.protocol_version[1] > P.PROTOCOL_VERSION[1]
        defaults = Calibration(0, 1, wire.accel_scale_m_s2_per_count, wire.accel_offset_counts,
                               wire.grip_scale_N_per_count, wire.grip_offset_counts)
        self.cal = (load_calibration(self.calibration_path, wire.device_id, defaults)
                    if self.calibration_path else defaults)
        if self.watchdog_ms is not None:
            self._request(P.SET_WATCHDOG, P.WATCHDOG_STRUCT.pack(self.watchdog_ms))
        self._request(P.SET_MODE, P.MODE_STRUCT.pack(P.MODE_STREAMING, 1))
        self._request(P.CLEAR_FAULTS)

    def _may_run_lockstep(self) -> bool:
        """Whether this link may be a simulator in lockstep: only a serial pseudo-terminal (SerialDevice)."""
        return False

    def _close(self) -> None:
        if self._t is not None:
            self._t.close()
            self._t = None
        self._rendering = False

    def close(self) -> None:
        """Zero the output (confirmed by the device's reply when it answers), then release the port.

        A SIGTERM/SIGHUP arriving meanwhile (plumbing.stopsignals) is raised after both, not in between."""
        with holding():
            if self._is_open and not self._disconnected:
                try:
                    if self._rendering:
                        self.stop_rendering()
                    self.zero()
                    self.read()  # the STATE reply confirms the zero reached the firmware
                except (DeviceError, ValueError):
                    pass
            super().close()

    # -- low level I/O -------------------------------------------------------------
    def _fail(self, why: str) -> DeviceError:
        """Mark the link dead, zero what the host believes it commands, and build the error."""
        self._disconnected = True
        self.last_command_A = 0.0
        self._state.status |= Status.DISCONNECTED
        self.last_error = f"{self.name}: {why}"
        self._state.extra["error"] = self.last_error
        return DeviceError(self.last_error)

    def _fault(self, why: str) -> DeviceError:
        """The device misbehaves although the link works (its clock ran backwards or froze): zero its output
        now (streaming: a zero CURRENT; on board: RENDER_STOP, which zeroes it), then stop as for a dead link
        (``Status.DISCONNECTED`` with ``Status.FAULT``; the error says ``device fault``)."""
        for msg_type, payload in ((P.RENDER_STOP, b""), (P.CURRENT, P.encode_current(0.0))) if self._rendering \
                else ((P.CURRENT, P.encode_current(0.0)),):
            try:
                self._tx(msg_type, payload)
            except DeviceError:
                break
        err = self._fail(f"device fault: {why}; output zeroed")
        self._state.status |= Status.FAULT
        self._state.extra["fault"] = True
        return err

    def _tx(self, msg_type: int, payload: bytes = b"") -> int:
        if self._disconnected or self._t is None:
            raise DeviceError(f"{self.name}: link is closed or disconnected")
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        try:
            self._t.write(P.encode_frame(msg_type, seq, payload))
        except TransportClosed as exc:
            raise self._fail(f"disconnected ({exc}); output zeroed by the device watchdog") from None
        self._last_tx = time.monotonic()
        self._last_tx_dev_t_s = self._dev_t_s
        self.stats["frames_tx"] += 1
        return seq

    def _poll(self, timeout_s: float) -> None:
        try:
            data = self._t.read(timeout_s)
        except TransportClosed as exc:
            raise self._fail(f"disconnected ({exc}); output zeroed by the device watchdog") from None
        if data:
            for frame in self._parser.feed(data):
                self._dispatch(frame)
            self.stats["crc_errors"] = self._parser.crc_errors
            self.stats["garbage_bytes"] = self._parser.garbage_bytes

    def _dispatch(self, frame: P.Frame) -> None:
        if P.check_frame_size(frame.type, len(frame.payload), self._newer_minor):
            # CRC intact but the wrong size or type: dropped and counted, as a frame with a bad CRC is
            # (a STATE lost this way is a counted loss: the next tick goes on with the last state)
            self.stats["malformed_frames"] += 1
            return
        last = self._rx_seq
        if last is not None:
            if frame.seq == last:
                self.stats["duplicates"] += 1
                return
            gap = (frame.seq - last - 1) & 0xFF
            if gap > 200:  # far "behind": a stale or duplicated older frame, not 200+ lost ones
                self.stats["duplicates"] += 1
                return
            self.stats["seq_gaps"] += gap
        self._rx_seq = frame.seq
        self.stats["frames_rx"] += 1
        t = frame.type
        if t == P.STATE:
            self._states.append(frame.payload[:P.STATE_STRUCT.size])  # a newer minor's appended fields ignored
        elif t == P.EVENT:
            self._on_event(frame.payload[:P.EVENT_STRUCT.size])
        elif t == P.ACK:
            if len(frame.payload) == 2:
                if tuple(frame.payload) == self._upload_key:
                    if self._upload_key[0] == P.REARM_COMMIT:
                        self.stats["rearms"] += 1
                        # one upload in flight at a time: the last re-arm's clock is the velocity it carries
                        self._rearm_ages.append(self._dev_t_s - self._last_rearm_dev_t_s)
                    self._upload_next()
                else:
                    self._replies[tuple(frame.payload)] = (True, "")
        elif t == P.NAK:
            self.stats["naks"] += 1
            if len(frame.payload) >= 3:
                if (frame.payload[0], frame.payload[1]) == self._upload_key:
                    self._upload_q.clear()  # e.g. NAK 3 while the last transient still plays: re-armed later
                    self._upload_key = None
                else:
                    self._replies[(frame.payload[0], frame.payload[1])] = (False, P.describe_nak(frame.payload))
        elif t == P.INFO:
            self._info_payload = frame.payload
        elif t == P.PONG:
            self._pongs.append(frame.payload)

    def _request(self, msg_type: int, payload: bytes = b"", timeout_s: float | None = None) -> None:
        """Send a configuration frame and wait for its ACK (retrying); NAK -> ValueError."""
        timeout_s = max(self.timeout_s, 0.05) if timeout_s is None else timeout_s
        for _ in range(self.retries + 1):
            seq = self._tx(msg_type, payload)
            key = (msg_type, seq)
            deadline = time.monotonic() + timeout_s
            while key not in self._replies:
                left = deadline - time.monotonic()
                if left <= 0:
                    # a thread descheduled past its deadline (loaded machine) may find the ACK already in the
                    # tty: take it. Sending the request again would run it twice on the device (a second
                    # RENDER_START restarts the wall mid-run: observer energy, velocity window, contact state).
                    self._poll(0.0)
                    break
                self._poll(left)
            reply = self._replies.pop(key, None)
            if reply is None:
                self.stats["timeouts"] += 1
                for frame in self._parser.skip_partial():
                    self._dispatch(frame)
                reply = self._replies.pop(key, None)
            if reply is None:
                continue
            ok, text = reply
            if not ok:
                raise ValueError(f"{self.name}: {text}")
            return
        raise self._fail(f"no acknowledgement of {P.TYPE_NAMES.get(msg_type)} after {self.retries + 1} tries "
                         f"of {timeout_s * 1000:.0f} ms; device not responding")

    # -- servo cycle ----------------------------------------------------------------
    def _send_current(self, current_A: float) -> None:
        if self._disconnected or self._t is None:
            return  # nothing to command; the device watchdog has zeroed the motor
        if self._rendering:
            if current_A != 0.0:
                raise DeviceError(f"{self.name}: the device renders on board; call stop_rendering() "
                                  "before commanding current")
            return
        self._last_current = current_A
        try:
            self._last_cmd_seq = self._tx(P.CURRENT, P.encode_current(current_A))
        except DeviceError:
            return  # marked disconnected; the next read() reports it (servo loops check status there)
        self._cmd_pending = True

    def read(self) -> DeviceState:
        """Next state sample (see module doc).

        When the link dies (disconnect, or no reply after ``retries`` timeouts) the first
        ``read()`` returns the last state with ``Status.DISCONNECTED`` set and the error text in
        ``state.extra["error"]`` (so a servo loop can stop and save its data), later calls raise
        :class:`DeviceError`.
        """
        if self._disconnected:
            if not self._disconnect_reported:
                self._disconnect_reported = True
                return self._state
            raise DeviceError(self.last_error or f"{self.name}: disconnected; reopen the device")
        if self._t is None:
            raise DeviceError(f"{self.name}: device is not open")
        try:
            return self._read_telemetry() if self._rendering else self._read_streaming()
        except DeviceError:
            if self._disconnected and not self._disconnect_reported:
                self._disconnect_reported = True
                return self._state
            raise

    def _loss_mark(self, lost: int) -> None:
        ring, i = self._loss_ring, self._loss_i
        self._loss_sum += lost - ring[i]
        ring[i] = lost
        self._loss_i = (i + 1) % self.loss_window

    def _got_state(self, now: float) -> None:
        """Bookkeeping for a state frame answering the current command (round trip, gap, loss window)."""
        self._rtt_ring[self._rtt_n % RTT_RING] = now - self._last_tx
        self._rtt_n += 1
        if self._last_rx_state is not None and now - self._last_rx_state > self._longest_gap_s:
            self._longest_gap_s = now - self._last_rx_state
        self._last_rx_state = now
        self._consecutive = 0
        self._loss_mark(0)

    def _read_streaming_tolerant(self) -> DeviceState:
        """Streaming once the link runs: a missing reply is a counted loss and the last state is held."""
        deadline = self._last_tx + self.loss_timeout_s
        while True:
            states = self._states
            while states:
                raw = P.decode_state(states.popleft())
                if raw.cmd_seq == self._last_cmd_seq:
                    states.clear()
                    self._cmd_pending = False
                    self._got_state(time.monotonic())
                    self._state.extra["held"] = False
                    return self._apply(raw)
                self.stats["stale_states"] += 1
                self._apply_stale(raw)
            left = deadline - time.monotonic()
            if left <= 0 and not self._final_poll():
                for frame in self._parser.skip_partial():
                    self._dispatch(frame)
                if self._states:
                    continue
                self._cmd_pending = False
                self.stats["losses"] += 1
                self._consecutive += 1
                self.stats["max_consecutive_losses"] = max(self.stats["max_consecutive_losses"], self._consecutive)
                self._loss_mark(1)
                rate = self._loss_sum / self.loss_window
                if self._consecutive >= self.max_consecutive_losses or rate > self.max_loss_rate:
                    why = (f"{self._consecutive} state frames lost in a row" if self._consecutive >=
                           self.max_consecutive_losses else
                           f"{self._loss_sum} of the last {self.loss_window} state frames lost")
                    try:  # the device still hears us: zero it now rather than at its watchdog
                        self._tx(P.CURRENT, P.encode_current(0.0))
                    except DeviceError:
                        pass
                    raise self._fail(f"{why} (limit: {self.max_consecutive_losses} in a row or "
                                     f"{self.max_loss_rate:.0%} of {self.loss_window}); output zeroed")
                self._state.extra["held"] = True
                return self._state  # the device holds the last command; the loop carries on
            self._poll(left)

    def _read_streaming(self) -> DeviceState:
        if not self._cmd_pending and self._have_state:
            return self._state  # host-paced: no new sample exists until the next command
        if not self._cmd_pending:
            self._send_current(0.0)
        if self._have_state and self.max_consecutive_losses > 0:
            return self._read_streaming_tolerant()
        tries = 0
        wait = self.timeout_s
        deadline = time.monotonic() + wait
        t_start = time.monotonic()
        while True:
            states = self._states
            while states:
                raw = P.decode_state(states.popleft())
                if raw.cmd_seq == self._last_cmd_seq:
                    states.clear()
                    self._cmd_pending = False
                    return self._apply(raw)
                self.stats["stale_states"] += 1
                self._apply_stale(raw)
            left = deadline - time.monotonic()
            if left <= 0 and not self._final_poll():
                self.stats["timeouts"] += 1
                tries += 1
                if tries > self.retries:
                    raise self._fail(f"no state frame within {(time.monotonic() - t_start) * 1000:.0f} ms "
                                     f"({tries} tries); device not responding (output zeroed by its watchdog)")
                for frame in self._parser.skip_partial():
                    self._dispatch(frame)
                self.stats["retransmits"] += 1
                self._last_cmd_seq = self._tx(P.CURRENT, P.encode_current(self._last_current))
                wait *= 2  # back off: a lost frame is retried at once, a stalled link gets time
                deadline = time.monotonic() + wait
                continue
            self._poll(left)

    def _read_telemetry(self) -> DeviceState:
        # the device free-runs: a late frame means a stalled link or device, never a lost command
        wait = max(self.timeout_s, 0.05)
        t_start = time.monotonic()
        deadline = t_start + wait
        tries = 0
        states = self._states
        while not states:
            now = time.monotonic()
            self._keepalive(now)
            left = deadline - now
            if left <= 0 and not self._final_poll():
                self.stats["timeouts"] += 1
                tries += 1
                # a STATE half received when the device (a simulator on a loaded machine) paused is kept: it
                # completes when the rest comes (given up on, its rest was garbage and the frame a seq gap)
                if not self._parser.pending_is_well_formed():
                    for frame in self._parser.skip_partial():
                        self._dispatch(frame)
                if tries > self.retries:
                    raise self._fail(f"no telemetry for {(now - t_start) * 1000:.0f} ms; device not responding")
                wait *= 2
                deadline = now + wait
                continue
            self._poll(min(left, 0.005))
        state = self._apply(P.decode_state(states.popleft()))
        self._dev_t_s = state.t_s
        now = time.monotonic()
        self._keepalive(now)
        if self._rearm:
            self._maybe_rearm(now, state)
        return state

    def _final_poll(self) -> bool:
        """At a deadline: take what already arrived (non-blocking) before calling it a timeout.

        A host thread that was descheduled (loaded machine, another thread holding the GIL)
        may wake after its deadline with the reply already waiting in the tty buffer.
        """
        n = len(self._states)
        self._poll(0.0)
        return len(self._states) > n

    def _keepalive(self, now: float) -> None:
        # every quarter of the watchdog period, by the host's clock or by the device's (from its telemetry),
        # whichever runs faster: a simulated board can run faster than the wall clock (fw-sim's fast pace), and a
        # keepalive paced by the host alone then let its watchdog trip between two (zero current for 8-100 ms)
        wd_s = (self.wire_info.watchdog_ms if self.watchdog_ms is None else self.watchdog_ms) * 1e-3
        if now - self._last_tx > 0.25 * wd_s or self._dev_t_s - self._last_tx_dev_t_s > 0.25 * wd_s:
            self._tx(P.KEEPALIVE)

    def _unwrap_us(self, t_us: int) -> float:
        last = self._t_last_us
        if last is not None:
            self._check_clock(last, t_us)
        if last is not None and t_us < last and last - t_us > 0x80000000:
            self._t_wraps += 1
        self._t_last_us = t_us
        return (self._t_wraps * 4294967296 + t_us) * 1e-6

    def _check_clock(self, last: int, t_us: int) -> None:
        """A fresh state's device clock must advance: backwards (by less than half the 2^32 us wrap, beyond
        which it is the wrap) or unchanged for :data:`CLOCK_FREEZE_STATES` states in a row is a device fault:
        events would get wrong times and every velocity estimate divides by the clock."""
        delta = ((t_us - last + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        if delta < 0:
            raise self._fault(f"its clock went backwards from t_us={last} to t_us={t_us} ({delta} us)")
        if delta == 0:
            self._clock_repeats += 1
            if self._clock_repeats >= CLOCK_FREEZE_STATES:
                raise self._fault(f"its clock is frozen at t_us={t_us} ({self._clock_repeats + 1} state frames "
                                  "with the same time)")
        else:
            self._clock_repeats = 0

    def _apply(self, raw: P.RawState) -> DeviceState:
        cal = self.cal
        st = self._state
        st.t_s = self._unwrap_us(raw.t_us)
        st.position_m = cal.encoder_sign * (raw.encoder - cal.encoder_zero_counts) * self._info.position_resolution_m
        st.accel_m_s2 = (raw.accel_raw - cal.accel_offset_counts) * cal.accel_scale_m_s2_per_count
        st.grip_N = (raw.grip_raw - cal.grip_offset_counts) * cal.grip_scale_N_per_count
        self._apply_status_only(raw)
        ex = st.extra
        ex["t_us"] = raw.t_us
        ex["encoder"] = raw.encoder
        ex["accel_raw"] = raw.accel_raw
        ex["grip_raw"] = raw.grip_raw
        ex["current_A"] = raw.current_mA * 1e-3
        self._have_state = True
        return st

    def _apply_status_only(self, raw: P.RawState) -> None:
        if raw.status & Status.WATCHDOG_TRIPPED and not self._raw_status & Status.WATCHDOG_TRIPPED:
            self.stats["watchdog_trips"] += 1
        self._raw_status = raw.status
        self._state.status = raw.status | self._unreported
        self._unreported = 0

    def _apply_stale(self, raw: P.RawState) -> None:
        """A reply to an earlier command (a resend's first answer, come late): its status counts, and its one-time
        watchdog-trip report is kept for the state :meth:`read` returns next. The device flags a trip in one reply
        only, and after a resend that reply may be the one the driver does not return."""
        keep = self._unreported | (raw.status & Status.WATCHDOG_TRIPPED)
        self._apply_status_only(raw)
        self._unreported = keep

    def clear_faults(self) -> None:
        """Clear the latched FAULT (a non-finite command keeps the output at zero until this)."""
        self._request(P.CLEAR_FAULTS)
        self._state.status &= ~int(Status.WATCHDOG_TRIPPED | Status.FAULT)
        self._raw_status &= ~int(Status.WATCHDOG_TRIPPED | Status.FAULT)
        self._unreported = 0

    def ping(self, payload: bytes = b"") -> float:
        """Round trip of a PING in seconds (no actuation, no physics step)."""
        self._pongs.clear()
        t0 = time.perf_counter()
        self._tx(P.PING, payload)
        deadline = time.monotonic() + max(self.timeout_s, 0.05)
        while not self._pongs:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceError(f"{self.name}: no PONG within {max(self.timeout_s, 0.05) * 1000:.0f} ms")
            self._poll(left)
        return time.perf_counter() - t0

    def restart_link_timing(self) -> None:
        """Start the round-trip, longest-gap and re-arm age figures afresh (the counters stay): a servo loop calls
        it after its priming cycle, so its run's figures cover its ticks, not its one-time start-up (e.g. a JIT)."""
        self._rtt_n = 0
        self._rearm_ages.clear()
        self._last_rx_state = None
        self._longest_gap_s = 0.0

    def link_stats(self) -> dict:
        """Link counters and timing.

        Returns
        -------
        dict
            ``frames_tx``/``frames_rx``, ``crc_errors``, ``losses`` (state frames not back within
            ``loss_timeout_s``), ``max_consecutive_losses``, ``seq_gaps``, ``duplicates``, ``timeouts``,
            ``retransmits``, ``naks``, ``garbage_bytes``, ``stale_states``, ``watchdog_trips``,
            ``longest_gap_s`` (longest time between two answered commands' states) and the command->state
            round trip ``rtt_median_s``/``rtt_p99_s``/``rtt_max_s`` (over the last 65536 replies); ``rearms``:
            sampled transients re-armed while rendering, every frame acknowledged up to the commit, and
            ``rearm_age_median_s``/``rearm_age_max_s`` (over the last 4096; None before one): how old, by the
            device's clock (its latest state read), the velocity a re-arm carried was when its commit was
            acknowledged. A contact plays the last committed re-arm, so its velocity is up to
            ``rearm_interval_s`` plus this old.
        """
        out = dict(self.stats)
        n = min(self._rtt_n, RTT_RING)
        rtt = sorted(self._rtt_ring[:n]) if n else []
        ages = sorted(self._rearm_ages)
        out.update(rearm_age_median_s=ages[len(ages) // 2] if ages else None,
                   rearm_age_max_s=ages[-1] if ages else None)
        out.update(longest_gap_s=self._longest_gap_s, rtt_samples=n,
                   rtt_median_s=rtt[n // 2] if n else None,
                   rtt_p99_s=rtt[min(n - 1, int(0.99 * n))] if n else None,
                   rtt_max_s=rtt[-1] if n else None,
                   loss_timeout_s=self.loss_timeout_s, max_consecutive_losses_allowed=self.max_consecutive_losses)
        return out

    # -- calibration -------------------------------------------------------------------
    def _mean_raw(self, n: int) -> tuple[float, float, float]:
        enc = acc = grip = 0.0
        for _ in range(n):
            self.read()
            ex = self._state.extra
            enc += ex["encoder"]
            acc += ex["accel_raw"]
            grip += ex["grip_raw"]
            if not self._rendering:
                self.command(0.0)
        return enc / n, acc / n, grip / n

    def calibrate_encoder_zero(self, known_position_m: float = 0.0, n: int = 20) -> int:
        """Hold the handle at ``known_position_m`` and call this: sets the encoder zero (eq. 3.3)."""
        enc, _, _ = self._mean_raw(n)
        res = self.info.position_resolution_m
        self.cal.encoder_zero_counts = int(round(enc - self.cal.encoder_sign * known_position_m / res))
        return self.cal.encoder_zero_counts

    def calibrate_sensor_offsets(self, n: int = 200, accel: bool = True, grip: bool = True) -> None:
        """With the handle at rest (and, for grip, not held): zero offsets of accelerometer and grip sensor."""
        _, acc, grp = self._mean_raw(n)
        if accel:
            self.cal.accel_offset_counts = acc
        if grip:
            self.cal.grip_offset_counts = grp

    def save_calibration(self, path=None) -> Path:
        """Write the current calibration for this device's id to ``path`` (default: the ``calibration`` option
        or ``$HFAM_CALIBRATION``); returns the path. ValueError when no file is given.
        """
        path = path or self.calibration_path
        if not path:
            raise ValueError("no calibration file given (calibration= option or $HFAM_CALIBRATION)")
        return save_calibration(path, self.wire_info.device_id, self.cal)

    # -- on-device rendering hook (docs/architecture.md) ----------------------------
    def configure_rendering(self, wall: dict, limits: dict, transient=None) -> None:
        """Upload wall, limits and transient, then start on-board rendering (see module doc).

        ``wall``: height_m, stiffness_N_m, damping_N_s_m, rearm_margin_m, and optionally the wall's passivity
        observer (protocol 1.1; ``renderer.passivity.passivity_constants`` computes them): instability_limit_J
        (stop once the wall generated more than this, J; 0 or absent: off) and instability_leak (``1 -
        exp(-T / window)`` per device tick). The device then stops on its own with zero output and reports
        status FAULT + UNSTABLE (``Status.UNSTABLE``); a 1.0 device gets the 16-byte WALL (no observer, warned);
        ``limits``: continuous_A, peak_A and optionally amplifier_A, each a finite number >= 0 (ValueError
        naming the key otherwise), clamped to the device's own (the device refuses, ValueError, unless
        continuous <= peak after the clamp, the peak also clamped to amplifier_A);
        ``transient``: a stimuli transient (pulse/sinusoid -> parameters, HfamLibrary -> table,
        anything else -> a sampled transient the host re-arms from the approach velocity and grip).
        """
        if not self.on_device_rendering:
            raise DeviceError(f"{self.name}: opened in streaming mode; use mode='on-device' to render on board")
        if not self._is_open:
            raise DeviceError(f"{self.name}: open the device before configure_rendering")
        w = [_number(wall, key, "wall") for key in ("height_m", "stiffness_N_m", "damping_N_s_m", "rearm_margin_m")]
        po_limit = _number(wall, "instability_limit_J", "wall") if "instability_limit_J" in wall else 0.0
        po_leak = _number(wall, "instability_leak", "wall") if "instability_leak" in wall else 0.0
        if po_limit < 0 or not 0.0 <= po_leak < 1.0:
            raise ValueError(f"wall: instability_limit_J must be >= 0 and instability_leak in [0, 1), got "
                             f"{po_limit!r} and {po_leak!r}")
        info = self.info
        lim = [_limit(limits, key) for key in ("continuous_A", "peak_A")]
        amp = _limit(limits, "amplifier_A") if "amplifier_A" in limits else info.current_amplifier_A
        cont = min(lim[0], info.current_continuous_A)
        peak = min(lim[1], info.current_peak_A)
        amp = min(amp, info.current_amplifier_A)
        caps = self.wire_info.capability_bits
        kind = _transient_upload_kind(transient, caps)
        if transient is not None:
            transient.check_device(info, info.servo_rate_hz)
        if self._rendering:
            self.stop_rendering()
        self._upload_q.clear()  # a re-arm still under way is void: its ACKs must not send more of it
        self._upload_key = None
        self._request(P.SET_CALIBRATION, self.cal.to_payload())
        if po_limit > 0 and self.wire_info.protocol_version < (1, 1):
            warnings.warn(f"{self.name}: the device speaks protocol {self.wire_info.protocol_version[0]}."
                          f"{self.wire_info.protocol_version[1]}, before the wall's passivity observer (1.1): "
                          "an unstable on-device wall is not stopped by it", RuntimeWarning, stacklevel=2)
            po_limit = 0.0
        if po_limit > 0:
            self._request(P.WALL, P.WALL_OBSERVER_STRUCT.pack(*w, po_limit, po_leak))
        else:
            self._request(P.WALL, P.WALL_STRUCT.pack(*w))
        self._request(P.LIMITS, P.LIMITS_STRUCT.pack(cont, peak, amp))
        self._rearm = False
        if kind == "none":
            self._request(P.TRANSIENT_PARAM, P.TRANSIENT_PARAM_STRUCT.pack(P.TRANSIENT_NONE, 0, 0, 0, 0))
        elif kind == "param":
            amp_ns = transient.gain * transient.amplitude_Ns_m
            if transient.name == "pulse":
                body = P.TRANSIENT_PARAM_STRUCT.pack(P.TRANSIENT_PULSE, amp_ns, transient.duration_s, 0.0, 0.0)
            else:
                body = P.TRANSIENT_PARAM_STRUCT.pack(P.TRANSIENT_SINUSOID, amp_ns, transient.duration_s,
                                                     transient.frequency_hz, 0.0)
            self._request(P.TRANSIENT_PARAM, body)
        elif kind == "table":
            self._upload_table(transient)
        else:
            self._rearm = True
            self._last_rearm, self._last_rearm_dev_t_s = time.monotonic(), self._dev_t_s  # this upload is a re-arm
            self._upload_rearm(transient, 0.1, 2.0, wait=True)
        self._transient = transient
        self._transient_name = getattr(transient, "name", "none") if transient is not None else "none"
        self._wall_height_m = w[0]
        dec = self.telemetry_decimation_option
        if dec is None and self.wire_info.capability_bits & P.CAP_NATIVE_USB:
            dec = 1  # the board says its link is native USB: a baud rate does not limit it
        if dec is None:
            dec = default_telemetry_decimation(info.servo_rate_hz, self.link_bytes_per_s())
        self.telemetry_decimation = dec
        self._request(P.SET_MODE, P.MODE_STRUCT.pack(P.MODE_ON_DEVICE, dec))
        self._request(P.CLEAR_FAULTS)
        self._states.clear()
        self._events.clear()
        self._request(P.RENDER_START)
        self._rendering = True

    def _upload_table(self, lib) -> None:
        c = np.asarray(lib.currents_A, dtype=float)
        n_v, n_g, n_s = c.shape
        if c.size > self.wire_info.max_table_samples:
            raise ValueError(f"{self.name}: HFAM library of {c.size} samples exceeds the device's table memory "
                             f"({self.wire_info.max_table_samples} samples)")
        self._request(P.TABLE_BEGIN, P.encode_table_begin(lib.velocities_m_s, lib.grips_N, n_s, lib.fs_hz,
                                                          lib.gain, lib.max_extrapolation))
        flat = c.reshape(-1).tolist()
        step = P.DATA_CHUNK_SAMPLES  # one frame at a time, each fits the device's receive buffer
        for off in range(0, len(flat), step):
            self._request(P.TABLE_DATA, P.encode_data_chunk(off, flat[off:off + step]))
        self._request(P.TABLE_COMMIT, P.DATA_OFFSET_STRUCT.pack(len(flat)))

    def _upload_rearm(self, transient, v_in_m_s: float, grip_N: float, wait: bool) -> None:
        fs = self.info.servo_rate_hz
        current = transient.waveform(v_in_m_s, grip_N, fs) / self.info.force_per_amp_N_A
        limit = self.wire_info.max_table_samples
        if len(current) > limit and not self._rearm_truncation_warned:
            self._rearm_truncation_warned = True
            warnings.warn(f"{self.name}: transient of {len(current)} samples truncated to the device's "
                          f"{limit}-sample buffer ({limit / fs * 1000:.1f} ms)", RuntimeWarning, stacklevel=3)
        samples = [float(x) for x in current[:limit]]
        step = P.DATA_CHUNK_SAMPLES
        frames = [(P.REARM_DATA, P.encode_data_chunk(off, samples[off:off + step]))
                  for off in range(0, len(samples), step)]
        frames.append((P.REARM_COMMIT, P.DATA_OFFSET_STRUCT.pack(len(samples))))
        if wait:
            for msg_type, payload in frames:
                self._request(msg_type, payload)
            return
        # while rendering: no blocking, but still one frame in flight. Frames sent back to back overran the
        # firmware's 128-byte receive ring (it parses slower than 1 Mbaud arrives, and handles a data frame for
        # ~20,000 cycles): bytes were dropped and every long frame failed its CRC (docs/protocol.md).
        self._upload_q = collections.deque(frames)
        self._upload_key = None
        self._upload_next()

    def _upload_next(self) -> None:
        """Send the next queued re-arm frame (after the ACK of the previous one)."""
        self._upload_key = None
        if not self._upload_q:
            return
        msg_type, payload = self._upload_q.popleft()
        try:
            seq = self._tx(msg_type, payload)
        except DeviceError:
            self._upload_q.clear()
            return
        self._upload_key = (msg_type, seq)
        self._upload_sent = time.monotonic()

    def _maybe_rearm(self, now: float, st: DeviceState) -> None:
        """While the handle approaches the wall from above, keep the armed transient matched to its velocity."""
        ring = self._vel_ring
        i = self._vel_i
        t_old, x_old = ring[i]
        ring[i] = (st.t_s, st.position_m)
        self._vel_i = (i + 1) % len(ring)
        if self._upload_key is not None:  # an upload is under way: wait for it (or give it up when no ACK came)
            if now - self._upload_sent < max(self.timeout_s, 0.05) * (self.retries + 1):
                return
            self.stats["timeouts"] += 1
            self._upload_q.clear()
            self._upload_key = None
        if st.t_s <= t_old:
            return
        # due by the host's clock or by the device's, whichever runs faster
        if (now - self._last_rearm < self.rearm_interval_s
                and st.t_s - self._last_rearm_dev_t_s < self.rearm_interval_s):
            return
        v = (st.position_m - x_old) / (st.t_s - t_old)
        if v < -0.005 and st.position_m > self._wall_height_m:
            self._last_rearm = now
            self._last_rearm_dev_t_s = st.t_s
            self._upload_rearm(self._transient, -v, st.grip_N, wait=False)

    def _on_event(self, payload: bytes) -> None:
        ev = P.decode_event(payload)  # its size was checked in _dispatch
        if not all(math.isfinite(ev[k]) for k in ("incoming_velocity_m_s", "grip_N", "max_penetration_m",
                                                  "peak_accel_m_s2")):
            self.stats["malformed_frames"] += 1  # NaN/inf never reaches an event
            return
        last = self._t_last_us if self._t_last_us is not None else ev["t_us"]
        delta = ((ev["t_us"] - last + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        t_s = (self._t_wraps * 4294967296 + last + delta) * 1e-6
        self._events.append({"t_s": t_s, "incoming_velocity_m_s": ev["incoming_velocity_m_s"], "grip_N": ev["grip_N"],
                             "max_penetration_m": ev["max_penetration_m"], "peak_accel_m_s2": ev["peak_accel_m_s2"],
                             "transient": self._transient_name, "clipped": ev["clipped"]})

    def pop_events(self) -> list[dict]:
        """Contact events reported by the firmware since the last call (keys as renderer.ContactEvent)."""
        out = self._events
        self._events = []
        return out

    def stop_rendering(self) -> None:
        """Stop on-board rendering (the firmware zeroes its output and reports an unfinished contact)."""
        if not self._rendering:
            return
        self._rendering = False
        self._upload_q.clear()
        self._upload_key = None
        self._request(P.RENDER_STOP)
        self._request(P.SET_MODE, P.MODE_STRUCT.pack(P.MODE_STREAMING, 1))
        self._states.clear()
        self._have_state = False
        self._cmd_pending = False


def _number(mapping: dict, key: str, what: str) -> float:
    if key not in mapping:
        raise ValueError(f"{what} is missing key {key!r}")
    try:
        value = float(mapping[key])
    except (TypeError, ValueError):
        raise ValueError(f"{what}.{key} must be a number, got {mapping[key]!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{what}.{key} must be finite, got {value}")
    return value


def _limit(limits: dict, key: str) -> float:
    """A current limit (A) of ``configure_rendering``'s ``limits``: a finite number >= 0 (ValueError naming the key)."""
    value = _number(limits, key, "limits")
    if value < 0:
        raise ValueError(f"limits.{key} must be >= 0 A, got {value}")
    return value


def _check_options(options: dict, name: str) -> dict:
    valid = [p for p in inspect.signature(ProtocolDevice.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"{name}: unknown option(s) {', '.join(unknown)}; valid: baudrate, {', '.join(valid)}")
    return options


# Linux's Unix98 pseudo-terminal slaves (/dev/pts/N): character devices of majors 136-143
# (Documentation/admin-guide/devices.txt)
_PTY_SLAVE_MAJORS = range(136, 144)


def is_pseudo_terminal(path: str) -> bool:
    """Whether ``path`` (symbolic links followed) is a pseudo-terminal slave, as the simulators serve
    (``devices fw-sim``, ``devices emulate``); a board's USB serial port (ttyACM, ttyUSB) is not one.

    Parameters
    ----------
    path : str
        A device path.

    Returns
    -------
    bool
    """
    try:
        st = os.stat(os.path.realpath(path))
    except OSError:
        return False
    return stat.S_ISCHR(st.st_mode) and os.major(st.st_rdev) in _PTY_SLAVE_MAJORS


class SerialDevice(ProtocolDevice):
    """A device on a serial/CDC port (pyserial), e.g. ``SerialDevice("/dev/ttyACM0", mode="on-device")``."""

    def __init__(self, port: str, baudrate: int = 921600, **options) -> None:
        self.port = str(port)
        self.baudrate = int(baudrate)
        super().__init__(**_check_options(options, f"serial:{port}"))

    @property
    def name(self) -> str:
        """``serial:<port>``."""
        return f"serial:{self.port}"

    def _make_transport(self) -> Transport:
        return SerialTransport(self.port, self.baudrate)

    def _may_run_lockstep(self) -> bool:
        return is_pseudo_terminal(self.port)

    def link_bytes_per_s(self) -> float:
        """``baudrate / 10``: a UART sends 10 bits (start, 8 data, stop) per byte."""
        return self.baudrate / 10.0
