"""numba kernel of the simulated teleoperation testbed (thesis chapter 5, section 4.3).

One call of :func:`run_session` advances master (sixth-order nonlinear joystick, eq. 3.32-3.35, or a
pure mass), simulated operator, slave joystick with tip force sensor, tip accelerometer and
environment, the controller (bilateral PD, PD + HFAM, position-force with the stabilisers of
section 5.4) and the CIMM induced-motion model (eq. 5.20) through a whole session, tick by tick at
the servo rate with internal substeps, writing one row of traces per tick. No allocation per tick.

Arrays: ``p`` (float64 parameters, indices ``P_*`` below), ``s`` (float64 state, ``S_*``),
``path`` (desired hand position per tick, m), ``stroke`` (tangential position along the texture per
tick, m), ``out`` (float64 (n_ticks, N_OUT) traces, columns ``O_*``).

A "chain" is one joystick in handle space: motor (m_m), cable (k_c, b_c), drum (m_d), hysteretic
linkage (section 3.5.3), handle (m_h), Coulomb friction at motor and drum (Karnopp). With its
``rigid`` flag set it is one pure mass (the conditions of section 5.3.1).
"""

from __future__ import annotations

import math

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from .kernel import _contact as _sample_contact
from .kernel import _friction, _xorshift_normal, hysteresis_step

# ---- chain parameter block (offsets inside a block of CP_N) ----
CP_MM, CP_BM, CP_CM, CP_KC, CP_BC, CP_MD, CP_BD, CP_CD = 0, 1, 2, 3, 4, 5, 6, 7
CP_KLP, CP_KLN, CP_FLP, CP_FLN, CP_GAM, CP_BL, CP_MH, CP_HYST, CP_RIGID, CP_VSTICK = 8, 9, 10, 11, 12, 13, 14, 15, 16, 17
CP_GAP = 18          # backlash: total free play of the cable transmission, motor to drum (m in handle space)
CP_N = 20
# ---- chain state block ----
CS_XM, CS_VM, CS_XD, CS_VD, CS_XH, CS_VH, CS_FL, CS_FHAT, CS_XLP, CS_AH = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
CS_N = 12

# parameter blocks
PB_MASTER, PB_SLAVE, PB_MODEL = 0, 20, 40
SB_MASTER, SB_SLAVE, SB_MODEL = 0, 12, 24
# scalar parameters
P_DT, P_NSUB, P_TICK = 60, 61, 62
P_KF_M, P_IMAX_M, P_KF_S, P_IMAX_S, P_ENC_M, P_ENC_S = 63, 64, 65, 66, 67, 68
# operator: grip between handle and hand (linear + quintic, damper), hand mass, muscle, compensation
P_KU, P_QU, P_BU, P_MA, P_KMUS, P_BMUS, P_COMP_W = 69, 70, 71, 72, 73, 74, 75
# model user (CIMM): linear + quintic stiffness, damper to ground
P_MKU, P_MQU, P_MBU, P_MDT_N, P_WASH_A = 76, 77, 78, 79, 80
# environment: kind 0 none, 1 Hunt-Crossley half-space, 2 block on foam; texture amplitude/wavelength
P_EKIND, P_EK, P_EALPHA, P_EMB, P_EKF, P_EBF, P_TEX_A, P_TEX_L = 81, 82, 83, 84, 85, 86, 87, 88
# sensors: force sensor low-pass alpha and noise, accelerometer alpha, noise, range
P_FS_A, P_FS_N, P_AC_A, P_AC_N, P_AC_R = 89, 90, 91, 92, 93
# controller
P_MODE, P_MU, P_LAM, P_KPS, P_KDS, P_KPM, P_KDM, P_VEL_A = 94, 95, 96, 97, 98, 99, 100, 101
P_BDAMP, P_KMU_A, P_KLAM_A, P_CIMM = 102, 103, 104, 105
P_HF_ON, P_HF_GAIN, P_HF_IMAX, P_HF_NSOS = 106, 107, 108, 109
P_DIV_POS, P_DIV_VEL = 110, 111
P_LINK_LOST_TICK = 112
P_PUSH, P_PUSH_TICK = 113, 114   # constant operator force on the master handle (N, up) from this tick on
P_MPD_A = 115        # bilateral PD: first-order low-pass (alpha) on the master PD force; 0 or 1 = off
P_FF_MAX = 116       # position-force: saturation of the force feedback F_f (N; 0 = none; Figure 5.10)
P_EK1, P_EMXDECAY = 117, 118   # environment: Maxwell branch stiffness (N/m) and exp(-dt/tau) (samples.py)
P_EDRUM = 119        # 1: the environment (force sensor) is struck by the slave's drum, 0: by its handle tip
P_FIR = 120          # 15 FIR taps (modified Bartlett-Hanning)
N_FIR = 15
P_SOS = 140          # up to 12 second-order sections (b0 b1 b2 a1 a2), HP first then inverse
MAX_SOS = 12
N_PARAM = P_SOS + 5 * MAX_SOS

