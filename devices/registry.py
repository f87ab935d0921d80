"""Device strings: the one way every command selects a device.

``sim``                 simulated device, Table 3.1 parameters (nonlinear model: the joystick)
``sim:joystick``        the same, by name
``sim:onedof``          the section 4.4.3 one-dof testbed: Table 3.1 with a linear linkage (chapter 4's device)
``sim:lti``             simulated linear "Phantom-like" device
``sim:<params file>``   simulated device from a TOML/JSON parameter file
``serial:<port>``       hardware over a serial/CDC port (e.g. serial:/dev/ttyACM0)
``hid:<vid>:<pid>``     hardware over USB HID (hex ids, e.g. hid:16c0:0486)
``fw-sim``              the real AVR firmware on simavr behind a pty (devices/firmware/fw_sim.py)

Hardware strings take driver options after ``?`` (``&``-separated ``key=value``,
numbers converted), e.g. ``serial:/dev/pts/3?mode=on-device&timeout_s=0.05``.
"""

from __future__ import annotations

from .base import Device

DEVICE_KINDS = ("sim", "sim:joystick", "sim:onedof", "sim:lti", "sim:<params file>", "serial:<port>", "hid:<vid>:<pid>", "fw-sim")


def _split(spec: str) -> tuple[str, str, dict]:
    """``kind, rest, options`` of a device string; ValueError listing the valid forms if malformed."""
    if not isinstance(spec, str):
        raise ValueError(f"device string must be text, got {spec!r}; valid forms: {', '.join(DEVICE_KINDS)}")
    kind, _, rest = spec.partition(":")
    options: dict = {}
    if spec == "fw-sim" or spec.startswith("fw-sim?"):
        return "fw-sim", "", _parse_options(spec, spec.partition("?")[2])
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
    return _split(spec)[0]


def make_device(spec: str, **options) -> Device:
    """Create (not open) the device named by ``spec``; see the module doc.

    Raises
    ------
    ValueError
        For an unknown or malformed device string, listing the valid forms.
    """
    kind, rest, spec_options = _split(spec)
    options = {**spec_options, **options}
    if kind == "sim":
        from .sim import SimDevice  # deferred: with numpy, 0.12 s CPU that every devices --help would pay

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
