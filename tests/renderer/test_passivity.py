"""The wall's passivity observer (renderer.passivity, compiled into renderer.law): an unstable wall loop
is stopped with zero output; ordinary walls and taps stay far below its limit."""

import math

import numpy as np
import pytest
from scipy import integrate

import stimuli
from devices.sim import SimDevice
from devices.sim.hand import TapTrajectory
from renderer import law_layout as LAW
from renderer.config import RendererConfig
from renderer.loop import ServoLoop
from renderer.passivity import TRAVEL_M, passivity_constants, wall_energy

TAPS = [0.05, 0.1, 0.15, 0.2, 0.3]
TAPS_S = TapTrajectory(TAPS).duration_s + 0.2


@pytest.mark.parametrize("nz", [1.0, -1.0, 0.6])
def test_wall_energy_is_the_potential_of_the_clamped_wall_force(nz):
    # U(d) = integral of the wall's force along its penetration: k s (|nz| k s below the clamp f_c along z,
    # i.e. f_c / |nz| along d beyond it); cross-checked with scipy's quadrature
    k, f_c = 680.0, 2.9
    force_along_d = lambda s: min(k * s, f_c / abs(nz))  # noqa: E731
    d_s = f_c / (abs(nz) * k)
    for d in (0.0, 1e-4, 0.5 * d_s, d_s, 2 * d_s, 0.02):
        ref = integrate.quad(force_along_d, 0.0, d, points=[d_s] if d > d_s else None)[0]
        assert wall_energy(k, f_c, d, nz) == pytest.approx(ref, rel=1e-9, abs=1e-15)
    assert wall_energy(k, f_c, -1e-3, nz) == 0.0


def test_limit_and_leak_follow_the_config():
    cfg = RendererConfig(stiffness_N_m=680.0, instability_window_s=0.5, instability_energy_frac=2.0)
    decay, limit = passivity_constants(cfg, 1e-4, 2.9)
    assert decay == pytest.approx(math.exp(-1e-4 / 0.5))
    assert limit == pytest.approx(2.0 * (2.9 ** 2 / (2 * 680.0) + 2.9 * TRAVEL_M))
    assert passivity_constants(cfg.replace(stiffness_N_m=0.0), 1e-4, 2.9)[1] == math.inf
    for key in ("instability_window_s", "instability_energy_frac"):
        for bad in (0.0, -1.0, math.nan):
            with pytest.raises(ValueError, match=key):
                RendererConfig(**{key: bad})


def _run(k, user, transient=None, duration_s=2.0, compiled=True, **cfg):
    """A run on the default sim; returns the result and the observer's peak energy over the limit (the
    observer is sampled every ``until_every`` ticks)."""
    peak = [0.0]

    def until(lp):
        peak[0] = max(peak[0], lp.law_state[LAW.W_PO_E])
        return False

    with SimDevice(seed=0) as dev:
        dev.set_user(*user)
        loop = ServoLoop(dev, RendererConfig(stiffness_N_m=k, **cfg), transient, compiled_sim=compiled)
        res = loop.run(duration_s=duration_s, until=until)
        return res, peak[0] / loop._law_c[LAW.C_PO_LIMIT], loop


def test_a_wall_too_stiff_for_the_device_buzzes_at_full_current_and_is_stopped():
    # 2e5 N/m (200x the very firm wall), the hand pressing 10 mm into it: without the observer the wall
    # buzzes for the whole run between no force and the current limit
    press = (-0.01, 2.0, "prescribed")
    free, ratio, loop = _run(2e5, press, instability_energy_frac=1e12)
    assert free.stop_reason == "duration"
    last = free.log["current_A"][-10_000:]
    assert np.ptp(last) > 0.9 * loop.continuous_safe_A  # full-scale oscillation in the last second
    crossings = np.count_nonzero(np.diff(np.sign(np.diff(free.log["position_m"][-10_000:]))))
    assert crossings > 100  # ... at some hundred hertz
    assert ratio * 1e12 > 1.0  # the observer would have stopped it at the default limit
    # with the observer: stopped with zero output, within 2 s, and the message says why and what to change
    for compiled in (True, False):
        res, _, _ = _run(2e5, press, compiled=compiled)
        assert res.stop_reason == "unstable", compiled
        assert res.timing["ticks"] < 20_000
        assert "stiffness_N_m=200000" in res.error and "unstable" in res.error
    # ... and the per-tick and compiled loops stop at the same tick (one law)
    a, _, _ = _run(2e5, press, compiled=True)
    b, _, _ = _run(2e5, press, compiled=False)
    assert a.timing["ticks"] == b.timing["ticks"]


def test_the_stop_zeroes_the_motor():
    sent = []
    with SimDevice(seed=0) as dev:
        dev.set_user(-0.01, 2.0, "prescribed")
        command = dev.command

        def spy(i):
            sent.append(i)
            return command(i)

        dev.command = spy
        res = ServoLoop(dev, RendererConfig(stiffness_N_m=2e5), compiled_sim=False).run(duration_s=3.0)
    assert res.stop_reason == "unstable"
    assert max(abs(i) for i in sent[-200:-1]) > 0.5  # it was buzzing ...
    assert sent[-1] == 0.0 and dev.last_command_A == 0.0  # ... and the last command is zero


@pytest.mark.parametrize("k", [340.0, 680.0, 1020.0])
def test_table_4_1_walls_with_transients_stay_far_below_the_limit(k):
    for transient in (None, stimuli.Pulse(), stimuli.DecayingSinusoid()):
        for grip in (1.0, 3.0):
            res, ratio, _ = _run(k, (TapTrajectory(TAPS), grip), transient, duration_s=TAPS_S)
            assert res.stop_reason == "duration" and len(res.events) == len(TAPS)
            assert ratio < 0.02, (k, transient, grip, ratio)


def test_even_a_wall_that_saturates_within_micrometres_is_not_stopped_for_tapping_on_it():
    for grip in (1.0, 3.0):
        res, ratio, _ = _run(1e6, (TapTrajectory(TAPS), grip), duration_s=TAPS_S)
        assert res.stop_reason == "duration" and len(res.events) >= len(TAPS)
        assert ratio < 0.5, (grip, ratio)


def test_a_handle_that_entered_the_wall_before_the_first_tick_is_no_instability(monkeypatch):
    """The account starts at the first tick: energy the wall stores because the hand pushed in between the
    priming read and that tick (the law's warm-up, a loaded machine) was put in against no force."""
    prime = ServoLoop._prime

    def slow_prime(self, warm_law=True):
        prime(self, warm_law)
        self.device.set_user(-0.01, 2.0, "prescribed")   # the hand, above the wall at priming, is now 10 mm in
        for _ in range(10):
            self.device.command(0.0)
            self.device.read()

    monkeypatch.setattr(ServoLoop, "_prime", slow_prime)
    res, ratio, loop = _run(680.0, (0.005, 2.0, "prescribed"), duration_s=0.5, compiled=False)
    assert res.stop_reason == "duration" and ratio < 0.5, res.error
    # the wall stores more at tick 0 than the observer's limit: counted as generated, it would stop the run there
    assert wall_energy(680.0, loop._law_c[LAW.C_PO_FC], res.log["penetration_m"][0], 1.0) > loop._law_c[LAW.C_PO_LIMIT]
