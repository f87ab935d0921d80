"""The serial driver's default on-device telemetry decimation fits the STATE frames into the link.

A STATE frame every tick of the 4 kHz ATmega328P board needs 92 % of its 1 Mbaud UART: the firmware
then drops frames (devices/firmware/README.md). The rule (devices.hardware.serial_device.
default_telemetry_decimation) takes the smallest decimation within half the link; checked here as
arithmetic and over the real pseudo-terminal against the real firmware on simavr (fw-sim).
"""

import numpy as np
import pytest

from devices import make_device
from devices.hardware.serial_device import (
    CONSERVATIVE_DECIMATION,
    STATE_FRAME_BYTES,
    SerialDevice,
    default_telemetry_decimation,
)
from renderer import RendererConfig, ServoLoop


def test_the_rule_takes_the_smallest_decimation_within_half_the_link():
    assert STATE_FRAME_BYTES == 23  # sync 2, length, type, seq, 16 payload bytes, CRC 2
    assert default_telemetry_decimation(4000.0, 1_000_000 / 10) == 2     # 92 kB/s of 100: every 2nd tick (46 %)
    assert default_telemetry_decimation(4000.0, 921_600 / 10) == 2       # 92 kB/s of 92.16: 49.9 % at 2
    assert default_telemetry_decimation(2000.0, 1_000_000 / 10) == 1     # 46 % at every tick
    assert default_telemetry_decimation(10_000.0, 921_600 / 10) == 5     # 230 kB/s of 92.16: 49.9 % at 5
    assert default_telemetry_decimation(1000.0, 115_200 / 10) == 4       # 23 kB/s of 11.52: 49.9 % at 4
    assert default_telemetry_decimation(4000.0, None) == CONSERVATIVE_DECIMATION == 2   # link rate unknown
    for rate, baud in ((4000.0, 1_000_000), (10_000.0, 921_600), (1000.0, 115_200), (333.0, 9600)):
        d = default_telemetry_decimation(rate, baud / 10)
        share = STATE_FRAME_BYTES * rate / d / (baud / 10)
        assert share <= 0.5 and (d == 1 or STATE_FRAME_BYTES * rate / (d - 1) / (baud / 10) > 0.5), (rate, baud, d)


def test_an_explicit_decimation_is_kept_and_a_bad_one_refused():
    dev = SerialDevice("/dev/null-not-opened", telemetry_decimation=1)
    assert dev.telemetry_decimation_option == 1
    assert SerialDevice("/dev/null-not-opened").telemetry_decimation_option is None
    assert SerialDevice("/dev/null-not-opened", baudrate=1_000_000).link_bytes_per_s() == 100_000.0
    with pytest.raises(ValueError, match="telemetry_decimation must be >= 1 tick, got 0"):
        SerialDevice("/dev/null-not-opened", telemetry_decimation=0)


def _run_on_board(spec: str):
    """1 s of on-board rendering on the AVR firmware (simavr) over its pty: (decimation, frame times, seq gaps)."""
    dev = make_device(spec)
    with dev:
        res = ServoLoop(dev, RendererConfig()).run(duration_s=1.0)
        # the log's row rate is the telemetry's, which the study's spectra and saved traces use
        assert res.timing["log_rate_hz"] == dev.info.servo_rate_hz / dev.telemetry_decimation
        assert res.timing["rate_hz"] == dev.info.servo_rate_hz
        return dev.telemetry_decimation, np.asarray(res.log["t_s"]), dev.stats["seq_gaps"]


def test_default_decimation_drops_no_state_frame_on_the_4_khz_firmware():
    d, t, gaps = _run_on_board("fw-sim?mode=on-device&pace=fast")   # no telemetry_decimation: the rule's
    assert d == 2
    dt_us = np.round(np.diff(t) * 1e6)
    assert gaps == 0 and np.all(dt_us == 500.0)       # every 2nd 250 us tick, none missing
    assert len(t) == 2000 and abs((t[-1] - t[0]) - 0.9995) < 1e-9   # and the run lasted 1 s of device time
    # what the rule avoids: a frame every tick overruns the UART and the firmware drops frames
    d1, t1, gaps1 = _run_on_board("fw-sim?mode=on-device&pace=fast&telemetry_decimation=1")
    assert d1 == 1 and gaps1 > 100 and np.count_nonzero(np.round(np.diff(t1) * 1e6) > 250.0) > 100
