"""`renderer run` on each 3-DOF device's emulator: the 1-DOF wall along the vertical axis, the emulated hand's taps
found with their speeds, the link's timing in run.json as the serial board's; an unplugged device ends the run
with its data kept (docs/bringup.md)."""

import csv
import json

import numpy as np
import pytest

from renderer.__main__ import main as renderer_main
from tests.support.stalls import fake_hd_stats, run_stalled

DEVICES = ["inverse3:emulator", "falcon:emulator", "woodenhaptics:emulator", "dhd:emulator", "touch:Default Device"]


def _run(spec, out, tmp_path, capsys, duration_s="2.6", extra=()):
    cfg = tmp_path / "cfg.toml"
    # a loaded machine can stall this process for >20 ms (258 ms seen at a load of 7 on 2 cores): the loop's own
    # overrun watchdog is widened so the test checks the device path, not the scheduler (the devices' watchdogs
    # stay 20 ms)
    cfg.write_text("watchdog_overrun_s = 1.0\n")
    code = renderer_main(["run", "--in-process", "--device", spec, "--duration-s", duration_s, "--transient",
                          "pulse", "--config", str(cfg), "--no-figure", "--out", str(out), *extra])
    return code, capsys.readouterr().out


def _taps_as_planned(code, out) -> bool:
    """The run ended by its duration with the emulated hand's taps found at its speeds and depths."""
    if code != 0 or not (out / "events.csv").is_file():
        return False
    with open(out / "events.csv") as fh:
        events = list(csv.DictReader(fh))
    return len(events) >= 2 and all(0.02 < float(e["incoming_velocity_m_s"]) < 0.3
                                    and 0.0003 < float(e["max_penetration_m"]) < 0.01 for e in events)


def _trace_before(out, t_event_s: float, span_s: float = 0.03) -> str:
    """The log's last ``span_s`` before ``t_event_s``: tick time, wall-clock period, position and velocity, for a
    failure's message (a tap read far off its speed: what the loop saw)."""
    with np.load(out / "log.npz") as z:
        t, wall, x, v = z["t_s"], z["wall_ns"], z["position_m"], z["velocity_m_s"]
    i = np.flatnonzero((t >= t_event_s - span_s) & (t <= t_event_s + 0.002))
    period_us = np.diff(wall, prepend=wall[0]) / 1000.0
    return "\n".join(f"t={t[k]:.4f} s period={period_us[k]:.0f} us x={x[k] * 1e3:.3f} mm v={v[k]:.3f} m/s"
                     for k in i)


def _losses(out) -> int:
    """The run's lost replies (``run.json``'s link counters)."""
    return int(json.loads((out / "run.json").read_text())["link"]["losses"])


