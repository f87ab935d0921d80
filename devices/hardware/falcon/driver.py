"""The Novint Falcon adapter: libnifalcon's protocol and kinematics over pyftdi (no vendor library needed).

Device string ``falcon:<index>`` (``falcon:0`` the first Falcon found) with options, e.g.
``falcon:0?firmware=/path/nvent_firmware.bin``. The firmware file is the user's own (the Novint driver's
or libnifalcon's nVent firmware; ``$HFAM_FALCON_FIRMWARE`` names it when the option is absent): opening
checks whether the Falcon already runs a firmware (one packet answered) and uploads the file if not
(:mod:`devices.hardware.falcon.link`), then homes it (the Falcon's encoders are relative: the firmware
homes each leg as the user moves the grip through its range; the green LED lights when done).

Each servo tick is one 16-byte command packet answered by one status packet. Forces go to motor
commands through libnifalcon's kinematics (:func:`devices.hardware.falcon.kinematics.motor_commands`),
clamped to +/-4096 per motor with the three scaled together (direction kept; ``Status.CLIPPING``);
encoders come back through its forward kinematics. The Falcon's own firmware publishes no command
timeout, so the host watchdog of :mod:`devices.hardware.threedof` keeps it safe when the host stops.

Frame: libnifalcon's x (right), y (up), z (along the grip, towards the user; centre at 0.11 m) become the
device frame's y, z and x: ``x = z_f - 0.11, y = x_f, z = y_f`` (a cyclic permutation: right-handed).
"""

from __future__ import annotations

import os
import time

from ...base import DeviceError, Status
from ..threedof import ThreeAxisDevice, three_axis_info
from . import kinematics as K
from . import protocol as P
from .link import FalconError, FalconLink, read_firmware_file

FIRMWARE_ENV = "HFAM_FALCON_FIRMWARE"
MAX_FORCE_N = 4.0
MAX_PEAK_FORCE_N = 8.9       # Novint quotes about 2 lb
MAX_STIFFNESS_N_M = 1500.0
SERVO_RATE_HZ = 1000.0
HALF_BOX_M = (0.05, 0.05, 0.05)   # the Falcon's 4 in (10 cm) cube
POSITION_RESOLUTION_M = 4e-5      # one encoder count moves the grip ~40 um near the centre