# scalar state
S_HA_X, S_HA_V, S_COMP = 40, 41, 42           # operator hand/arm position, velocity, compensation offset
S_XB, S_VB = 43, 44                           # environment block (wood on foam)
S_FS, S_AS_F = 45, 46                         # force-sensor filter state, slave accelerometer filter
S_XM_PREV, S_XS_PREV, S_VM_EST, S_VS_EST = 47, 48, 49, 50
S_XC, S_XC_PREV, S_KMU, S_KLAM = 51, 52, 53, 54
S_FF, S_FS_CMD = 55, 56                       # force applied at master / slave motor during the period
S_WASH_Y, S_WASH_X = 57, 58
S_CLIP_M, S_CLIP_S, S_CLIP_HF, S_NAN = 59, 60, 61, 62
S_CONTACT, S_LINK_HOLD = 63, 64
S_MPD = 65                                    # low-passed master PD force
S_FMX = 66                                    # environment: Maxwell-branch force (N)
S_FIRBUF = 70                                 # 15 samples, circular
S_FIRIDX = 86
S_SOSZ = 90                                   # 2 per section
N_STATE = 128

# output columns
(O_T, O_XM, O_XS, O_XC, O_FE, O_FF, O_XHAT, O_AM, O_AS, O_IM, O_IS, O_CONTACT, O_XTIP, O_XPATH,
 O_IHF, O_FE_TRUE, O_XM_TRUE) = range(17)
N_OUT = 17

MODE_PD, MODE_PF = 0, 1

FAULT_NONE, FAULT_NAN, FAULT_DIVERGED = 0, 1, 2


@njit(cache=True, _nrt=False, inline="always")
def _chain_substep(s, sb, p, pb, f_motor, f_handle_ext, f_drum_ext, dt):
    """One semi-implicit Euler substep of a joystick chain (eq. 3.32-3.35); returns the handle acceleration.

    With ``CP_GAP`` > 0 the cable transmission has backlash (Figure 5.11's condition): its spring and damper
    act only once the motor-drum offset leaves the free play of +/- gap/2.

    Parameters
    ----------
    s, sb : state array and the chain's state block offset.
    p, pb : parameter array and the chain's parameter block offset.
    f_motor : float
        Force at the motor in handle space (N, up).
    f_handle_ext : float
        External force on the handle: user plus contact (N, up).
    f_drum_ext : float
        External force on the drum: contact with a sensor beneath the front transmission element (N, up).
    dt : float
        Substep (s).
    """
    if p[pb + CP_RIGID] != 0.0:
        m = p[pb + CP_MM] + p[pb + CP_MD] + p[pb + CP_MH]
        a = (f_motor + f_handle_ext + f_drum_ext - p[pb + CP_BM] * s[sb + CS_VM]) / m
        v = s[sb + CS_VM] + a * dt
        x = s[sb + CS_XM] + v * dt
        s[sb + CS_VM] = v
        s[sb + CS_VD] = v
        s[sb + CS_VH] = v
        s[sb + CS_XM] = x
        s[sb + CS_XD] = x
        s[sb + CS_XH] = x
        s[sb + CS_AH] = a
        return a
    xm, vm, xd, vd, xh, vh = s[sb], s[sb + 1], s[sb + 2], s[sb + 3], s[sb + 4], s[sb + 5]
    xl = xd - xh
    if p[pb + CP_HYST] != 0.0:
        fl, fhat = hysteresis_step(xl, s[sb + CS_XLP], s[sb + CS_FL], s[sb + CS_FHAT], p[pb + CP_FLP],
                                   p[pb + CP_KLP], p[pb + CP_FLN], p[pb + CP_KLN], p[pb + CP_GAM])
        s[sb + CS_FHAT] = fhat
    else:
        fl = 0.5 * (p[pb + CP_KLP] + p[pb + CP_KLN]) * xl
    s[sb + CS_FL] = fl
    s[sb + CS_XLP] = xl
    flt = fl + p[pb + CP_BL] * (vd - vh)
    dc = xd - xm
    half_gap = 0.5 * p[pb + CP_GAP]
    if half_gap > 0.0:
        # backlash: the cable is slack inside the free play, engaged (spring and damper) beyond it
        if dc > half_gap:
            fc = p[pb + CP_KC] * (dc - half_gap) + p[pb + CP_BC] * (vd - vm)
        elif dc < -half_gap:
            fc = p[pb + CP_KC] * (dc + half_gap) + p[pb + CP_BC] * (vd - vm)
        else:
            fc = 0.0
    else:
        fc = p[pb + CP_KC] * dc + p[pb + CP_BC] * (vd - vm)
    fm = fc + f_motor - p[pb + CP_BM] * vm
    fd = -fc - p[pb + CP_BD] * vd - flt + f_drum_ext
    vst = p[pb + CP_VSTICK]
    cmf, stm = _friction(vm, fm, p[pb + CP_CM], vst)
    cdf, std = _friction(vd, fd, p[pb + CP_CD], vst)
    ah = (flt + f_handle_ext) / p[pb + CP_MH]
    vm = 0.0 if stm else vm + (fm + cmf) / p[pb + CP_MM] * dt
    vd = 0.0 if std else vd + (fd + cdf) / p[pb + CP_MD] * dt
    vh += ah * dt
    s[sb], s[sb + 1], s[sb + 2], s[sb + 3] = xm + vm * dt, vm, xd + vd * dt, vd
    s[sb + 4], s[sb + 5] = xh + vh * dt, vh
    s[sb + CS_AH] = ah
    return ah


