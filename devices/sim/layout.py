"""Array layout of the simulated device's physics kernel, and its amplifier input rule: no numba.

``devices.sim.kernel`` (the compiled physics) and ``devices.sim.device`` (the Python side that builds
and reads the arrays) share these indices. They live apart from the kernel so that code which only
builds, reads or hands over the arrays (the device, the ahead-of-time compiled servo loop of
``renderer.sim_aot``) starts without importing numba (~0.3 s).

* ``s`` (float64, ``N_STATE``): physical state, filter states and outputs.
* ``p`` (float64, ``N_PARAM``): parameters, precomputed once per device,
  including the discretized LTI transmission matrices at ``P_LTI_MATS``.
* ``rs`` (uint64, 1): xorshift64* state of the sensor-noise generator.
"""

from __future__ import annotations

import math

# ---- state indices ----------------------------------------------------------
S_XM, S_VM, S_XD, S_VD, S_XH, S_VH = 0, 1, 2, 3, 4, 5
S_FL, S_FHAT, S_XLPREV = 6, 7, 8          # hysteresis: filtered force, coarse force, previous deflection
S_IAMP, S_ACCF, S_XB, S_VB = 9, 10, 11, 12
S_TEMP, S_CONTACT, S_AH, S_FCONTACT = 13, 14, 15, 16
S_XU, S_VU = 17, 18                          # desired hand position/velocity (last substep)
S_XA, S_VA = 19, 20                          # reactive hand only: hand/arm mass position/velocity
# reactive hand only: time since contact-force onset (s, < 0: none), held target (m), holding (0/1)
S_RFX_T, S_RFX_X, S_RFX_ON = 21, 22, 23
S_LTI = 24                                   # LTI transmission states start here
S_LTI_TMP = 44                               # scratch for the LTI state update
LTI_MAX_ORDER = 16
S_FM = 64                                    # samples: Maxwell-branch force of the viscoelastic foam (N)
S_EF = 65                                    # person: low-passed position error of the compensation (m)
S_XF, S_VF = 66, 67                          # person with a fingertip: fingertip position (m) and velocity (m/s)
N_STATE = 72

# ---- parameter indices ------------------------------------------------------
P_MODEL = 0            # 0 nonlinear, 1 lti
P_DT, P_NSUB, P_KF = 1, 2, 3
P_AMP_LOWPASS, P_AMP_ALPHA, P_IMAX = 4, 5, 6
P_MM, P_BM, P_CM, P_KC, P_BC, P_MD, P_BD, P_CD = 7, 8, 9, 10, 11, 12, 13, 14
P_KLP, P_KLN, P_FLP, P_FLN, P_GAMMA, P_BL, P_MH, P_HYST = 15, 16, 17, 18, 19, 20, 21, 22
P_KU_PER_N, P_BU_PER_N, P_VSTICK = 23, 24, 25
P_ACC_BETA, P_ACC_RES, P_ACC_NOISE, P_ACC_RANGE = 26, 27, 28, 29
P_GRIP_RES, P_GRIP_MAX, P_ENC_RES = 30, 31, 32
P_THERM_A, P_THERM_GAIN = 33, 34     # per-tick thermal decay and I^2 -> steady temperature gain
P_S_KIND, P_S_K, P_S_ALPHA, P_S_MB, P_S_KF, P_S_BF = 35, 36, 37, 38, 39, 40
P_MOTOR_ON = 41
P_TEMP_MAX = 43
P_LTI_N = 42
P_LTI_MATS = 48        # A (n*n), B (n), C (n), D (1), row-major
N_PARAM = 48 + 40 * 40
# reactive hand (devices.sim.hand.ReactiveHand); the LTI matrices end well before these
P_HAND_ON, P_HAND_MA, P_HAND_KM, P_HAND_BM = N_PARAM - 8, N_PARAM - 7, N_PARAM - 6, N_PARAM - 5
P_HAND_DELAY, P_HAND_FTHR, P_HAND_MTOOL = N_PARAM - 4, N_PARAM - 3, N_PARAM - 2
# person's low-frequency compensation (devices.sim.person.Person): gain N/m, low-pass factor per substep
P_HAND_KCOMP, P_HAND_CALPHA = N_PARAM - 9, N_PARAM - 10
# viscoelastic foam (standard linear solid): Maxwell-branch stiffness N/m and decay factor per substep
P_S_K1, P_S_MXDECAY = N_PARAM - 11, N_PARAM - 12
# person's internal model of the tool's drag: Coulomb friction (N) and viscous damping (N s/m) in handle space
P_HAND_CTOOL, P_HAND_BTOOL = N_PARAM - 13, N_PARAM - 14
# person's fingertip between the handle and the grip impedance (devices.sim.person.Person.fingertip_mass_kg;
# mass 0: none, the grip impedance acts on the handle itself): mass kg, contact stiffness N/m, damping N s/m
P_FT_MASS, P_FT_K, P_FT_B = N_PARAM - 15, N_PARAM - 16, N_PARAM - 17

# the device's Python-side state as a vector (SimDevice.fused_state / fused_sync), for compiled loops that
# stand in for SimDevice.command (renderer.law.run_sim, stimuli.hfam's taps on a wall)
(D_TICK, D_USER_TICK, D_HELD, D_LIMIT, D_PERIOD, D_REJECTED, D_LAST, D_STATUS, D_POS, D_ACC, D_GRIP,
 D_T) = range(12)
N_DEV = 12


STATUS_FAULT, STATUS_CLIPPING = 1, 8      # devices.base.Status.FAULT, CLIPPING
HOT_STATUS = 2                            # devices.base.Status.OVER_TEMPERATURE


def command_rule(current_A, limit_A):
    """The simulated amplifier's input rule (the safety of ``Device.command``): a NaN or infinite
    command becomes 0 (FAULT, counted as rejected), the rest is clamped to +/- ``limit_A`` (CLIPPING
    when at or beyond it). Plain Python for ``SimDevice.command``, compiled (:data:`command_rule_nb`)
    for the compiled servo loop: one rule for both.

    Returns
    -------
    current_A : float
    status : int
        Status bits.
    rejected : int
        1 if the command was rejected.
    """
    if current_A != current_A or current_A == math.inf or current_A == -math.inf:
        return 0.0, STATUS_FAULT, 1
    if current_A >= limit_A:
        return (limit_A if current_A > limit_A else current_A), STATUS_CLIPPING, 0
    if current_A <= -limit_A:
        return (-limit_A if current_A < -limit_A else current_A), STATUS_CLIPPING, 0
    return current_A, 0, 0
