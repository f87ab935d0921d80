"""The servo laws' position rings go by the sample's own clock (renderer.ring): a device that hands over its
newest sample (a servo thread on its own clock, like the Touch's) gives the same velocities and impact speeds
as one that answers every tick, when the host re-reads samples or misses some."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer import RendererConfig, ServoLoop
from renderer.ring import grid_steps
from tests.renderer.fakes import MassDevice, make_info, tap_trajectory

# a late host tick (the device's clock moved 6 periods), then 5 ticks back to back that catch up and read that
# same sample again (renderer.loop: max_catchup_s), every 10 ticks: on average one device period per host tick
LATE_AND_CATCHING_UP = (1, 1, 1, 1, 6, 0, 0, 0, 0, 0)


@pytest.mark.parametrize("t_prev, t, steps", [
    (math.nan, 3.2, -1),          # the first sample starts the grid
    (1.000, 1.001, 1),            # the next sample
    (1.000, 1.0014, 1),           # a jittered one
    (1.000, 1.0004, 0),           # the same sample read again (or a tick too early to be a new one)
    (1.000, 1.000, 0),
    (1.000, 1.003, 3),            # two samples missed
    (1.000, 1.0026, 3),
    (1.000, 2.0, 1000),           # a long gap (the laws fill only the ring's last slots of it)
    (1.000, 0.9, -1),             # the clock went back: restart
    (1.000, math.nan, -1),        # no time
])
def test_grid_steps(t_prev, t, steps):
    assert grid_steps(1000.0, t_prev, t) == steps


class OwnClockDevice(MassDevice):
    """A :class:`MassDevice` whose physics runs on its own clock: host tick ``k`` finds it ``pattern[k % n]``
    periods further on (0: the host reads the same sample again), the last current applied meanwhile."""

    def __init__(self, pattern, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.pattern = pattern
        self.k = 0

    def _send_current(self, current_A: float) -> None:
        if self._in_command:
            for _ in range(self.pattern[self.k % len(self.pattern)]):
                self._step(self.pending_A)
            self.k += 1
        self.pending_A = current_A


def _taps(dev, tr):
    return ServoLoop(dev, RendererConfig(stiffness_N_m=680.0)).run(duration_s=tr.duration_s)


def test_a_device_on_its_own_clock_reads_the_speeds_of_one_answering_every_tick():
    info = make_info(servo_rate_hz=1000.0)        # the Touch's rate
    tr = tap_trajectory(0.3, n_taps=6, height_m=0.02)
    ref = _taps(MassDevice(tr, grip_N=2.0, info=info), tr)
    own = _taps(OwnClockDevice(LATE_AND_CATCHING_UP, tr, grip_N=2.0, info=info), tr)
    assert len(ref.events) == len(own.events) == 6
    v_ref = np.array([e.incoming_velocity_m_s for e in ref.events])
    v_own = np.array([e.incoming_velocity_m_s for e in own.events])
    assert np.all(np.abs(v_ref - 0.3) < 0.03), v_ref
    # the same taps read at the same speeds (within 3.1 %; read naively, two of the six taps read 2.58 m/s)
    np.testing.assert_allclose(v_own, v_ref, rtol=0.05)
    # the per-tick velocity at each new sample is the velocity at that device time; a sample read again keeps it
    t_own, t_ref = own.log["t_s"], ref.log["t_s"]
    new = np.flatnonzero(np.diff(t_own) > 0) + 1
    at = np.searchsorted(t_ref, t_own[new])
    assert np.all(np.abs(t_ref[at] - t_own[new]) < 1e-9)
    # on the way down, before contact (whose forces act over the device's own periods, not the host's)
    descending = (np.abs(ref.log["velocity_m_s"][at]) > 0.1) & (ref.log["penetration_m"][at] < -0.002)
    assert descending.sum() > 100
    err = np.abs(own.log["velocity_m_s"][new] - ref.log["velocity_m_s"][at])[descending]
    # equal but after a jump, where a straight line stands in for the samples the host missed (the hand still
    # accelerating early in a descent); read naively, the jumps gave 1.6 m/s (90th percentile) and 1.9 m/s
    assert np.percentile(err, 90) < 0.03 and err.max() < 0.1, (np.percentile(err, 90), err.max())
    again = np.flatnonzero(np.diff(t_own) == 0) + 1
    assert len(again) > 1000
    np.testing.assert_array_equal(own.log["velocity_m_s"][again], own.log["velocity_m_s"][again - 1])


def test_the_3d_law_fits_a_steady_motion_exactly_through_repeated_and_missed_samples():
    from devices.sim import Sim3Device
    from renderer import law3 as L3
    from renderer.loop3 import ServoLoop3

    dev = Sim3Device()
    dev.set_user(0.0, grip_N=2.0)
    loop = ServoLoop3(dev, RendererConfig())
    loop.prepare()
    loop._prime_state()
    c, w, pk, stack = loop.c.copy(), loop.w.copy(), loop.packed, loop.stack.copy()
    log = np.zeros((L3.N_LOG, 64))
    c[L3.C_CAP] = log.shape[1]          # the law writes its log ring up to this column
    fs = loop.fs_hz
    x0, y0, z0 = w[L3.W_LX], w[L3.W_LY], w[L3.W_LZ]
    v = (0.05, -0.02, 0.1)                  # m/s, upwards: away from the scene's wall
    n, got = 0, []
    for k in range(4 * loop.nring):
        n += LATE_AND_CATCHING_UP[k % len(LATE_AND_CATCHING_UP)]
        t = 5.0 + n / fs
        loop.kernels.law3_tick(c, w, pk.obj, pk.tri, pk.node, stack, log, t, x0 + v[0] * n / fs,
                               y0 + v[1] * n / fs, z0 + v[2] * n / fs, 0.0, 2.0, 0)
        got.append((w[L3.W_VX], w[L3.W_VY], w[L3.W_VZ]))
    # once the ring holds only the motion (not the primed standstill), every tick reads its velocity
    np.testing.assert_allclose(np.array(got[2 * loop.nring:]), np.broadcast_to(v, (2 * loop.nring, 3)), atol=1e-9)


class TimelessDevice(MassDevice):
    """A :class:`MassDevice` whose driver gives no time (every state at t = 0)."""

    def _update_state(self) -> None:
        super()._update_state()
        self.state.t_s = 0.0


def test_a_driver_that_gives_no_time_still_gets_its_velocities():
    info = make_info(servo_rate_hz=1000.0)
    tr = tap_trajectory(0.3, n_taps=3, height_m=0.05)        # the first tap 167 ms in
    ref = _taps(MassDevice(tr, grip_N=2.0, info=info), tr)
    res = _taps(TimelessDevice(tr, grip_N=2.0, info=info), tr)
    # once its clock has stood still longer than any catch-up (RendererConfig.max_catchup_s, 100 ticks here, plus
    # the ring), each tick is a sample again: the same taps at the same speeds
    assert len(res.events) == len(ref.events) == 3
    np.testing.assert_allclose([e.incoming_velocity_m_s for e in res.events],
                               [e.incoming_velocity_m_s for e in ref.events], rtol=1e-9)


def test_the_first_tick_after_a_slow_start_reads_the_motion_since_the_priming_sample():
    """The loop primes its ring with one sample, then warms up (a cache load, a first transfer) before its first
    tick: a device on its own clock has moved on meanwhile, and the first tick must not read that motion as one
    period's (a tap at the first tick read 23 m/s for 0.1 on the emulated Touch)."""
    info = make_info(servo_rate_hz=1000.0)
    tr = tap_trajectory(0.1, n_taps=1, height_m=0.0101)    # the hand reaches the wall 101 ms in
    dev = OwnClockDevice((1,), tr, grip_N=2.0, info=info)
    loop = ServoLoop(dev, RendererConfig(stiffness_N_m=680.0))
    prime = loop._prime

    def slow_prime(*args, **kwargs):
        prime(*args, **kwargs)
        for _ in range(100):             # 100 ms of the device's own clock pass before the first tick
            dev._step(0.0)

    loop._prime = slow_prime
    res = loop.run(duration_s=0.2)
    assert res.events and res.events[0].tick <= 2      # the tap at the first ticks
    assert res.events[0].incoming_velocity_m_s == pytest.approx(0.1, rel=0.2)
