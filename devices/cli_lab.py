"""Bodies of ``python -m devices list`` and ``python -m devices probe`` (parsers in :mod:`devices.cli_lab_parser`)."""

from __future__ import annotations

import importlib.util
import math
import sys
import time

import hid
import serial.tools.list_ports
import usb.core
from pyftdi.usbtools import UsbTools, UsbToolsError

from plumbing.errors import UserError

from .base import DeviceError
from .hardware.falcon import protocol as FP
from .hardware.falcon.driver import default_firmware_hint
from .hardware.forcedimension.driver import load_bindings
from .hardware.openhaptics import hdapi
from .hardware.woodenhaptics import protocol as WP
from .lab_devices import make_lab_device
from .registry import LAB_KINDS, _split

PROBE_SAMPLES = 500
PULSE_S = 0.1


def _serial_lines() -> list[str]:
    out = []
    for p in sorted(serial.tools.list_ports.comports(), key=lambda p: p.device):
        ids = f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else "no USB ids"
        what = p.description if p.description and p.description != "n/a" else ""
        out.append(f"  {p.device}  ({ids}{', ' + what if what else ''})  ->  inverse3:{p.device}  or  serial:{p.device}")
    return out


def _hid_lines() -> list[str]:
    out = []
    for d in sorted(hid.enumerate(), key=lambda d: (d["vendor_id"], d["product_id"])):
        vp = f"{d['vendor_id']:04x}:{d['product_id']:04x}"
        name = (d.get("product_string") or "").strip()
        if (d["vendor_id"], d["product_id"]) == (WP.VID, WP.PID):
            hint = "woodenhaptics (mbed USBHID ids)"
        else:
            hint = f"hid:{vp}"
        out.append(f"  {vp}  {name or 'HID device'}  ->  {hint}")
    return out


def _falcon_lines() -> tuple[list[str], str]:
    try:
        found = UsbTools.find_all([(FP.FTDI_VID, FP.FALCON_PID)], nocache=True)
    except (ValueError, usb.core.NoBackendError, UsbToolsError, usb.core.USBError) as exc:
        return [], f"USB: not available ({exc}; pyusb needs libusb-1.0: apt-get install libusb-1.0-0)"
    devices = sorted(found, key=lambda d: (d[0].bus or 0, d[0].address or 0))
    lines = [f"  bus {d[0].bus} address {d[0].address} serial {d[0].sn or '?'}  ->  falcon:{k}"
             for k, d in enumerate(devices)]
    return lines, ""


def _dhd_line() -> str:
    if importlib.util.find_spec("forcedimension_core") is None:
        return "  missing: forcedimension-core is not installed (pip install 'hfam-haptics[forcedimension]')"
    try:
        mod, _ = load_bindings()
    except DeviceError as exc:
        return f"  missing: {str(exc).removeprefix('dhd: ')}"
    try:
        n = mod.getDeviceCount()
        v = mod.getSDKVersion()
    except Exception as exc:  # a broken SDK install: say it, do not fail the listing
        return f"  the SDK loads but does not answer ({exc})"
    if not isinstance(n, int):
        return "  the SDK is forcedimension-core's mock (a test mode), not a device"
    return f"  SDK {'.'.join(str(x) for x in v)}: {n} device(s)" + (f"  ->  dhd:0 .. dhd:{n - 1}" if n > 0 else "")


def _touch_line() -> str:
    try:
        hd = hdapi.load()
    except hdapi.HDLibraryError as exc:
        return f"  missing: {exc}"
    return f"  OpenHaptics {hd.version} at {hd.path}  ->  'touch:Default Device' (or the name set in Touch Setup)"


def run_list(args) -> int:
    """``devices list``: what this machine can see, with the device strings."""
    sections = [("Serial ports (Haply Inverse3, the hfam board)", _serial_lines(), "no serial ports")]
    sections.append(("USB HID devices (WoodenHaptics, the hfam board over HID)", _hid_lines(), "no HID devices"))
    falcons, why = _falcon_lines()
    sections.append((f"Novint Falcons (USB 0403:cb48; {default_firmware_hint()})", falcons,
                     why or "no Falcon plugged in (or no permission: docs/bringup.md)"))
    for title, lines, none in sections:
        print(title + ":")
        print("\n".join(lines) if lines else f"  {none}")
    print("Force Dimension (dhd):")
    print(_dhd_line())
    print("3D Systems Touch (OpenHaptics):")
    print(_touch_line())
    print("Emulators (no hardware): inverse3:emulator, falcon:emulator, woodenhaptics:emulator, dhd:emulator, "
          "sim, fw-sim")
    return 0


