"""Issue 39 part 3: ``python -m devices calibrate`` for a real board, over the emulator on a real pty."""

import json
import threading

import pytest

from devices.__main__ import main as devices_main
from devices.firmware.emulator import EmulatorHandle, build_emulator
from devices.hardware.serial_device import SerialDevice

DEVICE_ID = "hfam-emulator(sim-joystick)/EMU0001"


@pytest.fixture
def board():
    emu = build_emulator(taps_m_s=(), grip_N=0.0)   # the hand holds the handle still at 1 cm, grip not held
    emu.encoder_offset = 1234                       # an uncalibrated encoder: 1234 counts off
    port = emu.open_pty()
    stop = threading.Event()
    th = threading.Thread(target=emu.serve, args=(stop,), daemon=True)
    th.start()
    try:
        yield port
    finally:
        EmulatorHandle(port, emu, th, stop).stop()


def test_calibrate_stores_the_zero_and_offsets_the_driver_then_loads(board, tmp_path, capsys):
    out = tmp_path / "cal.json"
    out.write_text(json.dumps({"format": "hfam-calibration", "version": 1, "devices": {"other/1": {"encoder_zero_counts": 7}}}))
    with SerialDevice(board) as dev:               # uncalibrated: 1234 counts too high
        res = dev.info.position_resolution_m
        assert dev.read().position_m == pytest.approx(0.01 + 1234 * res, abs=2e-5)
    code = devices_main(["calibrate", "--device", f"serial:{board}", "--known-position-m", "0.01", "--samples", "50",
                         "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    data = json.loads(out.read_text())
    assert data["devices"]["other/1"] == {"encoder_zero_counts": 7}              # the other board's entry kept
    entry = data["devices"][DEVICE_ID]
    assert abs(entry["encoder_zero_counts"] - 1234) <= 1
    assert f"calibrated {DEVICE_ID}" in text and "+10.000 mm" in text
    with SerialDevice(board, calibration=out) as dev:   # the driver loads it on open
        assert dev.read().position_m == pytest.approx(0.01, abs=2e-5)


def test_calibrate_refuses_to_replace_an_entry_without_force(board, tmp_path, capsys):
    out = tmp_path / "cal.json"
    args = ["calibrate", "--device", f"serial:{board}", "--samples", "20", "--out", str(out)]
    assert devices_main(args) == 0
    before = out.read_text()
    capsys.readouterr()
    assert devices_main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "already holds a calibration" in err and "--force" in err
    assert out.read_text() == before
    assert devices_main(args + ["--force"]) == 0


def test_calibrate_bad_input_is_one_error_line(tmp_path, capsys):
    assert devices_main(["calibrate", "--device", "sim", "--out", str(tmp_path / "c.json")]) == 2
    assert "serial:<port>" in capsys.readouterr().err
    assert devices_main(["calibrate", "--device", "serial:/dev/nonexistent-hfam", "--out", str(tmp_path / "c.json")]) == 2
    assert capsys.readouterr().err.startswith("error:")
    assert not (tmp_path / "c.json").exists()
    with pytest.raises(SystemExit) as info:
        devices_main(["calibrate", "--device", "serial:/dev/x", "--known-position-m", "nan", "--out", "c.json"])
    assert info.value.code == 2
