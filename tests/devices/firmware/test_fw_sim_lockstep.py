"""fw-sim in lockstep (issue 39, item 3): the real AVR firmware on simavr, whose clock waits for the host.

simavr runs this firmware at 0.1-1x real time on a loaded 2-core machine, so a host on the wall clock
overran every tick and its watchdogs stopped the run. In lockstep the harness runs the MCU one host period
per host frame (docs/protocol.md "Lockstep"); INFO says so and the host paces on the device's clock. These
tests run with whatever load the machine has: nothing in them depends on how fast simavr or the host is.
"""

import dataclasses
import os
import signal
import time

import numpy as np
import pytest

from devices import Status
from devices.base import DeviceInfo
from devices.firmware import fw_sim
from devices.hardware import wire_protocol as P
from devices.base import DeviceError
from devices.hardware.serial_device import SerialDevice, is_pseudo_terminal
from devices.registry import make_device
from renderer.config import RendererConfig
from renderer.loop import ServoLoop

TAPS_M_S = (0.05, 0.1, 0.2)


def _wait_for(predicate, what, guard_s=600.0):
    """Poll ``predicate()`` until it returns a true value (the guard is a hang guard, not a budget)."""
    t0 = time.monotonic()
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() - t0 < guard_s, f"hang guard: {what}"
        time.sleep(0.02)


def test_info_flags_carry_lockstep_and_a_real_board_has_none():
    info = DeviceInfo("paddle", 500, 10.0, 0.07, 0.0187, 0.8, 2.0, 2.0, 4000.0, lockstep_ticks=4)
    wire = P.WireInfo(info, (1, 1), (1, 0, 0), "HK0001", 0.345, 512, 0.0098, 0, 100, 31, 0)
    payload = P.encode_info(wire)
    assert int.from_bytes(payload[85:87], "little") == 2 | 4 << 8
    back = P.decode_info(payload)
    assert back.info.lockstep_ticks == 4 and back.info.lockstep_rate_hz == 1000.0 and not back.info.simulated
    board = P.decode_info(P.encode_info(dataclasses.replace(wire, info=dataclasses.replace(info, lockstep_ticks=0))))
    assert board.info.lockstep_ticks == 0 and board.info.lockstep_rate_hz is None
    with pytest.raises(P.ProtocolError, match="0 servo ticks"):
        P.decode_info(payload[:85] + (2).to_bytes(2, "little") + payload[87:])
    with pytest.raises(ValueError, match="lockstep_ticks"):
        DeviceInfo("paddle", 500, 10.0, 0.07, 0.0187, 0.8, 2.0, 2.0, 4000.0, lockstep_ticks=300)
    # the firmware itself never claims lockstep: only the harness's lockstep pace marks INFO
    port, handle = fw_sim.start_fw_sim(pace="realtime", taps_m_s=())
    try:
        with SerialDevice(port, max_consecutive_losses=0) as dev:
            assert dev.info.lockstep_ticks == 0 and dev.timeout_s == 0.02
    finally:
        handle.stop()
    with pytest.raises(ValueError, match="lockstep_ticks"):
        make_device("fw-sim?lockstep_ticks=0")


def _streaming_run(duration_s):
    """``renderer``'s servo loop streaming to fw-sim (default pace: lockstep) for ``duration_s`` of device time,
    recording every state read and current commanded."""
    dev = make_device("fw-sim")
    states, commands = [], []
    with dev:
        read, command = dev.read, dev.command

        def rec_read():
            s = read()
            # the current the firmware reports it applied, beside the one this STATE answers (the last sent)
            states.append((s.t_s, s.extra["current_A"], s.status, dev._last_current))
            return s

        def rec_command(i):
            commands.append(i)
            command(i)

        dev.read, dev.command = rec_read, rec_command
        assert dev.info.lockstep_ticks == 4 and dev.info.servo_rate_hz == 4000.0
        with pytest.raises(ValueError, match="lockstep"):  # 4 kHz streaming does not exist on this link
            ServoLoop(dev, RendererConfig(rate_hz=4000.0)).prepare()
        loop = ServoLoop(dev, RendererConfig())
        res = loop.run(duration_s=duration_s)
        link = dev.link_stats()
        handle = dev.handle
    harness = handle.final_stats  # written by the harness as it stopped (close), not a snapshot of a running one
    assert harness["final"] == 1
    return res, np.array(states), np.array(commands), link, harness


