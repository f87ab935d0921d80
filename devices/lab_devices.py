"""Device strings of the common 3-DOF research devices (docs/bringup.md): their drivers and built-in emulators.

``inverse3:<port>``         Haply Inverse3 on a serial port (e.g. inverse3:/dev/ttyACM0)
``falcon:<index>``          Novint Falcon over USB/FTDI (falcon:0), ``?firmware=<file>``
``woodenhaptics``           WoodenHaptics on USB HID (1234:0006; ``woodenhaptics:<vid>:<pid>`` for others)
``dhd:<index>``             Force Dimension through its SDK (dhd:0; optional extra ``forcedimension``)
``touch:<name>``            3D Systems Touch through OpenHaptics (touch:Default Device)

The address ``emulator`` (``inverse3:emulator``, ``falcon:emulator``, ``woodenhaptics:emulator``,
``dhd:emulator``) opens the built-in emulator of that device's protocol instead of hardware, to rehearse
without one: the Inverse3's over a real pseudo-terminal, the Falcon's as an FT232R under pyftdi, the
WoodenHaptics' as a hidapi handle, Force Dimension's on forcedimension-core's mock mode. Options
``fault_<name>=<value>`` inject the emulator's faults (e.g. ``falcon:emulator?fault_unplug_after=1500``).

Every 1-DOF command (``renderer run``, ``study run``) gets the device's **vertical view**
(:class:`devices.hardware.threedof.VerticalAxisDevice`: z is the handle, x and y held); ``?axes=3`` gives
the 3-axis device itself (for 3-D code). Options: ``loss_timeout_s``, ``max_consecutive_losses``,
``watchdog_ms`` (every device), ``hold_stiffness_N_m``, ``hold_damping_N_s_m``, ``hold_force_fraction``,
``grip_N`` (the vertical view), and per device: ``baudrate`` (inverse3), ``firmware``, ``homing_timeout_s``
(falcon), ``gravity`` (woodenhaptics: 0 turns CWoodenDevice's gravity compensation off).
"""

from __future__ import annotations

from .base import Device
from .firmware.dhd_emulator import DhdEmulator
from .firmware.falcon_emulator import FalconModel, VirtualFalconBackend, falcon_usb_device, stand_in_firmware
from .firmware.inverse3_emulator import start_inverse3_emulator
from .firmware.woodenhaptics_emulator import WoodenHapticsHandle
from .hardware.falcon.driver import FalconDevice
from .hardware.forcedimension.driver import ForceDimensionDevice
from .hardware.haply.driver import Inverse3Device
from .hardware.openhaptics.driver import TouchDevice
from .hardware.threedof import ThreeAxisDevice, VerticalAxisDevice
from .hardware.woodenhaptics import protocol as W
from .hardware.woodenhaptics.driver import WoodenHapticsDevice

LAB_KINDS = ("inverse3", "falcon", "woodenhaptics", "dhd", "touch")
LAB_FORMS = ("inverse3:<port>", "falcon:<index>", "woodenhaptics", "dhd:<index>", "touch:<name>")
EMULATOR = "emulator"
_BASE_OPTIONS = ("loss_timeout_s", "max_consecutive_losses", "watchdog_ms")
_VIEW_OPTIONS = ("hold_stiffness_N_m", "hold_damping_N_s_m", "hold_force_fraction", "grip_N")
_DRIVER_OPTIONS = {"inverse3": ("baudrate",), "falcon": ("firmware", "homing_timeout_s"),
                   "woodenhaptics": ("gravity",), "dhd": (), "touch": ()}
_FAULTS = {"inverse3": ("garbage_every", "silent", "wrong_device", "disconnect_after", "stall_at", "stall_s",
                        "freeze_at"),
           "falcon": ("garbage_every", "stall_at", "stall_s", "unplug_after", "watchdog_ms", "corrupt_echo_at"),
           "woodenhaptics": ("bad_size_every", "freeze_at", "stall_at", "stall_s", "unplug_after"),
           "dhd": ("open_fails", "unplug_after"), "touch": ()}


