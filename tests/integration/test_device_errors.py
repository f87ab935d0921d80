"""A device that cannot be opened is a user error: one ``error: ...`` line naming it, exit code 2."""

from __future__ import annotations

import numpy as np
import pytest

from devices.base import DeviceError, DeviceInfo, DeviceState, Status
from devices.base import Device

MISSING_PORT = "serial:/dev/hfam-no-such-port"


def _main(package: str):
    import importlib

    return importlib.import_module(f"{package}.__main__").main


@pytest.mark.parametrize("argv", [
    ["devices", "record", "--velocities", "0.1", "--out", "{tmp}/rec.csv"],
    ["devices", "identify", "--grip", "2", "--out", "{tmp}/ident"],
    ["renderer", "run", "--in-process", "--duration", "0.1", "--out", "{tmp}/run"],
    ["renderer", "run", "--duration", "0.1", "--out", "{tmp}/run"],  # servo in its own process
])
def test_missing_serial_port_is_a_one_line_error(argv, tmp_path, capsys):
    args = [a.format(tmp=tmp_path) for a in argv[1:]] + ["--device", MISSING_PORT]
    assert _main(argv[0])(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and "/dev/hfam-no-such-port" in err[-1]
    assert not any("Traceback" in line for line in err)


class _HandshakeDevice(Device):
    """Like a serial device: ``info`` exists only after the hello handshake of ``open()``."""

    def __init__(self):
        super().__init__()
        self.opened = 0

    def __getattr__(self, name):
        if name == "info":
            raise DeviceError("info comes from the hello handshake; open the device first")
        raise AttributeError(name)

    def _open(self):
        self.opened += 1
        self.info = DeviceInfo(name="hs", encoder_lines=2000, gear_ratio=15.0, handle_length_m=0.15,
                               torque_constant_Nm_A=0.0235, current_continuous_A=1.26, current_peak_A=4.0,
                               current_amplifier_A=4.0, servo_rate_hz=10000.0)

    def _close(self):
        pass

    def read(self):
        return DeviceState(t_s=0.0, position_m=0.0, accel_m_s2=0.0, grip_N=0.0, status=Status.OK)

    def _send_current(self, current_A):
        pass


def test_build_library_opens_a_handshake_device_for_its_info(monkeypatch, tmp_path):
    from stimuli import cli_build

    dev = _HandshakeDevice()
    monkeypatch.setattr("devices.registry.make_device", lambda spec: dev)
    ns = type("A", (), dict(device="serial:/dev/x", force_per_amp=None, peak_current_A=None))()
    fpa, peak, rate, grips = cli_build._device_limits(ns)
    assert dev.opened == 1 and not dev._is_open
    assert fpa == pytest.approx(0.0235 * 15.0 / 0.15) and peak == 4.0 and rate == 10000.0
    assert np.isfinite(fpa) and grips == (0.0, 10.0)


def test_renderer_run_keeps_the_log_of_a_failed_servo_process(monkeypatch, tmp_path, capsys):
    """The servo process fails after 199 ticks: ``renderer run`` saves them before reporting the error."""
    from renderer import process
    from tests.renderer.fakes import make_failing_device

    real = process.run_in_process
    monkeypatch.setattr(process, "run_in_process",
                        lambda device, cfg, transient, **kw: real(make_failing_device, cfg, transient,
                                                                  duration_s=1.0, realtime=False))
    with pytest.raises(RuntimeError, match="injected failure"):
        _main("renderer")(["run", "--device", MISSING_PORT, "--duration", "1", "--out", str(tmp_path / "run")])
    assert "partial run saved" in capsys.readouterr().err
    import json

    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["stop_reason"] == "exception" and run["ticks"] == 199
    assert (tmp_path / "run" / "log.npz").exists()


def test_build_library_warns_when_model_grips_miss_the_device_grip_range(tmp_path, capsys):
    """Models at 0-4 N only: the sim's grip sensor spans 0-10 N, so renderer/study would refuse the library."""
    from devices.sim import SimDevice

    rec = tmp_path / "rec.csv"
    assert _main("devices")(["record", "--device", "sim", "--sample", "wood_on_foam", "--velocities", "0.05,0.08",
                             "--grip", "2", "--out", str(rec)]) == 0
    dev = SimDevice()
    models = []
    for g in (0.0, 4.0):
        m = dev.linear_model(g)
        m = type(m)(m.zeros_rad_s, m.poles_rad_s, m.gain, m.delay_s, band_hz=(10.0, 1000.0), grip_N=g)
        models += ["--model", str(m.save(tmp_path / f"accel_g{g:g}N.json") or tmp_path / f"accel_g{g:g}N.json")]
    out = tmp_path / "lib.npz"
    capsys.readouterr()
    assert _main("stimuli")(["build-library", "--recordings", str(rec), *models, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "warning: model grip levels 0..4 N do not cover device 'sim' grip range 0..10 N" in text
    assert out.exists()