def test_a_10_s_streaming_run_in_lockstep_never_trips_a_watchdog():
    """10 s of device time at the lockstep rate (1 kHz: 4 of the firmware's 4 kHz ticks per command), with the
    machine as loaded as it is: every tick exactly 1 ms of device time apart, 0 overruns, no host or firmware
    watchdog, events at the taps' speeds and within the run, and the firmware applied each command to the mA."""
    duration_s = 10.0
    res, states, cmds, link, harness = _streaming_run(duration_s)
    assert res.stop_reason == "duration", res.error
    tm = res.timing
    assert tm["ticks"] == 10_000 and tm["rate_hz"] == 1000.0 and tm["overruns"] == 0 and not tm["realtime"]
    # the device clock: every command 1 ms (16,000 MCU cycles) after the previous one, 10 s in all
    t = np.asarray(res.log["t_s"])
    assert len(t) == 10_000 and np.all(np.abs(np.diff(t) - 1e-3) < 1e-9), np.unique(np.round(np.diff(t), 7))
    assert t[-1] - t[0] == pytest.approx(duration_s - 1e-3, abs=1e-9)
    # no watchdog anywhere: the firmware's (STATE bit 4, in every reply) nor the harness's wall-clock release
    assert link["watchdog_trips"] == 0 and not np.any(states[:, 2].astype(int) & Status.WATCHDOG_TRIPPED)
    ls = harness["lockstep"]
    assert ls["timeouts"] == 0 and ls["free"] == 0 and ls["currents"] >= 10_000 and ls["frames_dropped"] == 0
    assert link["timeouts"] == 0 and link["losses"] == 0 and link["crc_errors"] == 0
    # events: device times within the run, one per tap of the simulated hand at its speed
    assert len(res.events) >= 12
    assert all(0.0 < e.t_s < t[-1] for e in res.events)
    v = np.array([e.incoming_velocity_m_s for e in res.events])
    cycle = np.resize(TAPS_M_S, len(v))
    assert np.all(np.abs(v - cycle) < 0.1 * cycle), v
    # what the firmware reports it applied (STATE current_mA) is the command that STATE answers, to the mA
    applied, sent = states[:, 1], np.clip(states[:, 3], -2.0, 2.0)
    assert len(states) >= 10_000 and np.max(np.abs(np.round(sent * 1000.0) - np.round(applied * 1000.0))) <= 1
    assert np.max(np.abs(cmds)) > 0.05 and np.count_nonzero(sent) > 100  # the wall pushed back: currents to check
    print(f"\nlockstep 10 s: {tm['wall_time_s']:.1f} s wall ({tm['realtime_factor']:.2f}x real time), "
          f"{ls['late_replies']} late replies (max {ls['late_max_cycles']} cycles), the MCU waited for the host "
          f"{ls['wait_wall_s']:.1f} s of wall time in {ls['waits']} waits; events at "
          + ", ".join(f"{e.t_s:.2f} s" for e in res.events))


def test_the_firmware_watchdog_runs_on_the_device_clock_in_lockstep():
    """Host silence is counted in MCU time: 0.3 s of wall-clock silence trips nothing (the MCU waits), while
    frames that do not feed the watchdog (PINGs, one host period each) trip it after its 30 ms of MCU time."""
    port, handle = fw_sim.start_fw_sim(pace="lockstep", taps_m_s=())
    try:
        with SerialDevice(port, watchdog_ms=30) as dev:
            assert dev.info.lockstep_ticks == 4
            dev.read()
            dev.command(1.0)
            s = dev.read()
            assert s.extra["current_A"] == pytest.approx(1.0, abs=1e-3)
            t_on = s.t_s
            time.sleep(0.3)  # wall-clock silence: the MCU's clock stands still meanwhile
            dev.command(1.0)
            s = dev.read()
            assert not s.status & Status.WATCHDOG_TRIPPED and s.t_s - t_on == pytest.approx(1e-3, abs=1e-9)
            t_on = s.t_s
            for _ in range(20):  # 20 ms of MCU time without a CURRENT: under the 30 ms watchdog
                dev.ping()
            dev.command(1.0)
            s = dev.read()
            assert not s.status & Status.WATCHDOG_TRIPPED and s.extra["current_A"] == pytest.approx(1.0, abs=1e-3)
            t_on = s.t_s
            for _ in range(40):  # 40 ms: the firmware zeroes the motor after 30 ms of MCU time
                dev.ping()
            st = _wait_for(lambda: (lambda d: d if d["motor_zeroings"] == 1 else None)(handle.stats()),
                           "the harness reports the zeroing")
            assert st["motor_A"] == 0.0
            dev.command(0.5)  # the host is back: output resumes, the gap is reported once
            s = dev.read()
            assert s.status & Status.WATCHDOG_TRIPPED and s.extra["current_A"] == pytest.approx(0.5, abs=1e-3)
            assert s.t_s - t_on == pytest.approx(41e-3, abs=1e-9)  # 40 pings and this CURRENT, 1 ms each
            assert dev.link_stats()["watchdog_trips"] == 1
    finally:
        handle.stop()


