"""The emulator as a command and a child process; fault-spec parsing; the latency command."""

import signal
from pathlib import Path

import numpy as np
import pytest

from devices import make_device
from devices.__main__ import main as devices_main
from devices.firmware.emulator import FaultSpec, start_emulator
from devices.hardware.serial_device import SerialDevice
from renderer import RendererConfig, ServoLoop

ROOT = Path(__file__).resolve().parents[3]


def test_fault_spec_parsing_and_errors():
    f = FaultSpec.parse("drop=0.01, corrupt=0.2,delay=0.1,delay_s=0.003,disconnect_after_s=2,silent=1")
    assert f.drop == 0.01 and f.corrupt == 0.2 and f.delay_s == 0.003 and f.disconnect_after_s == 2 and f.silent
    assert FaultSpec.parse(f.to_text()) == f
    assert FaultSpec.parse("") == FaultSpec()
    with pytest.raises(ValueError, match="unknown fault 'dorp'"):
        FaultSpec.parse("dorp=0.1")
    with pytest.raises(ValueError, match="drop=2 is a probability"):
        FaultSpec.parse("drop=2")
    with pytest.raises(ValueError, match="'x' is not a number"):
        FaultSpec.parse("corrupt=x")


def test_child_process_emulator_starts_and_stops():
    # the child is `python -m devices emulate --pty ...`: start_emulator reads the port it prints
    port, handle = start_emulator(process=True, faults="drop=0.001")
    try:
        assert handle.alive and port.startswith("/dev/pts/")
        with SerialDevice(port) as dev:
            assert dev.info.name == "hfam-emulator(sim-joystick)"
    finally:
        handle.stop()
    assert not handle.alive and handle.process.returncode == 0


def test_latency_command(capsys):
    port, handle = start_emulator()
    try:
        assert handle.alive
        assert devices_main(["latency", "--device", f"serial:{port}", "--n", "300", "--warmup", "20"]) == 0
    finally:
        handle.stop()
    assert not handle.alive
    out = capsys.readouterr().out
    assert "300 command->state round trips" in out and "achieved update rate" in out and "link: " in out


def test_emulate_rejects_bad_fault_spec(capsys):
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    assert devices_main(["emulate", "--fault", "drop=7"]) == 2
    assert "drop=7 is a probability" in capsys.readouterr().err
    # its SIGTERM/SIGINT handlers are gone again: a pool forked later by this process (the demo's tap
    # workers) must still die on SIGTERM (a leaked handler once hung Pool.terminate for 600 s)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_the_emulator_reports_native_usb_and_gets_telemetry_every_tick():
    """The emulator stands for a native-USB board and says so in INFO (capability 32): the serial driver's
    default then asks for a STATE frame every 10 kHz tick, not the every-5th-tick the pty's nominal
    921,600 baud would call for (the AVR board, a UART, gets 2: test_telemetry_decimation)."""
    port, handle = start_emulator("on-device", pace="host")
    try:
        with make_device(f"serial:{port}?mode=on-device") as dev:
            assert "native_usb" in dev.info.capabilities and dev.telemetry_decimation_option is None
            # an emulator, not hardware: the hardware path (not simulated), recorded as emulated
            assert dev.info.emulated and not dev.info.simulated and dev.info.name.startswith("hfam-emulator(")
            res = ServoLoop(dev, RendererConfig()).run(duration_s=0.05)
            assert dev.telemetry_decimation == 1
        assert res.timing["log_rate_hz"] == res.timing["rate_hz"] == 10000.0
        assert np.all(np.round(np.diff(res.log["t_s"]) * 1e6) == 100.0)
    finally:
        handle.stop()


def test_a_busy_emulator_skips_the_ticks_it_missed_and_never_runs_ahead_of_the_clock():
    # the emulator is descheduled for 300 ms while rendering on board: it runs at most 50 ms of the
    # missed ticks (as a firmware's overrun counter would) and then keeps to the wall clock; it must
    # never run more ticks than the time elapsed (a sign slip once ran 2.3 s of device time in 1.7 s)
    from devices.firmware.emulator import Emulator
    emu = Emulator(make_device("sim"), mode="on-device", pace="realtime")   # no pty: frames go nowhere
    emu._start_render()
    fs, t0 = emu.fs, emu.t_render0
    cap = int(0.05 * fs)

    def run_until_idle(now):
        before = emu.ticks
        for _ in range(1000):   # bounded: an emulator that keeps finding ticks due fails, not hangs
            if emu._run_due_ticks(now) != 0.0:
                break
        return emu.ticks - before

    assert run_until_idle(t0 + 0.3) == cap
    # 10 ms later: 10 ms of ticks are due, not the skipped backlog
    assert abs(run_until_idle(t0 + 0.31) - int(0.01 * fs)) <= 1
    assert emu.ticks <= 0.31 * fs