@pytest.mark.parametrize("spec", DEVICES)
def test_renderer_run_on_the_emulated_device(spec, tmp_path, capsys, monkeypatch, request):
    lib = None
    if spec.startswith("touch"):
        lib = str(request.getfixturevalue("fake_hd"))
        monkeypatch.setenv("HFAM_OPENHAPTICS_LIB", lib)
    spec = spec + "?loss_timeout_s=0.1"   # a loaded machine stalls the emulators for tens of ms
    for attempt in range(3):
        out = tmp_path / f"run{attempt}"
        if lib is not None:
            fake_hd_stats(lib, reset=True)
        code, stdout = _run(spec, out, tmp_path, capsys)
        if (_taps_as_planned(code, out) and _losses(out) <= 10) or not run_stalled(out, lib):
            break
        # the machine stalled this process for tens of ms while the device held the last force and the emulated
        # hand pressed on (a 41 ms period and a 105 ms link gap with two suites on 2 cores): the passivity
        # observer rightly stopped the wall, which its own tests check, or late replies counted 13 lost; or it
        # stalled the fake Touch library's scheduler thread past the 100 ms loss timeout, and the driver rightly
        # declared the device gone. Then run again: a run without a stall must pass
    assert code == 0, stdout
    run = json.loads((out / "run.json").read_text())
    assert run["rate_hz"] == 1000.0 and run["stop_reason"] == "duration"
    assert run["device"]["name"].endswith("(vertical axis)")
    link = run["link"]
    assert link["frames_tx"] >= 2600 and link["rtt_samples"] >= 2500
    assert 0 < link["rtt_median_s"] < 0.005 and link["losses"] <= 10
    with open(out / "events.csv") as fh:
        events = list(csv.DictReader(fh))
    # the emulated hand taps along z at 0.05, 0.1, 0.2 m/s (the Touch's fake library: 0.1 m/s)
    v = sorted(float(e["incoming_velocity_m_s"]) for e in events)
    off = [e for e in events if not 0.02 < float(e["incoming_velocity_m_s"]) < 0.3]
    assert len(events) >= 2 and not off, (
        f"attempt {attempt}: taps {[(e['t_s'], e['incoming_velocity_m_s']) for e in events]}; period max "
        f"{run.get('period_max_us')} us; link {link}; fake HD stats {fake_hd_stats(lib) if lib else None}\n"
        + "\n".join(_trace_before(out, float(e["t_s"])) for e in off[:1]))
    if not spec.startswith("touch"):
        assert v[0] < 0.07 and v[-1] > 0.14
    assert all(0.0003 < float(e["max_penetration_m"]) < 0.01 for e in events)
    log = np.load(out / "log.npz")
    assert abs(log["current_A"]).max() <= run["device"]["current_amplifier_A"] + 1e-9   # N here: 1 N per A
    assert run["compute_p50_us"] > 0 and run["period_p50_us"] > 0   # the per-tick host cost, as the serial board's
    assert "link:" in stdout and "round trip" in stdout


def test_an_unplugged_device_stops_the_run_and_keeps_its_data(tmp_path, capsys):
    out = tmp_path / "run"
    code, stdout = _run("falcon:emulator?fault_unplug_after=1500", out, tmp_path, capsys, duration_s="5")
    assert code == 1 and "stop: disconnected" in stdout
    run = json.loads((out / "run.json").read_text())
    assert run["stop_reason"] == "disconnected" and 1.2 < run["sim_time_s"] < 2.0
    assert "falcon:0" in run["error"] and "disconnected" in run["error"] and "zeroed" in run["error"]
    with open(out / "events.csv") as fh:
        assert len(list(csv.DictReader(fh))) >= 1   # the taps before the cable was pulled


def test_a_3d_scene_opens_the_device_with_its_three_axes(tmp_path, capsys):
    """`renderer run` on a 3-D scene drives all three motors of a 3-DOF device (no ``?axes=3`` needed): a block
    whose top is where the emulated hand taps, found along its normal, with the hand's speeds."""
    cfg = tmp_path / "scene.toml"
    cfg.write_text('watchdog_overrun_s = 1.0\nstiffness_N_m = 680.0\n[scene]\nobjects = [\n  { shape = "box", '
                   'center_m = [0.0, 0.0, -0.01], half_extents_m = [0.03, 0.03, 0.01], name = "block", '
                   'stiffness_N_m = 680.0 },\n]\n')
    out = tmp_path / "run"
    code = renderer_main(["run", "--in-process", "--device", "falcon:emulator?loss_timeout_s=0.1", "--duration-s",
                          "2.3", "--config", str(cfg), "--no-figure", "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0, stdout
    run = json.loads((out / "run.json").read_text())
    assert run["device"]["name"] == "Novint Falcon" and run["device"]["axes"] == 3, run["device"]
    with open(out / "events.csv") as fh:
        events = list(csv.DictReader(fh))
    assert {e["object"] for e in events} == {"block"}, events
    whole = [e for e in events if int(e["tick"]) < 2300 - 100]   # a tap the run's end cut off has no depth yet
    assert len(whole) >= 2
    for e in whole:
        assert float(e["normal_z"]) == pytest.approx(1.0, abs=1e-6)
        assert 0.02 < float(e["incoming_velocity_m_s"]) < 0.3 and 0.0003 < float(e["max_penetration_m"]) < 0.01
    log = np.load(out / "log.npz")
    # the motors pushed the handle back out along z; x and y carry the proxy's (frictionless) lateral force only
    assert log["force_z_N"].max() > 0.5 and abs(log["sensor_flags"]).max() == 0   # no accelerometer is no fault