def test_a_killed_or_hung_simulator_is_detected_and_a_silent_host_is_zeroed():
    """Lockstep takes no wall-clock watchdog away from a real stall: a killed harness (pty gone) is seen at the
    next read, a hung one after the driver's ``lockstep_timeout_s``; with ``lockstep_free_run_s`` a host silent
    that long lets the MCU run free, and the firmware's watchdog zeroes the motor."""
    # a host that goes silent: the MCU runs free after lockstep_free_run_s and its watchdog zeroes the motor
    # (2 s of wall time: far beyond a loaded machine's own stalls between the steps below, which would otherwise
    # let the MCU run free before the test goes silent)
    port, handle = fw_sim.start_fw_sim(pace="lockstep", taps_m_s=(), lockstep_free_run_s=2.0)
    try:
        dev = SerialDevice(port).open()
        dev.read()
        dev.command(1.0)
        assert dev.read().extra["current_A"] == pytest.approx(1.0, abs=1e-3)
        st = _wait_for(lambda: (lambda d: d if d["motor_zeroings"] == 1 else None)(handle.stats()),
                       "the free-running MCU's watchdog zeroes the motor")
        assert st["motor_A"] == 0.0 and st["lockstep"]["timeouts"] >= 1
        assert 100.0 < st["zero_after_host_silence_ms"] < 100.6  # the firmware's 100 ms, in MCU time
        # the harness hangs (SIGSTOP): the host gives up after its lockstep_timeout_s of wall time
        dev.lockstep_timeout_s = dev.timeout_s = 0.5
        os.kill(handle.process.pid, signal.SIGSTOP)
        try:
            dev.command(0.2)
            t0 = time.monotonic()
            s = dev.read()
            waited = time.monotonic() - t0
        finally:
            os.kill(handle.process.pid, signal.SIGCONT)
        assert s.status & Status.DISCONNECTED and "device not responding" in s.extra["error"]
        assert waited >= 0.5
        dev.close()
    finally:
        handle.stop()
    # the harness is killed: the pty closes and the host's next read reports it
    port, handle = fw_sim.start_fw_sim(pace="lockstep", taps_m_s=())
    try:
        dev = SerialDevice(port).open()
        dev.read()
        dev.command(0.3)
        dev.read()
        handle.process.kill()
        handle.process.wait()
        dev.command(0.3)
        t0 = time.monotonic()
        s = dev.read()
        assert s.status & Status.DISCONNECTED and "disconnected" in s.extra["error"]
        assert time.monotonic() - t0 < dev.lockstep_timeout_s  # seen at once, not after the long timeout
        dev.close()
    finally:
        handle.stop()


class _BoardPort(SerialDevice):
    """The same serial driver as on a board's USB port (not a pseudo-terminal)."""

    def _may_run_lockstep(self) -> bool:
        return False


def test_only_a_pseudo_terminal_may_put_the_host_in_lockstep():
    """Lockstep turns off the host's loss detection and the renderer's wall-clock watchdog: a board whose INFO
    said lockstep (third-party firmware setting flags bit 1) is refused at the handshake, so a real motor is
    never left to its firmware's watchdog alone; the simulator's pseudo-terminal is accepted."""
    master, slave = os.openpty()
    try:
        assert is_pseudo_terminal(os.ttyname(slave))
    finally:
        os.close(master)
        os.close(slave)
    assert not is_pseudo_terminal("/dev/null") and not is_pseudo_terminal("/nonexistent/ttyACM0")
    port, handle = fw_sim.start_fw_sim(pace="lockstep", taps_m_s=())
    try:
        with pytest.raises(DeviceError, match="INFO says lockstep.*pseudo-terminal"):
            _BoardPort(port).open()
        dev = SerialDevice(port).open()       # the simulator on its pty: accepted, in lockstep
        assert dev.info.lockstep_ticks > 0 and dev.max_consecutive_losses == 0
        dev.close()
    finally:
        handle.stop()


def test_a_lockstep_period_shorter_than_a_round_trip_on_the_uart_is_refused():
    # a CURRENT and its STATE take 340 us of the 1 Mbaud UART: one 250 us tick per host period cannot work
    with pytest.raises(ValueError, match=r"lockstep_ticks must be a whole number of servo ticks in 2\.\.255"):
        fw_sim.start_fw_sim(pace="lockstep", taps_m_s=(), lockstep_ticks=1)
    with pytest.raises(ValueError, match=r"lockstep_ticks must be in 2\.\.255"):
        make_device("fw-sim?lockstep_ticks=1")
