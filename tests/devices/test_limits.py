"""Implausible inputs against the device's own limits (issue 39, part 5): refused with one clear error naming the
flag, the value and the limit, or warned about where the run still means something."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from devices.limits import (
    IMPLAUSIBLE_STIFFNESS_FACTOR,
    RATED_TAP_SPEED_M_S,
    check_grips,
    check_stiffness,
    check_tap_speeds,
    one_count_stiffness_N_m,
)
from devices.registry import make_device
from tests.support.cli import run_cli

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args, cwd):
    # the JIT loop, like every test (tests/conftest.py): no background build into the user's cache
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg",
                               "HFAM_SIM_AOT": "off"}, timeout=900)


def test_grips_outside_the_sensor_range_are_refused():
    info = make_device("sim").info
    assert check_grips(info, [0.0, 1.0, 10.0]) == (0.0, 1.0, 10.0)
    with pytest.raises(ValueError, match=r"--grips-N 200 N: outside the grip range of .*, 0-10 N"):
        check_grips(info, [0.0, 1.0, 200.0])
    with pytest.raises(ValueError, match=r"--grip-N 500 N"):
        check_grips(info, [500.0], "--grip-N")


def test_tap_speeds_warned_above_rated_and_refused_far_above():
    assert check_tap_speeds([0.05, 0.3]) == (0.05, 0.3)
    with pytest.warns(RuntimeWarning, match=r"0.8 m/s is above the device's rated tap speed 0.5 m/s"):
        check_tap_speeds([0.1, 0.8])
    with pytest.raises(ValueError, match=r"--velocities-m-s 5 m/s: not a tap speed"):
        check_tap_speeds([0.1, 5.0])
    assert RATED_TAP_SPEED_M_S == 0.5


def test_stiffness_against_one_encoder_count():
    info = make_device("sim").info
    k1 = one_count_stiffness_N_m(info)
    assert k1 == pytest.approx(info.current_continuous_A * info.force_per_amp_N_A / info.position_resolution_m)
    assert check_stiffness(info, 680.0) == 680.0
    with pytest.warns(RuntimeWarning, match="a switch between zero and the limit"):
        check_stiffness(info, 2 * k1)
    with pytest.raises(ValueError, match=r"stiffness_N_m=1e\+09 N/m: far beyond"):
        check_stiffness(info, 1e9)
    assert 1e9 > IMPLAUSIBLE_STIFFNESS_FACTOR * k1


@pytest.mark.parametrize("args, message", [
    (["-m", "renderer", "run", "--device", "sim", "--stiffness-N-m", "1e9", "--out", "r1"],
     "error: stiffness_N_m=1e+09 N/m: far beyond what the device can render"),
    (["-m", "renderer", "run", "--device", "sim", "--grip-N", "500", "--out", "r2"],
     "error: --grip-N 500 N: outside the grip range"),
    (["-m", "renderer", "run", "--device", "sim", "--velocities-m-s", "5", "--out", "r3"],
     "error: --velocities-m-s 5 m/s: not a tap speed"),
    (["-m", "devices", "identify", "--device", "sim", "--grips-N", "0,1,200", "--out", "i1"],
     "error: --grips-N 200 N: outside the grip range"),
    (["-m", "devices", "record", "--device", "sim", "--velocities-m-s", "3", "--out", "t.csv"],
     "error: --velocities-m-s 3 m/s: not a tap speed"),
])
def test_commands_refuse_implausible_inputs_with_one_line(tmp_path, capsys, args, message):
    assert args[0] == "-m"
    res = run_cli(capsys, *args[1:], cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and message in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []        # nothing written


def test_renderer_run_warns_about_a_speed_outside_the_hfam_library(tmp_path):
    """HFAM at 0.18 m/s on a library recorded up to 0.12 m/s: the run goes on, with one warning line saying the
    transient is extrapolated."""
    import numpy as np

    from stimuli.library import HfamLibrary
    lib = HfamLibrary.load(ROOT / "stimuli" / "libraries" / "wood_on_foam_sim.npz")
    small = HfamLibrary(lib.velocities_m_s[lib.velocities_m_s <= 0.12], lib.grips_N,
                        lib.currents_A[lib.velocities_m_s <= 0.12], lib.fs_hz, lib.force_per_amp_N_A)
    small.save(tmp_path / "lib.npz")
    hi = float(np.max(small.velocities_m_s))
    res = _cli("-m", "renderer", "run", "--device", "sim", "--transient", "hfam", "--library",
               str(tmp_path / "lib.npz"), "--velocities-m-s", "0.18", "--taps", "1", "--out", "r", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (f"warning: --velocities-m-s 0.18 m/s outside the HFAM library's {small.velocities_m_s[0]:g}-{hi:g} m/s"
            in res.stderr)


def test_demo_explains_hfam_clipping_and_a_negative_cut():
    """`renderer demo --device sim:lti` showed HFAM clipping 11/15 taps and a -12 % "cut" without a word: the
    table now says why (the library's peak current against the device's limit; the limit taking the wall's
    current)."""
    import numpy as np

    from renderer.demo.sim_demo import clipping_explanation
    from stimuli.library import HfamLibrary
    lib = HfamLibrary([0.05, 0.1], [1.0, 3.0], np.full((2, 2, 10), 0.5) * np.linspace(1, -1, 10), 1e4, 2.35)
    rows = [{"rendering": "hfam_firm", "clipped": 11, "taps": 15}, {"rendering": "firm", "clipped": 0, "taps": 15}]
    text = clipping_explanation(rows, {"pulse_firm": 0.4, "hfam_firm": -0.12}, lib)
    assert len(text) == 2
    assert text[0].startswith("Why hfam_firm clipped 11/15 taps: its transients ask up to 0.50 A")
    assert text[1].startswith("A negative cut (hfam_firm -12 %)")
    assert clipping_explanation([{"rendering": "hfam_firm", "clipped": 1, "taps": 15}], {"hfam_firm": 0.3}, lib) == []
