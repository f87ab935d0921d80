"""Device strings: the one way every command selects a device.

``sim``                 simulated device, Table 3.1 parameters (nonlinear model: the joystick)
``sim:joystick``        the same, by name
``sim:onedof``          the section 4.4.3 one-dof testbed: Table 3.1 with a linear linkage (chapter 4's device)
``sim:lti``             simulated linear "Phantom-like" device
``sim:<params file>``   simulated device from a TOML/JSON parameter file
``sim:3d``              simulated 3-DOF device (the 1-DOF sim along the tap, docs/sim.md); ``sim:3d-delta``
                        (Falcon-like linkage), ``sim:3d-serial`` (Phantom-like)
``serial:<port>``       hardware over a serial/CDC port (e.g. serial:/dev/ttyACM0)
``hid:<vid>:<pid>``     hardware over USB HID (hex ids, e.g. hid:16c0:0486)
``fw-sim``              the real AVR firmware on simavr behind a pty (devices/firmware/fw_sim.py)
``inverse3:<port>``     Haply Inverse3 (serial), e.g. inverse3:/dev/ttyACM0
``falcon:<index>``      Novint Falcon (USB/FTDI), e.g. falcon:0?firmware=nvent_firmware.bin
``woodenhaptics``       WoodenHaptics (USB HID 1234:0006; woodenhaptics:<vid>:<pid> for other ids)
``dhd:<index>``         Force Dimension through its SDK (optional extra ``forcedimension``), e.g. dhd:0
``touch:<name>``        3D Systems Touch through OpenHaptics, e.g. touch:Default Device

The 3-DOF devices also take the address ``emulator`` (``falcon:emulator``: the built-in emulator of the
device's protocol) and open as their 1-DOF vertical view unless ``?axes=3`` (devices/lab_devices.py); a 3-D
run (``renderer run`` on a 3-D scene) opens all three axes unless the string says ``axes=1``.

Hardware strings take driver options after ``?`` (``&``-separated ``key=value``,
numbers converted), e.g. ``serial:/dev/pts/3?mode=on-device&timeout_s=0.05``.
"""

from __future__ import annotations

from .base import Device

DEVICE_KINDS = ("sim", "sim:joystick", "sim:onedof", "sim:lti", "sim:<params file>", "sim:3d", "sim:3d-delta",
                "sim:3d-serial", "serial:<port>", "hid:<vid>:<pid>", "fw-sim", "inverse3:<port>", "falcon:<index>",
                "woodenhaptics", "dhd:<index>", "touch:<name>")
#: the 3-DOF research devices (devices/lab_devices.py)
LAB_KINDS = ("inverse3", "falcon", "woodenhaptics", "dhd", "touch")


def all_axes_options(spec: str) -> dict:
    """What a 3-D run adds to ``make_device(spec, ...)`` to open every axis of the device.

    ``{"axes": 3}`` for a 3-DOF research device (inverse3, falcon, woodenhaptics, dhd, touch) whose string does not
    choose its axes itself; nothing for the others (``sim:3d`` is three-axis already, a 1-DOF device has one).
    ValueError for a malformed string, as :func:`make_device`.
    """
    kind, _, options = _split(spec)
    return {"axes": 3} if kind in LAB_KINDS and "axes" not in options else {}


