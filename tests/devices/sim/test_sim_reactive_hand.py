"""The optional reactive simulated hand (devices.sim.ReactiveHand): hand mass, muscle impedance, contact reflex.

The default hand (eq. 3.34, tied to its desired trajectory) must stay exactly as it was; the reactive one
must follow free motion like it, be decelerated by an impulse as a ~0.23 kg mass would be, and stop
pushing ``reflex_delay_s`` after it feels a contact.
"""

from __future__ import annotations

import numpy as np
import pytest

from devices.sim import ReactiveHand, SimDevice, TapTrajectory, default_params
from devices.sim import kernel as K

FS = 10000.0


def _quiet():
    p = default_params()
    return p.replace(sensors={"accel_noise_m_s2": 0.0})


def _run(dev, n, current_A=0.0, log=None):
    for _ in range(n):
        dev.command(current_A)
        if log is not None:
            log.append(dev.true_state())


def _tool_mass(dev):
    return float(dev._p[K.P_MM] + dev._p[K.P_MD] + dev._p[K.P_MH])


def test_default_hand_unchanged_after_a_reactive_one():
    """set_user without ``hand`` gives bit-identical physics, even on a device that used the reactive hand."""
    traj = TapTrajectory(0.1, n_taps=1, approach_height_m=0.004, press_depth_m=0.003)
    fresh, used = SimDevice(_quiet(), sample="wood_on_foam"), SimDevice(_quiet(), sample="wood_on_foam")
    used.set_user(traj, grip_N=2.0, hand=ReactiveHand())
    _run(used, 500)
    a, b = [], []
    for dev, log in ((fresh, a), (used, b)):
        dev.set_user(traj, grip_N=2.0)
        assert dev.hand is None
        _run(dev, 1500, log=log)
    xa = np.array([s["handle_position_m"] for s in a])
    xb = np.array([s["handle_position_m"] for s in b])
    assert np.array_equal(xa, xb)


def test_free_motion_follows_the_trajectory():
    """The feedforward (internal model) keeps the reactive hand on its trajectory in free space."""
    v = 0.1
    dev = SimDevice(_quiet())
    dev.set_user(TapTrajectory(v, n_taps=1, approach_height_m=0.02, press_depth_m=0.003), grip_N=2.0,
                 hand=ReactiveHand())
    log = []
    _run(dev, 1500, log=log)                       # 20 ms ramp, then cruise; no sample: no contact
    vh = np.array([s["handle_velocity_m_s"] for s in log])
    cruise = vh[600:1500]
    assert np.all(np.abs(cruise + v) < 0.06 * v)   # within 6 % of the tap speed (friction load, no integrator)
    assert not any(s["reflex_holding"] for s in log)


def test_impulse_decelerates_the_reactive_hand_like_a_mass():
    """An upward 10 ms current pulse in cruise: the reactive hand mass loses ~J/(m_a + m_tool) of its
    speed and the handle follows it; the default (velocity-source) hand's handle gets back on its track."""
    v, i_A, n_pulse = 0.1, 0.2, 100
    impulse = i_A * SimDevice().info.force_per_amp_N_A * n_pulse / FS
    expected = impulse / (ReactiveHand().arm_mass_kg + _tool_mass(SimDevice()))
    for hand in (None, ReactiveHand()):
        dev = SimDevice(_quiet())
        dev.set_user(TapTrajectory(v, n_taps=1, approach_height_m=0.03, press_depth_m=0.003), grip_N=2.0,
                     hand=hand)
        _run(dev, 1000)
        before = dev.true_state()
        _run(dev, n_pulse, i_A)
        after = []
        _run(dev, 150, log=after)
        # mean handle speed change 2.5-15 ms after the pulse (the linkage's ringing averages out)
        dv_handle = np.mean([s["handle_velocity_m_s"] for s in after[25:]]) - before["handle_velocity_m_s"]
        if hand is None:
            assert abs(dv_handle) < 0.25 * expected
        else:
            dv_arm = after[25]["arm_velocity_m_s"] - before["arm_velocity_m_s"]
            assert dv_arm == pytest.approx(expected, rel=0.2)      # muscle damping takes a little of it
            assert dv_handle > 0.6 * expected


def test_contact_reflex_holds_the_target():
    """Pressing through a stiff sample: ~40 ms after the contact force rises, the hand's target holds,
    so the hand penetrates far less than with the reflex switched off (a delay longer than the tap)."""
    v = 0.1
    pen = {}
    for delay in (0.04, 10.0):
        dev = SimDevice(_quiet(), sample="wood_on_foam")
        dev.motor_enabled = False
        traj = TapTrajectory(v, n_taps=1, approach_height_m=0.004, press_depth_m=0.02)   # pushes for ~300 ms
        dev.set_user(traj, grip_N=2.0, hand=ReactiveHand(reflex_delay_s=delay))
        log = []
        _run(dev, 3000, log=log)
        pen[delay] = -min(s["handle_position_m"] for s in log)
        holding = [s["t_s"] for s in log if s["reflex_holding"]]
        contact = [s["t_s"] for s in log if s["in_contact"]]
        if delay == 0.04:
            assert holding, "reflex never fired"
            assert 0.04 <= holding[0] - contact[0] <= 0.06     # delay + force build-up of a few ms
        else:
            assert not holding
    assert pen[0.04] < 0.75 * pen[10.0]          # measured 0.61


def test_bad_reactive_hand_parameters():
    with pytest.raises(ValueError, match="arm_mass_kg"):
        ReactiveHand(arm_mass_kg=0.0)
    with pytest.raises(ValueError, match="reflex_delay_s"):
        ReactiveHand(reflex_delay_s=float("nan"))
    with pytest.raises(ValueError, match="ReactiveHand"):
        SimDevice().set_user(0.0, hand="reactive")
    with pytest.raises(ValueError, match="nonlinear"):
        SimDevice.from_spec("lti").set_user(0.0, hand=ReactiveHand())