class FalconDevice(ThreeAxisDevice):
    """The ``index``-th Novint Falcon (see module doc). ``usb_device`` is the test seam (a pyusb device)."""

    spec_prefix = "falcon"

    def __init__(self, index: int = 0, firmware=None, usb_device=None, homing_timeout_s: float = 30.0,
                 **options) -> None:
        super().__init__(**options)
        if not (isinstance(index, int) and index >= 0):
            raise ValueError(f"falcon:<index>: index must be a whole number >= 0, got {index!r}")
        self.index = index
        self.firmware_path = firmware if firmware is not None else os.environ.get(FIRMWARE_ENV)
        self._usb_device = usb_device
        self.homing_timeout_s = float(homing_timeout_s)
        self._link: FalconLink | None = None
        self._p = list(K.WORKSPACE_CENTRE)   # libnifalcon frame, last position (the FK's next guess)
        self.firmware_uploaded = False
        self.info = three_axis_info("Novint Falcon", SERVO_RATE_HZ, tuple(-h for h in HALF_BOX_M), HALF_BOX_M,
                                    MAX_FORCE_N, MAX_PEAK_FORCE_N, MAX_STIFFNESS_N_M, POSITION_RESOLUTION_M,
                                    linear=False, buttons=4)

    @property
    def name(self) -> str:
        """``falcon:<index>``."""
        return f"falcon:{self.index}"

    # -- link ---------------------------------------------------------------------------------------
    def _open_link(self) -> None:
        try:
            dev = self._usb_device if self._usb_device is not None else FalconLink.find(self.index)
            self._link = FalconLink(dev, self.name)
            link = self._link
            link.normal_mode()
            running = any(link.exchange(P.encode_command((0, 0, 0)), 0.02) is not None for _ in range(3))
            if not running:
                if not self.firmware_path:
                    raise FalconError(f"{self.name}: the Falcon runs no firmware and none was given: give its "
                                      f"firmware file ({self.name}?firmware=/path/to/nvent_firmware.bin or "
                                      f"${FIRMWARE_ENV}); the Falcon loads it from the host at every power-up")
                image = (bytes(self.firmware_path) if isinstance(self.firmware_path, (bytes, bytearray))
                         else read_firmware_file(self.firmware_path, self.name))
                link.upload_firmware(image)
                self.firmware_uploaded = True
                if not any(link.exchange(P.encode_command((0, 0, 0)), 0.05) is not None for _ in range(5)):
                    raise FalconError(f"{self.name}: the Falcon took {self.firmware_path} but does not run it (no "
                                      "answer in normal mode): is it the Falcon's firmware (nVent)? Power-cycle "
                                      "the Falcon before trying another file")
            self._home()
        except FalconError as exc:
            self._close_link()
            raise DeviceError(str(exc)) from None

    def _home(self) -> None:
        link = self._link
        deadline = time.monotonic() + self.homing_timeout_s
        while True:
            pkt = link.exchange(P.encode_command((0, 0, 0), P.LED_BLUE, homing=True), 0.02)
            if pkt is not None:
                _, homed, _ = P.decode_status(pkt)
                if homed == P.HOMED_ALL:
                    return
            if time.monotonic() > deadline:
                raise FalconError(f"{self.name}: not homed within {self.homing_timeout_s:g} s: move the grip "
                                  "slowly through its whole range (in, out, up, down, left, right) while opening")

    def _close_link(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            try:
                link.exchange(P.encode_command((0, 0, 0)), 0.01)
            except Exception:
                pass
            link.close()

    def _link_usable(self) -> bool:
        return self._link is not None

    def _transact(self, fx_N: float, fy_N: float, fz_N: float) -> bool:
        link = self._link
        if link is None:
            raise OSError("link closed")
        p = self._p
        force_f = (fy_N, fz_N, fx_N)   # device frame -> libnifalcon's (x_f = y, y_f = z, z_f = x)
        try:
            cmds = K.motor_commands(p, force_f)
        except K.OutOfWorkspace:
            cmds = (0, 0, 0)
        largest = max(abs(c) for c in cmds)
        st = self._state
        if largest > K.MAX_COMMAND:
            s = K.MAX_COMMAND / largest
            cmds = tuple(int(c * s) for c in cmds)
            self.stats["clipped"] += 1
            st.status |= Status.CLIPPING
        else:
            st.status &= ~Status.CLIPPING
        try:
            pkt = link.exchange(P.encode_command(cmds, P.LED_GREEN), self.loss_timeout_s)
        except FalconError as exc:
            raise OSError(str(exc).removeprefix(f"{self.name}: ")) from None
        self.stats["garbage_bytes"] = link.parser.garbage_bytes
        if pkt is None:
            return False
        enc, _, buttons = P.decode_status(pkt)
        theta = [K.theta_from_encoder(e) * K.DEG_TO_RAD for e in enc]
        try:
            q = K.fk(theta, guess=p)
        except K.OutOfWorkspace:
            st.extra["kinematics_misses"] = st.extra.get("kinematics_misses", 0) + 1
            return True   # the reply came: the position is held at the last solution
        p[0], p[1], p[2] = q
        st.x_m, st.y_m, st.position_m = q[2] - K.WORKSPACE_CENTRE[2], q[0], q[1]
        st.buttons = buttons
        st.extra["encoders"] = enc
        st.extra["motor_commands"] = cmds
        return True

    def jacobian(self):
        """dp/dtheta at the last sample, libnifalcon's frame rows reordered to the device frame."""
        try:
            j = K.jacobian(K.ik(self._p))
        except K.OutOfWorkspace:
            return None
        return (j[2], j[0], j[1])


def default_firmware_hint() -> str:
    """Where the firmware comes from (for ``devices list``)."""
    path = os.environ.get(FIRMWARE_ENV)
    return f"firmware ${FIRMWARE_ENV}={path}" if path else f"no firmware file set (${FIRMWARE_ENV} or ?firmware=)"