def _split(spec: str) -> tuple[str, str, dict]:
    """``kind, rest, options`` of a device string; ValueError listing the valid forms if malformed."""
    if not isinstance(spec, str):
        raise ValueError(f"device string must be text, got {spec!r}; valid forms: {', '.join(DEVICE_KINDS)}")
    kind, _, rest = spec.partition(":")
    options: dict = {}
    if spec == "fw-sim" or spec.startswith("fw-sim?"):
        return "fw-sim", "", _parse_options(spec, spec.partition("?")[2])
    if kind in LAB_KINDS or spec.split("?", 1)[0] == "woodenhaptics":
        if kind not in LAB_KINDS:
            kind = "woodenhaptics"
        base, _, query = spec.partition("?")
        rest = base.partition(":")[2]
        return kind, rest, _parse_options(spec, query) if query else {}
    if kind in ("serial", "hid") and "?" in rest:
        rest, query = rest.split("?", 1)
        options = _parse_options(spec, query)
    if kind == "sim" or (kind == "serial" and rest):
        return kind, rest, options
    if kind == "hid" and rest.count(":") == 1:
        vid, pid = rest.split(":")
        try:
            int(vid, 16), int(pid, 16)
        except ValueError:
            raise ValueError(f"device string {spec!r}: vendor and product ids must be hex numbers "
                             f"(e.g. hid:16c0:0486)") from None
        return kind, rest, options
    raise ValueError(f"unknown device string {spec!r}; valid forms: {', '.join(DEVICE_KINDS)}")


def check_device_spec(spec: str) -> str:
    """Validate the form of a device string without touching any device; return its kind.

    Commands call this before any other set-up, so a typo is reported as such.
    """
    kind, rest, _ = _split(spec)
    if kind in LAB_KINDS:
        _check_lab_address(kind, rest, spec)
    return kind


def _check_lab_address(kind: str, rest: str, spec: str) -> None:
    """The address checks of devices/lab_devices.py, repeated here without importing the drivers."""
    if kind in ("falcon", "dhd") and rest != "emulator" and not rest.isdigit():
        raise ValueError(f"device string {spec!r}: {kind}:<index> takes a device index (e.g. {kind}:0) or 'emulator'")
    if kind in ("inverse3", "touch") and not rest:
        raise ValueError(f"device string {spec!r}: give the {'port' if kind == 'inverse3' else 'device name'} "
                         f"after '{kind}:'")


def make_device(spec: str, **options) -> Device:
    """Create (not open) the device named by ``spec``; see the module doc.

    Raises
    ------
    ValueError
        For an unknown or malformed device string, listing the valid forms.
    """
    kind, rest, spec_options = _split(spec)
    options = {**spec_options, **options}
    if kind in LAB_KINDS:
        from .lab_devices import make_lab_device  # deferred: the 3-DOF drivers, pyftdi/pyusb and emulators, 0.13 s CPU a sim run does not need

        return make_lab_device(kind, rest, options, spec)
    if kind == "sim":
        from .sim import Sim3Device, SimDevice  # deferred: with numpy, 0.12 s CPU that every devices --help would pay

        if rest in ("3d", "3d-delta", "3d-serial"):
            return Sim3Device(linkage=rest[3:] or None, **options)
        return SimDevice.from_spec(rest or None, **options)
    if kind == "fw-sim":
        from .firmware.fw_sim import FwSimDevice  # deferred: 19 ms CPU (simavr harness) a sim run does not need

        return FwSimDevice(**options)
    if kind == "serial":
        from .hardware.serial_device import SerialDevice  # deferred: 16 ms CPU (pyserial) a sim run does not need

        return SerialDevice(rest, **options)
    from .hardware.hid_device import HidDevice  # deferred: 11 ms CPU a sim run does not need; hidapi is optional

    vid, pid = rest.split(":")
    return HidDevice(int(vid, 16), int(pid, 16), **options)


def _parse_options(spec: str, query: str) -> dict:
    """``mode=on-device&timeout_s=0.05`` -> {"mode": "on-device", "timeout_s": 0.05}."""
    out: dict = {}
    for item in query.split("&"):
        if not item:
            continue
        key, eq, value = item.partition("=")
        if not eq or not key.isidentifier():
            raise ValueError(f"device string {spec!r}: option {item!r} is not key=value")
        for conv in (int, float):
            try:
                value = conv(value)
                break
            except ValueError:
                pass
        out[key] = value
    return out


def open_device(spec: str, **options) -> Device:
    """Create and open the device named by ``spec`` (use as a context manager)."""
    return make_device(spec, **options).open()
