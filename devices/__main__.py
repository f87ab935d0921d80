"""``python -m devices <command>``: record taps, identify and validate a device, fit a model, emulate or simulate the firmware."""

from __future__ import annotations

from plumbing.dispatch import Command, run_as_script
from plumbing.dispatch import main as dispatch

#: the commands, listed without importing them; each names its parser module (``register(subparsers)``, light),
#: whose parser names the body that runs (plumbing.dispatch.Body)
COMMANDS = (
    Command("record", "devices.cli_record_parser", "tap a sample and record 100 ms of handle acceleration per tap (CSV)"),
    Command("identify", "devices.cli_identify_parser",
            "identify a device: comprehensive evaluation (LTI model set) or successive isolation (nonlinear physical model)"),
    Command("fit", "devices.cli_identify_parser", "fit a model to swept-sine recordings made anywhere"),
    Command("validate", "devices.cli_validate_parser", "validate an identified model against the device (ETFEs, held transients)"),
    Command("linearity", "devices.cli_linearity_parser",
            "linearity and time-invariance report: ETFEs at several amplitudes, grips, positions"),
    Command("calibrate", "devices.cli_calibrate_parser",
            "calibrate a real board: encoder zero, accelerometer and grip offsets"),
    Command("emulate", "devices.cli_hardware_parser",
            "firmware emulator on a pseudo-terminal (speaks docs/protocol.md, sim physics)"),
    Command("latency", "devices.cli_hardware_parser", "measure command->state round trip and achieved update rate of a device"),
    Command("firmware-report", "devices.cli_firmware_parser",
            "timing of the real AVR firmware on simavr (tick cycles, ISRs, RAM, encoder)"),
    Command("fw-sim", "devices.cli_firmware_parser", "run the real firmware on simavr behind a pty (connect with serial:<pty>)"),
    Command("list", "devices.cli_lab_parser",
            "list the haptic devices this machine can see (serial, HID, FTDI, vendor libraries)"),
    Command("probe", "devices.cli_lab_parser",
            "a short, safe check of one device: workspace, sensors, and a small force pulse after a prompt"),
)


def main(argv=None) -> int:
    """Run ``python -m devices`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m devices", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m devices`` and of the ``hfam-devices`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