@njit(cache=True, _nrt=False, inline="always")
def _grip_force(p, ik, iq, ib, x_rel, v_rel):
    """Linear + quintic user stiffness and damper (section 5.7.1): force on the handle (N)."""
    return -(p[ik] * x_rel + p[iq] * x_rel ** 5) - p[ib] * v_rel


@njit(cache=True, _nrt=False)
def run_session(p, s, rs, path, stroke, out, k0, k1, master_ext):
    """Run ticks ``k0 .. k1-1`` of a teleoperation session; returns (fault code, tick of the fault or -1).

    Controller (per tick, after reading the sensors at t_k; the commands are applied during the
    next period, zero-order hold):

    * ``P_MODE = 0`` bilateral PD (position-position): slave force kp_s (x_c - x_s) + kd_s (v_c - v_s)
      with x_c = K_mu(mu x_m) (K_mu optional, as for position-force); master force kp_m (x_s/mu - x_m)
      + kd_m (v_s/mu - v_m), optionally low-passed (``P_MPD_A``, first order); plus the HFAM
      current (section 4.3.1, eq. 4.4-4.5) when ``P_HF_ON``: tip acceleration -> 15-point FIR ->
      cascade of second-order sections (22 Hz high-pass, then the discretised inverse of H_ha) ->
      its own saturation.
    * ``P_MODE = 1`` position-force (section 5.1): F_f = K_lambda(lambda F_e) - b v_m (eq. 5.9, 5.11),
      x_c = K_mu(mu (x_m - x_hat_mi,hf)) (eq. 5.10, 5.20) with the CIMM model (sections 5.5-5.7)
      advanced by the force applied at the master motor when ``P_CIMM``.

    Parameters
    ----------
    p, s : float64 arrays (N_PARAM,), (N_STATE,)
    rs : uint64 array (1,)
        Sensor-noise generator state (xorshift64*).
    path, stroke : float64 arrays (n_ticks,)
        Desired operator hand position (m) and tangential texture coordinate (m) per tick.
    out : float64 array (n_ticks, N_OUT)
        Traces, one row per tick (see ``O_*``).
    k0, k1 : int
        Tick range.
    master_ext : int
        1 if the master is external (its rows O_XM/O_AM are supplied in ``out`` by the caller and the
        simulated master is not advanced), 0 for the simulated master.

    Returns
    -------
    fault : int
        0 none, 1 NaN in a sensor or command, 2 divergence (|x_s - x_c| or a speed beyond its limit).
        On a fault both motor commands are zero from that tick on and the run stops.
    tick : int
    """
    dt = p[P_DT]
    nsub = int(p[P_NSUB])
    T = p[P_TICK]
    mdt_n = int(p[P_MDT_N])
    kfm, kfs = p[P_KF_M], p[P_KF_S]
    mu, lam = p[P_MU], p[P_LAM]
    mode = p[P_MODE]
    for k in range(k0, k1):
        t = k * T
        # ---------------- sensors at t_k ----------------
        if master_ext != 0:
            xm_meas = out[k, O_XM]
        elif math.isfinite(s[SB_MASTER + CS_XM]):
            xm_meas = p[P_ENC_M] * math.floor(s[SB_MASTER + CS_XM] / p[P_ENC_M])
        else:
            xm_meas = math.nan
        if math.isfinite(s[SB_SLAVE + CS_XM]):
            xs_meas = p[P_ENC_S] * math.floor(s[SB_SLAVE + CS_XM] / p[P_ENC_S])
        else:
            xs_meas = math.nan
        fe = s[S_FS] + p[P_FS_N] * _xorshift_normal(rs)
        a_s = s[S_AS_F] + p[P_AC_N] * _xorshift_normal(rs)
        if a_s > p[P_AC_R]:
            a_s = p[P_AC_R]
        elif a_s < -p[P_AC_R]:
            a_s = -p[P_AC_R]
        # velocity estimates: backward difference, first-order low-pass
        va = p[P_VEL_A]
        if k == k0 and k0 == 0:
            s[S_XM_PREV] = xm_meas
            s[S_XS_PREV] = xs_meas
        s[S_VM_EST] += va * ((xm_meas - s[S_XM_PREV]) / T - s[S_VM_EST])
        s[S_VS_EST] += va * ((xs_meas - s[S_XS_PREV]) / T - s[S_VS_EST])
        s[S_XM_PREV] = xm_meas
        s[S_XS_PREV] = xs_meas
        vm_est, vs_est = s[S_VM_EST], s[S_VS_EST]
        xhat = s[SB_MODEL + CS_XM] if p[P_CIMM] != 0.0 else 0.0
        if p[P_WASH_A] > 0.0 and p[P_CIMM] != 0.0:
            # first-order high-pass (washout) of the model output: underestimates low-frequency motion
            y = p[P_WASH_A] * (s[S_WASH_Y] + xhat - s[S_WASH_X])
            s[S_WASH_X] = xhat
            s[S_WASH_Y] = y
            xhat = y
        # ---------------- controller ----------------
        link_lost = p[P_LINK_LOST_TICK] >= 0.0 and k >= p[P_LINK_LOST_TICK]
        if link_lost:
            if s[S_LINK_HOLD] == 0.0:
                s[S_LINK_HOLD] = 1.0
                s[S_XC] = xs_meas
            xc = s[S_XC]
            vc = 0.0
        else:
            xc_raw = mu * (xm_meas - xhat)
            if p[P_KMU_A] < 1.0:
                s[S_KMU] += p[P_KMU_A] * (xc_raw - s[S_KMU])
                xc_raw = s[S_KMU]
            elif k == k0 and k0 == 0:
                s[S_KMU] = xc_raw
            xc = xc_raw
            vc = (xc - s[S_XC]) / T if k > 0 else 0.0
            s[S_XC] = xc
        # slave PD on the motor position
        f_s = p[P_KPS] * (xc - xs_meas) + p[P_KDS] * (vc - vs_est)
        ihf = 0.0
        if mode == 0.0:
            f_m = p[P_KPM] * (xs_meas / mu - xm_meas) + p[P_KDM] * (vs_est / mu - vm_est)
            if 0.0 < p[P_MPD_A] < 1.0:
                # PD as the low-frequency power band only (Figure 4.2): above its corner the HFAM channel
                # owns the master, and the PD does not pull back the handle motion HFAM creates
                if k == k0 and k0 == 0:
                    s[S_MPD] = f_m
                s[S_MPD] += p[P_MPD_A] * (f_m - s[S_MPD])
                f_m = s[S_MPD]
            if p[P_HF_ON] != 0.0:
                # 15-point modified Bartlett-Hanning smoothing (circular buffer)
                idx = int(s[S_FIRIDX])
                s[S_FIRBUF + idx] = a_s
                acc = 0.0
                for j in range(N_FIR):
                    acc += p[P_FIR + j] * s[S_FIRBUF + (idx - j) % N_FIR]
                s[S_FIRIDX] = (idx + 1) % N_FIR
                x = acc
                for q in range(int(p[P_HF_NSOS])):
                    b0, b1, b2 = p[P_SOS + 5 * q], p[P_SOS + 5 * q + 1], p[P_SOS + 5 * q + 2]
                    a1, a2 = p[P_SOS + 5 * q + 3], p[P_SOS + 5 * q + 4]
                    z0, z1 = s[S_SOSZ + 2 * q], s[S_SOSZ + 2 * q + 1]
                    y = b0 * x + z0
                    s[S_SOSZ + 2 * q] = b1 * x - a1 * y + z1
                    s[S_SOSZ + 2 * q + 1] = b2 * x - a2 * y
                    x = y
                ihf = p[P_HF_GAIN] * x
                if ihf > p[P_HF_IMAX]:
                    ihf = p[P_HF_IMAX]
                    s[S_CLIP_HF] += 1.0
                elif ihf < -p[P_HF_IMAX]:
                    ihf = -p[P_HF_IMAX]
                    s[S_CLIP_HF] += 1.0
        else:
            ff = lam * fe
            if p[P_KLAM_A] < 1.0:
                s[S_KLAM] += p[P_KLAM_A] * (ff - s[S_KLAM])
                ff = s[S_KLAM]
            if p[P_FF_MAX] > 0.0:
                # the force-feedback saturation of Figure 5.10 ("the saturated force feedback signal")
                if ff > p[P_FF_MAX]:
                    ff = p[P_FF_MAX]
                elif ff < -p[P_FF_MAX]:
                    ff = -p[P_FF_MAX]
            f_m = ff - p[P_BDAMP] * vm_est
        if link_lost:
            f_m = 0.0
            ihf = 0.0
        # ---------------- safety: NaN, divergence, saturation ----------------
        fault = 0
        if not (math.isfinite(f_m) and math.isfinite(f_s) and math.isfinite(ihf) and math.isfinite(xm_meas)
                and math.isfinite(xs_meas) and math.isfinite(fe)):
            fault = FAULT_NAN
            s[S_NAN] += 1.0
        elif abs(xs_meas - xc) > p[P_DIV_POS] or abs(vs_est) > p[P_DIV_VEL] or abs(vm_est) > p[P_DIV_VEL]:
            fault = FAULT_DIVERGED
        if fault != 0:
            s[S_FF] = 0.0
            s[S_FS_CMD] = 0.0
            out[k, O_T] = t
            out[k, O_IM] = 0.0
            out[k, O_IS] = 0.0
            return fault, k
        i_m = f_m / kfm + ihf
        if i_m > p[P_IMAX_M]:
            i_m = p[P_IMAX_M]
            s[S_CLIP_M] += 1.0
        elif i_m < -p[P_IMAX_M]:
            i_m = -p[P_IMAX_M]
            s[S_CLIP_M] += 1.0
        i_s = f_s / kfs
        if i_s > p[P_IMAX_S]:
            i_s = p[P_IMAX_S]
            s[S_CLIP_S] += 1.0
        elif i_s < -p[P_IMAX_S]:
            i_s = -p[P_IMAX_S]
            s[S_CLIP_S] += 1.0
        fm_applied = i_m * kfm
        fs_applied = i_s * kfs
        # ---------------- outputs at t_k ----------------
        out[k, O_T] = t
        out[k, O_XM] = xm_meas
        out[k, O_XS] = xs_meas
        out[k, O_XC] = xc
        out[k, O_FE] = fe
        out[k, O_FF] = fm_applied if mode == 1.0 else fm_applied
        out[k, O_XHAT] = xhat
        if master_ext == 0:
            out[k, O_AM] = s[SB_MASTER + CS_AH]
        out[k, O_AS] = a_s
        out[k, O_IM] = i_m
        out[k, O_IS] = i_s
        out[k, O_XTIP] = s[SB_SLAVE + CS_XH]
        out[k, O_XPATH] = path[k]
        out[k, O_IHF] = ihf
        out[k, O_FE_TRUE] = s[S_FS]
        out[k, O_XM_TRUE] = s[SB_MASTER + CS_XM]
        # ---------------- physics over the period ----------------
        xu0 = path[k]
        xu1 = path[k + 1] if k + 1 < path.shape[0] else path[k]
        vu = (xu1 - xu0) / T
        surf = 0.0
        if p[P_TEX_A] > 0.0:
            y = stroke[k]
            surf = p[P_TEX_A] * (0.5 - 0.5 * math.cos(2.0 * math.pi * y / p[P_TEX_L]))
        push = p[P_PUSH] if k >= p[P_PUSH_TICK] else 0.0
        contact = 0.0
        fc_sum = 0.0
        ah_sum = 0.0
        for j in range(nsub):
            xu = xu0 + (xu1 - xu0) * (j + 1) / nsub
            # operator: hand/arm mass behind the grip, muscle to the compensated target
            if master_ext == 0:
                xh, vh = s[SB_MASTER + CS_XH], s[SB_MASTER + CS_VH]
                if p[P_MA] > 0.0:
                    fu = _grip_force(p, P_KU, P_QU, P_BU, xh - s[S_HA_X], vh - s[S_HA_V])
                    xt = xu + s[S_COMP]
                    fa = -fu + p[P_KMUS] * (xt - s[S_HA_X]) + p[P_BMUS] * (vu - s[S_HA_V])
                    s[S_HA_V] += fa / p[P_MA] * dt
                    s[S_HA_X] += s[S_HA_V] * dt
                    # active compensation of low-frequency deflection (integral, ~P_COMP_W rad/s)
                    s[S_COMP] += p[P_COMP_W] * (xu - xh) * dt
                else:
                    fu = _grip_force(p, P_KU, P_QU, P_BU, xh - xu, vh - vu)
                _chain_substep(s, SB_MASTER, p, PB_MASTER, fm_applied, fu + push, 0.0, dt)
            # slave + environment
            # the environment: the virtual environment's sample contact (devices.sim.kernel._contact, one
            # definition of wood, wood on foam and foam), struck by the slave's handle tip or its drum
            if p[P_EDRUM] != 0.0:
                xq, vq = s[SB_SLAVE + CS_XD], s[SB_SLAVE + CS_VD]
            else:
                xq, vq = s[SB_SLAVE + CS_XH], s[SB_SLAVE + CS_VH]
            fe_true, ab, _flag, s[S_FMX] = _sample_contact(p[P_EKIND], p[P_EK], p[P_EALPHA], p[P_EMB], p[P_EKF],
                                                           p[P_EBF], p[P_EK1], p[P_EMXDECAY], dt, xq - surf, vq,
                                                           s[S_XB], s[S_VB], s[S_FMX])
            if fe_true > 0.0:
                contact = 1.0
            fc_sum += fe_true
            if p[P_EDRUM] != 0.0:
                ah = _chain_substep(s, SB_SLAVE, p, PB_SLAVE, fs_applied, 0.0, fe_true, dt)
            else:
                ah = _chain_substep(s, SB_SLAVE, p, PB_SLAVE, fs_applied, fe_true, 0.0, dt)
            ah_sum += ah
            if p[P_EKIND] == 2.0:
                s[S_VB] += ab * dt
                s[S_XB] += s[S_VB] * dt
            # sensors: force-sensor and accelerometer low-pass
            s[S_FS] += p[P_FS_A] * (fe_true - s[S_FS])
            s[S_AS_F] += p[P_AC_A] * (ah - s[S_AS_F])
            # CIMM model: user (linear + quintic, damper) to ground, driven by the applied force
            if p[P_CIMM] != 0.0 and (j + 1) % mdt_n == 0:
                mdt = dt * mdt_n
                fum = _grip_force(p, P_MKU, P_MQU, P_MBU, s[SB_MODEL + CS_XH], s[SB_MODEL + CS_VH])
                _chain_substep(s, SB_MODEL, p, PB_MODEL, fm_applied, fum, 0.0, mdt)
        s[S_CONTACT] = contact
        out[k, O_CONTACT] = contact
    return 0, -1


@njit(cache=True, _nrt=False)
def cimm_model_run(p, s, force_N, out_x):
    """Advance only the CIMM induced-motion model (sections 5.6-5.7) one servo tick per input sample.

    Parameters
    ----------
    p, s : float64 arrays (N_PARAM,), (N_STATE,)
        Packed with a CIMM model (``Testbed.pack(cimm)``); only the model block is touched.
    force_N : float64 array (n,)
        Force applied at the master motor during each tick (N).
    out_x : float64 array (n,)
        Model motor position x_hat_mi,hf at the end of each tick (m).
    """
    nsub = int(p[P_NSUB])
    mdt_n = int(p[P_MDT_N])
    mdt = p[P_DT] * mdt_n
    for k in range(force_N.shape[0]):
        for j in range(nsub // mdt_n):
            fum = _grip_force(p, P_MKU, P_MQU, P_MBU, s[SB_MODEL + CS_XH], s[SB_MODEL + CS_VH])
            _chain_substep(s, SB_MODEL, p, PB_MODEL, force_N[k], fum, 0.0, mdt)
        out_x[k] = s[SB_MODEL + CS_XM]
