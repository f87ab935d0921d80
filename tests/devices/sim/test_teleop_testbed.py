"""The teleoperation testbed's plant (issue 37): backlash in the cable transmission, and the environments
shared with the virtual environment (``devices.sim.samples``)."""

from __future__ import annotations

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.samples import get_sample
from devices.sim.teleop import BACKLASH_FIG_5_11_M, ENVIRONMENTS, Environment, chain_block, environment_from_sample


def test_backlash_is_free_play_between_motor_and_drum():
    """The cable engages only after the motor has crossed half the free play (kernel level)."""
    P = default_params()
    p = np.zeros(K.N_PARAM)
    gap = BACKLASH_FIG_5_11_M
    p[K.PB_SLAVE:K.PB_SLAVE + K.CP_N] = chain_block(P, backlash_m=gap)
    s = np.zeros(K.N_STATE)
    dt, f = 1e-5, 0.5                     # 0.5 N on the motor alone (10.75 g): 0.05 mm in ~0.5 ms
    xm, xd = [], []
    for _ in range(200):
        K._chain_substep(s, K.SB_SLAVE, p, K.PB_SLAVE, f, 0.0, 0.0, dt)
        xm.append(s[K.SB_SLAVE + K.CS_XM])
        xd.append(s[K.SB_SLAVE + K.CS_XD])
    xm, xd = np.array(xm), np.array(xd)
    inside = xm < 0.5 * gap - 1e-6
    assert inside.sum() > 10 and np.all(np.abs(xd[inside]) < 1e-9)   # drum untouched inside the play
    assert xd[-1] > 1e-6                                             # then the cable drags it along
    p2 = p.copy()
    p2[K.PB_SLAVE + K.CP_GAP] = 0.0
    s2 = np.zeros(K.N_STATE)
    for _ in range(20):
        K._chain_substep(s2, K.SB_SLAVE, p2, K.PB_SLAVE, f, 0.0, 0.0, dt)
    assert s2[K.SB_SLAVE + K.CS_XD] > 0.0                           # without backlash at once


def test_environments_are_the_virtual_environments_samples():
    """One definition of wood, wood on foam and foam: the teleoperation environment is built from
    devices.sim.samples (and its contact is devices.sim.kernel._contact, the virtual environment's)."""
    for name in ("wood", "wood_on_foam", "foam"):
        e, s = ENVIRONMENTS[name], get_sample(name)
        assert (e.kind, e.k_N_m, e.alpha_s_m, e.maxwell_k_N_m, e.maxwell_tau_s) == (
            s.kind, s.contact_k_N_m, s.contact_alpha_s_m, s.maxwell_k_N_m, s.maxwell_tau_s), name
        assert e.source.startswith("devices.sim.samples")
    wf, s = ENVIRONMENTS["wood_on_foam"], get_sample("wood_on_foam")
    assert (wf.block_mass_kg, wf.foam_k_N_m, wf.foam_b_Ns_m) == (s.block_mass_kg, s.foam_k_N_m, s.foam_b_Ns_m)
    assert ENVIRONMENTS["texture"].k_N_m == get_sample("wood").contact_k_N_m


def test_environment_validation_names_the_field():
    with pytest.raises(ValueError, match="struck_by"):
        Environment("x", 1, 1e5, 1.0, struck_by="handle")
    with pytest.raises(ValueError, match="no contact"):
        environment_from_sample(get_sample("placeholder"))