def run_probe(args) -> int:
    """``devices probe DEVICE``: open, report specs, read 0.5 s, an optional small pulse; always zero on exit."""
    spec = args.device
    kind, rest, options = _split(spec)
    if kind not in LAB_KINDS:
        raise UserError(f"probe checks the 3-DOF devices ({', '.join(k + ':' for k in LAB_KINDS)}); for the hfam "
                        f"board use 'python -m devices latency --device {spec}'")
    options = dict(options)
    options["axes"] = 3
    dev = make_lab_device(kind, rest, options, spec)
    try:
        dev.open()
    except DeviceError:
        raise
    try:
        return _probe(dev, args)
    finally:
        dev.close()


def _probe(dev, args) -> int:
    spec = dev.info.specs()
    print(f"{dev.name}: {dev.info.name}; servo {spec.servo_rate_hz:g} Hz; force {spec.max_force_N:g} N continuous, "
          f"{spec.max_peak_force_N:g} N peak; stiffness up to {spec.max_stiffness_N_m:g} N/m; workspace "
          f"{_box(spec.workspace_min_m, spec.workspace_max_m)}; {spec.buttons} button(s)")
    xs = []
    t0 = time.monotonic()
    for _ in range(PROBE_SAMPLES):
        st = dev.read()
        if st.status & 32:
            raise DeviceError(st.extra.get("error", f"{dev.name}: disconnected"))
        xs.append((st.x_m, st.y_m, st.position_m))
        dev.command_force(0.0, 0.0, 0.0)
    elapsed = time.monotonic() - t0
    bad = [p for p in xs if not all(math.isfinite(v) for v in p)]
    outside = [p for p in xs if not spec.contains(p)]
    spans = [max(p[i] for p in xs) - min(p[i] for p in xs) for i in range(3)]
    mean = [sum(p[i] for p in xs) / len(xs) for i in range(3)]
    link = dev.link_stats()
    print(f"  {len(xs)} samples in {elapsed:.2f} s ({len(xs) / elapsed:.0f} Hz); position mean "
          f"({mean[0] * 1e3:+.1f}, {mean[1] * 1e3:+.1f}, {mean[2] * 1e3:+.1f}) mm, moved "
          f"({spans[0] * 1e3:.2f}, {spans[1] * 1e3:.2f}, {spans[2] * 1e3:.2f}) mm; round trip median "
          f"{(link['rtt_median_s'] or 0) * 1e3:.2f} ms, {link['losses']} lost")
    problems = []
    if bad:
        problems.append(f"{len(bad)} samples not finite (sensor fault)")
    if outside:
        problems.append(f"{len(outside)} samples outside the workspace box (homing or calibration)")
    if problems:
        print("  sensors: " + "; ".join(problems))
        return 1
    print("  sensors: ok (finite, inside the workspace)")
    if args.no_pulse:
        return 0
    if not args.yes:
        if not sys.stdin.isatty():
            print(f"  pulse skipped: no terminal to ask (run with --yes to push {args.pulse_N:g} N up for 0.1 s)")
            return 0
        answer = input(f"  hold the handle lightly; push {args.pulse_N:g} N up for 0.1 s? [y/N] ").strip().lower()
        if answer not in ("y", "yes"):
            print("  pulse skipped")
            return 0
    z0 = dev.read().position_m
    t_end = time.monotonic() + PULSE_S
    zmax = z0
    while time.monotonic() < t_end:
        st = dev.read()
        zmax = max(zmax, st.position_m)
        dev.command_force(0.0, 0.0, args.pulse_N)
    dev.zero()
    print(f"  pulse: {args.pulse_N:g} N up for {PULSE_S:g} s moved the handle up {(zmax - z0) * 1e3:.2f} mm; "
          "output zeroed")
    return 0


def _box(lo, hi) -> str:
    return " x ".join(f"{(h - l) * 1e3:.0f}" for l, h in zip(lo, hi)) + " mm"
