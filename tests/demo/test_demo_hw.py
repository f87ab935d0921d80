"""Hardware mode of the demo over the emulated serial port (a real pty), with scripted prompts.

The emulator's simulated hand plays the person: it keeps tapping at 0.1 m/s. The
scripted prompt plays the person's other job, putting the real sample under the stylus and taking
it away again (the emulator's sim sample is switched between renderings).
"""

import argparse
import csv

import pytest

from devices.emulator import start_emulator
from renderer import demo_hw


def args_for(port, out, **kw):
    ns = argparse.Namespace(device=f"serial:{port}", out=out, taps=2, library=None, scope="text",
                            renderings=("firm", "pulse_firm"), timeout=20.0,
                            # a loaded CI machine can stall a process for >20 ms; widen the host loop's
                            # watchdog so the test checks the demo, not the scheduler
                            watchdog_overrun_s=0.2)
    for k, v in kw.items():
        setattr(ns, k, v)
    return ns


def test_person_taps_each_rendering_over_the_emulated_serial_port(tmp_path, capsys):
    port, handle = start_emulator("streaming", sample="wood_on_foam", taps_m_s=(0.1,))
    prompts = []

    def person(text):
        prompts.append(text)
        # before each virtual rendering the person swaps the real sample for the placeholder
        handle.emulator.phys.set_sample("wood_on_foam" if "wood-on-foam" in text else "placeholder")
        return ""

    try:
        code = demo_hw.run_hardware_demo(args_for(port, tmp_path), prompt=person)
    finally:
        handle.stop()
    assert code == 0
    assert len(prompts) == 3 and "wood-on-foam" in prompts[0] and "firm proportional" in prompts[1]
    stdout = capsys.readouterr().out
    assert "taps 2/2" in stdout  # the text scope ran
    with open(tmp_path / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    by = {}
    for r in rows:
        by.setdefault(r["rendering"], []).append(r)
    assert set(by) == {"real_wood_on_foam", "firm", "pulse_firm"}
    assert all(len(v) >= 2 for v in by.values())
    real_peak = max(float(r["peak_accel_m_s2"]) for r in by["real_wood_on_foam"])
    firm_peak = max(float(r["peak_accel_m_s2"]) for r in by["firm"])
    # the real sample's contact transient dwarfs the proportional wall's, as in the sim demo
    assert firm_peak < 0.5 * real_peak
    for r in by["firm"] + by["pulse_firm"]:
        assert 0.07 < float(r["velocity_m_s"]) < 0.13
        # compared with the real tap at the same speed: proportional feedback and a pulse are poor copies
        assert float(r["nrmse"]) > 0.8 and float(r["correlation"]) < 0.6
    assert (tmp_path / "fig_contact.png").read_bytes()[:4] == b"\x89PNG"


def test_unknown_rendering_is_refused_before_anyone_taps(tmp_path):
    port, handle = start_emulator("streaming")
    try:
        with pytest.raises(ValueError, match="unknown nope"):
            demo_hw.run_hardware_demo(args_for(port, tmp_path, renderings=("nope",)), prompt=lambda t: "")
    finally:
        handle.stop()


def test_text_scope_draws_a_sparkline(capsys):
    import numpy as np

    scope = demo_hw.TextScope()
    t = np.arange(100) / 1000.0
    scope.update(t, np.zeros(100), np.sin(t * 600), 1, 3)
    scope.close()
    out = capsys.readouterr().out
    assert "taps 1/3" in out and "█" in out