def check_address(kind: str, rest: str, spec: str) -> None:
    """ValueError naming the valid form when a lab device string's address is malformed."""
    if kind in ("falcon", "dhd"):
        if rest != EMULATOR and not rest.isdigit():
            raise ValueError(f"device string {spec!r}: {kind}:<index> takes a device index (e.g. {kind}:0) or "
                             f"'{EMULATOR}'")
    elif kind == "inverse3":
        if not rest:
            raise ValueError(f"device string {spec!r}: give the Inverse3's port, e.g. inverse3:/dev/ttyACM0")
    elif kind == "woodenhaptics":
        if rest and rest != EMULATOR:
            parts = rest.split(":")
            try:
                ok = len(parts) == 2 and all(0 <= int(p, 16) <= 0xFFFF for p in parts)
            except ValueError:
                ok = False
            if not ok:
                raise ValueError(f"device string {spec!r}: woodenhaptics or woodenhaptics:<vid>:<pid> (hex ids)")
    elif kind == "touch":
        if not rest:
            raise ValueError(f"device string {spec!r}: give the device's name, e.g. 'touch:Default Device'")
        if rest == EMULATOR:
            raise ValueError(f"device string {spec!r}: the Touch has no built-in emulator (its library is the "
                             "vendor's): point $HFAM_OPENHAPTICS_LIB at a test HD library instead")


def make_lab_device(kind: str, rest: str, options: dict, spec: str) -> Device:
    """The device of a lab device string (see module doc); ValueError for unknown or bad options."""
    check_address(kind, rest, spec)
    options = dict(options)
    axes = options.pop("axes", 1)
    if axes not in (1, 3):
        raise ValueError(f"device string {spec!r}: axes must be 1 (the vertical view) or 3, got {axes!r}")
    faults = {k[len("fault_"):]: options.pop(k) for k in list(options) if k.startswith("fault_")}
    view = {k: options.pop(k) for k in _VIEW_OPTIONS if k in options}
    valid = _BASE_OPTIONS + _DRIVER_OPTIONS[kind] + _VIEW_OPTIONS + ("axes",)
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"device string {spec!r}: unknown option(s) {', '.join(unknown)}; valid: {', '.join(valid)}"
                         + (", fault_<name> (emulator only)" if _FAULTS[kind] else ""))
    emulated = rest == EMULATOR
    if faults and not emulated:
        raise ValueError(f"device string {spec!r}: fault_ options are for the built-in emulator ({kind}:{EMULATOR})")
    bad = sorted(set(faults) - set(_FAULTS[kind]))
    if bad:
        raise ValueError(f"device string {spec!r}: unknown emulator fault(s) {', '.join(bad)}; valid: "
                         f"{', '.join('fault_' + f for f in _FAULTS[kind])}")
    dev = _make_driver(kind, rest, options, faults, emulated)
    # the emulators advance their handle one servo period per transaction (deterministic: their clock waits for the
    # host), so a state's time is its reply's count, not its wall-clock time (renderer.ring goes by it)
    dev.lockstep = emulated
    if axes == 3:
        if view:
            raise ValueError(f"device string {spec!r}: {', '.join(view)} belong to the vertical view (axes=1)")
        return dev
    return VerticalAxisDevice(dev, **view)


def _make_driver(kind: str, rest: str, options: dict, faults: dict, emulated: bool) -> ThreeAxisDevice:
    if kind == "inverse3":
        if not emulated:
            return Inverse3Device(rest, **options)
        emu = start_inverse3_emulator(faults={k: v for k, v in faults.items()})
        try:
            dev = Inverse3Device(emu.port, **options)
        except BaseException:
            emu.stop()
            raise
        dev.owned.append(emu)
        return dev
    if kind == "falcon":
        if not emulated:
            return FalconDevice(int(rest), **options)
        image = stand_in_firmware()
        model = FalconModel(image, **faults)
        backend = VirtualFalconBackend(model)
        options.setdefault("firmware", image)
        dev = FalconDevice(0, usb_device=falcon_usb_device(backend), **options)
        dev.owned.append(backend)
        return dev
    if kind == "woodenhaptics":
        if emulated:
            handle = WoodenHapticsHandle(**faults)
            dev = WoodenHapticsDevice(handle=handle, **options)
            dev.owned.append(handle)
            return dev
        if rest:
            vid, pid = (int(p, 16) for p in rest.split(":"))
            return WoodenHapticsDevice(vid, pid, **options)
        return WoodenHapticsDevice(W.VID, W.PID, **options)
    if kind == "dhd":
        if not emulated:
            return ForceDimensionDevice(int(rest), **options)
        emu = DhdEmulator(**faults)
        dev = ForceDimensionDevice(0, bindings=(emu.dhd, emu.expert), **options)
        dev.owned.append(emu)
        return dev
    return TouchDevice(rest, **options)


def option_names(kind: str) -> list[str]:
    """Every option a lab device string of ``kind`` takes (for help texts)."""
    return list(_BASE_OPTIONS + _DRIVER_OPTIONS[kind] + _VIEW_OPTIONS + ("axes",))

