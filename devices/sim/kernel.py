"""numba physics kernel of the simulated device: one call advances one servo period.

Layout of the arrays shared with :mod:`devices.sim.device` (indices below):

* ``s`` (float64, ``N_STATE``): physical state, filter states and outputs.
* ``p`` (float64, ``N_PARAM``): parameters, precomputed once per device,
  including the discretized LTI transmission matrices at ``P_LTI_MATS``.
* ``rs`` (uint64, 1): xorshift64* state of the sensor-noise generator, so
  every device owns a seedable, reproducible noise stream.

Integration is semi-implicit (symplectic) Euler at the fixed substep
``p[P_DT]`` (<= 40 us): forces from the current state, then velocities, then
positions. It preserves oscillation frequencies to O((w*dt)^2) and stays
stable for the stiff cable/contact springs at these steps.

Coulomb friction (eq. 3.35) uses Karnopp's stick-slip model: a mass whose
speed is inside the stick band ``p[P_VSTICK]`` and whose other applied force
is within the Coulomb level is held (velocity set to zero, friction cancels
the applied force); otherwise friction is ``-c*sign(v)`` (or opposes the
applied force inside the band). This avoids the chatter a bare ``sign(v)``
produces at zero velocity.

The kernels use numba's ``error_model="numpy"``: every divisor here is a
validated positive parameter (masses, resolutions, time steps, gamma) or
``1 + |...|``, so no division by zero occurs; the default (Python) model
only tested each divisor for zero to raise ``ZeroDivisionError``, which
kept those branches in the substep loop (measured: a tenth of a servo
period's CPU; the same results bit for bit).
"""

from __future__ import annotations

import math

import numpy as np
from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

# the arrays' layout and the amplifier's input rule (numba-free, shared with devices.sim.device)
from .layout import *  # noqa: F401,F403 -- re-exported: kernel.P_*, kernel.S_*, kernel.command_rule


@njit(cache=True, _nrt=False, inline="always", error_model="numpy")
def hysteresis_step(x, x_prev, f_prev, fhat_prev, f_p, k_p, f_n, k_n, gamma):
    """One update of the rate-independent hysteretic spring (thesis section 3.5.3).

    Coarse force (eq. 3.22) with the convergence offsets g_p = k_p/gamma and
    g_n = -k_n/gamma (eq. 3.30-3.31), smoothed by the spatial first-order
    filter of eq. 3.24 with X = |x_i - x_{i-1}| (eq. 3.25).

    Parameters
    ----------
    x, x_prev : float
        Deflection now and at the previous update (m).
    f_prev, fhat_prev : float
        Filtered and coarse force at the previous update (N).
    f_p, k_p, f_n, k_n : float
        Asymptotes f_p + k_p*x (increasing) and f_n + k_n*x (decreasing), N and N/m.
    gamma : float
        Spatial filter bandwidth (rad/m).

    Returns
    -------
    f, fhat : float
        Filtered force (the element's output) and coarse force, N.
    """
    if x > x_prev:
        fhat = f_p + k_p * x + k_p / gamma
    elif x < x_prev:
        fhat = f_n + k_n * x - k_n / gamma
    else:
        fhat = fhat_prev
    gx = gamma * abs(x - x_prev)
    f = (gx * fhat + f_prev) / (1.0 + gx)
    return f, fhat


@njit(cache=True, _nrt=False, inline="always", error_model="numpy")
def _friction(v, f_other, c, vstick):
    """Karnopp stick-slip Coulomb friction (eq. 3.35 without chatter).

    Returns (friction force N, stuck flag)."""
    if c <= 0.0:
        return 0.0, False
    if abs(v) < vstick:
        if abs(f_other) <= c:
            return -f_other, True
        return (-c if f_other > 0.0 else c), False
    return (-c if v > 0.0 else c), False


@njit(cache=True, _nrt=False, inline="always", error_model="numpy")
def _contact(kind, sk, salpha, smb, skf, sbf, sk1, mxdecay, dt, xh, vh, xb, vb, fm):
    """Sample contact (thesis Table 4.1 samples): Hunt-Crossley contact, standard-linear-solid foam.

    ``kind`` 1 (half-space): ``F = k d (1 + alpha d') + f_m`` with the Maxwell
    branch ``f_m' = k_1 d' - f_m / tau`` (d: penetration); ``kind`` 2 (block
    on foam): the handle hits the block through the Hunt-Crossley contact and
    the block rests on the foam ``k_f c + b_f c' + f_m`` (c: compression,
    same Maxwell branch). ``mxdecay = exp(-dt/tau)``. Contact forces never pull.

    Returns (force on the handle N (up), block acceleration m/s^2, in-contact 0/1, new f_m N).
    """
    if kind == 1.0:
        d = -xh
        if d > 0.0:
            fm = (fm + sk1 * (-vh) * dt) * mxdecay
            f = sk * d * (1.0 + salpha * (-vh)) + fm
            return (f if f > 0.0 else 0.0), 0.0, 1.0, fm
        return 0.0, 0.0, 0.0, fm * mxdecay
    if kind == 2.0:
        d = xb - xh
        f = 0.0
        flag = 0.0
        if d > 0.0:
            f = sk * d * (1.0 + salpha * (vb - vh))
            if f < 0.0:
                f = 0.0
            flag = 1.0
        fm = (fm + sk1 * (-vb) * dt) * mxdecay
        return f, (-f - skf * xb - sbf * vb + fm) / smb, flag, fm
    return 0.0, 0.0, 0.0, fm


@njit(cache=True, _nrt=False, inline="always", error_model="numpy")
def _reactive_hand_step(xh, vh, xu, vu, au, ku, bu, xa, va, rt, rx, ron, ma, km, bmu, rdelay, fthr, mtool, dt,
                        ef, kcomp, calpha, ctool, btool):
    """One substep of the person (:class:`devices.sim.person.Person`; also the older ``ReactiveHand``).

    The grip spring-damper (k_u, b_u of eq. 3.34) couples the handle to a hand
    mass ``ma`` instead of to the desired trajectory; the hand mass is driven
    towards its target by the muscle impedance (``km``, ``bmu``) plus the
    feedforward ``(ma + mtool) * a_t`` (an internal model of the free-motion
    dynamics of arm and tool). Contact reflex: once the force the handle
    pushes up on the hand exceeds ``fthr`` while the target is not
    accelerating, after ``rdelay`` seconds the target stops descending (holds
    where it is) until the desired trajectory rises above it.

    Low-frequency compensation (section 5.6.2): the error to the target,
    low-passed (``ef += calpha * (xt - xa - ef)``), pushes back with ``kcomp``.

    Returns (force of the hand on the handle N, xa, va, rt, rx, ron, ef).
    """
    fu = -ku * (xh - xa) - bu * (vh - va)
    # target: the desired trajectory, or the held position after the reflex
    xt, vt, at = xu, vu, au
    if ron != 0.0:
        if xu > rx:
            ron = 0.0
            rt = -1.0
        else:
            xt, vt, at = rx, 0.0, 0.0
    if rt >= 0.0:
        rt += dt
        if ron == 0.0 and rt >= rdelay:
            # stop pushing: the target holds where the hand is (not where the plan had got to)
            ron = 1.0
            rx = xa if xa > xu else xu
            xt, vt, at = rx, 0.0, 0.0
    elif ron == 0.0 and abs(at) < 0.1 and -fu > fthr:
        # armed only while the target is not accelerating: the reaching motion's own
        # tool-drag (m_tool * a_t plus the grip lag) is expected, not a contact
        rt = 0.0
    ef += calpha * (xt - xa - ef)
    # the internal model plans free motion only: below the surface (height 0) the person leaves the
    # braking to the surface and the reflex, no voluntary feedforward
    ff = 0.0
    if xt >= 0.0:
        ff = (ma + mtool) * at + btool * vt
        if vt > 0.0:
            ff += ctool
        elif vt < 0.0:
            ff -= ctool
    fa = -fu + km * (xt - xa) + bmu * (vt - va) + kcomp * ef + ff
    va += fa / ma * dt
    xa += va * dt
    return fu, xa, va, rt, rx, ron, ef


@njit(cache=True, _nrt=False, inline="always", error_model="numpy")
def _xorshift_uniform(rs):
    """Uniform sample in (0, 1] from the xorshift64* stream in ``rs[0]``."""
    x = rs[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    rs[0] = x
    r = x * np.uint64(2685821657736338717)
    return ((r >> np.uint64(11)) + np.uint64(1)) * (1.0 / 9007199254740993.0)


@njit(cache=True, _nrt=False, error_model="numpy")
def _xorshift_normal(rs):
    """Standard normal sample from the xorshift64* stream in ``rs[0]`` (Box-Muller)."""
    u1 = _xorshift_uniform(rs)
    u2 = _xorshift_uniform(rs)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True, _nrt=False, error_model="numpy")
def _substeps_nonlinear(s, p, xu0, xu1, au, g, i_cmd):
    """All substeps of one servo period of eq. 3.32-3.35; state kept in locals (no aliasing reloads).

    With ``p[P_HAND_ON]`` set, the grip spring-damper ties the handle to the reactive hand
    (:func:`_reactive_hand_step`, fed the desired acceleration ``au``) instead of to the desired
    trajectory itself (eq. 3.34); the branch is taken the same way every substep, so it costs the
    default hand nothing measurable.
    """
    dt = p[P_DT]
    nsub = int(p[P_NSUB])
    vu = (xu1 - xu0) / (dt * nsub)
    ku = p[P_KU_PER_N] * g
    bu = p[P_BU_PER_N] * g
    kf = p[P_KF]
    lowpass = p[P_AMP_LOWPASS] != 0.0
    alpha = p[P_AMP_ALPHA]
    beta = p[P_ACC_BETA]
    mm, bm, cm, kc, bc = p[P_MM], p[P_BM], p[P_CM], p[P_KC], p[P_BC]
    md, bd, cd, bl, mh = p[P_MD], p[P_BD], p[P_CD], p[P_BL], p[P_MH]
    klp, kln, flp, fln, gam = p[P_KLP], p[P_KLN], p[P_FLP], p[P_FLN], p[P_GAMMA]
    hyst = p[P_HYST] != 0.0
    kmean = 0.5 * (klp + kln)
    vstick = p[P_VSTICK]
    kind, sk, salpha, smb, skf, sbf = p[P_S_KIND], p[P_S_K], p[P_S_ALPHA], p[P_S_MB], p[P_S_KF], p[P_S_BF]
    sk1, mxdecay, fmx = p[P_S_K1], p[P_S_MXDECAY], s[S_FM]
    inv_mm, inv_md, inv_mh = 1.0 / mm, 1.0 / md, 1.0 / mh
    xm, vm, xd, vd, xh, vh = s[S_XM], s[S_VM], s[S_XD], s[S_VD], s[S_XH], s[S_VH]
    fl, fhat, xlp = s[S_FL], s[S_FHAT], s[S_XLPREV]
    reactive = p[P_HAND_ON] != 0.0
    ma, km, bmu, rdelay, fthr = p[P_HAND_MA], p[P_HAND_KM], p[P_HAND_BM], p[P_HAND_DELAY], p[P_HAND_FTHR]
    mtool = p[P_HAND_MTOOL]
    xa, va, rt, rx, ron = s[S_XA], s[S_VA], s[S_RFX_T], s[S_RFX_X], s[S_RFX_ON]
    ef, kcomp, calpha = s[S_EF], p[P_HAND_KCOMP], p[P_HAND_CALPHA]
    ctool, btool = p[P_HAND_CTOOL], p[P_HAND_BTOOL]
    iamp, accf, xb, vb = s[S_IAMP], s[S_ACCF], s[S_XB], s[S_VB]
    # the person's fingertip (Person.fingertip_mass_kg > 0): handle -[contact k_f, b_f]- fingertip -[grip
    # impedance k_u(g), b_u(g)]- hand; without one the grip impedance acts on the handle itself (eq. 3.34)
    # (handle and fingertip move together at the fingertip's rest: xf = xh, vf = vh at every set_user)
    mf = p[P_FT_MASS]
    # a hand that does not hold the handle (grip 0, section 3.5.2) does not touch it either
    finger = reactive and mf > 0.0 and g > 0.0
    kft, bft = p[P_FT_K], p[P_FT_B]
    inv_mf = 1.0 / mf if finger else 0.0
    xf, vf = s[S_XF], s[S_VF]
    ah = 0.0
    fs = 0.0
    contact_any = 0.0
    dxu = (xu1 - xu0) / nsub
    for j in range(nsub):
        xu = xu0 + dxu * (j + 1)
        if lowpass:
            iamp += alpha * (i_cmd - iamp)
        else:
            iamp = i_cmd
        fs, ab, flag, fmx = _contact(kind, sk, salpha, smb, skf, sbf, sk1, mxdecay, dt, xh, vh, xb, vb, fmx)
        if flag > 0.0:
            contact_any = 1.0
        if finger:
            # the grip impedance pulls the fingertip; the fingertip's contact pushes the handle
            fw, xa, va, rt, rx, ron, ef = _reactive_hand_step(xf, vf, xu, vu, au, ku, bu, xa, va, rt, rx, ron,
                                                              ma, km, bmu, rdelay, fthr, mtool, dt,
                                                              ef, kcomp, calpha, ctool, btool)
            fu = -kft * (xh - xf) - bft * (vh - vf)
            vf += (fw - fu) * inv_mf * dt
            xf += vf * dt
        elif reactive:
            fu, xa, va, rt, rx, ron, ef = _reactive_hand_step(xh, vh, xu, vu, au, ku, bu, xa, va, rt, rx, ron,
                                                              ma, km, bmu, rdelay, fthr, mtool, dt,
                                                              ef, kcomp, calpha, ctool, btool)
        else:
            fu = -ku * (xh - xu) - bu * (vh - vu)
        # hysteretic linkage between drum and handle (sec. 3.5.3)
        xl = xd - xh
        if hyst:
            fl, fhat = hysteresis_step(xl, xlp, fl, fhat, flp, klp, fln, kln, gam)
        else:
            fl = kmean * xl
        xlp = xl
        fl_total = fl + bl * (vd - vh)
        fc = kc * (xd - xm) + bc * (vd - vm)         # cable force on the motor
        fm = fc + kf * iamp - bm * vm                # eq. 3.32 without friction
        fd = -fc - bd * vd - fl_total                # eq. 3.33 without friction
        cmf, stuck_m = _friction(vm, fm, cm, vstick)
        cdf, stuck_d = _friction(vd, fd, cd, vstick)
        ah = (fl_total + fu + fs) * inv_mh           # eq. 3.34 with the sample's contact force
        vm = 0.0 if stuck_m else vm + (fm + cmf) * inv_mm * dt
        vd = 0.0 if stuck_d else vd + (fd + cdf) * inv_md * dt
        vh += ah * dt
        xm += vm * dt
        xd += vd * dt
        xh += vh * dt
        if kind == 2.0:
            vb += ab * dt
            xb += vb * dt
        accf += beta * (ah - accf)
    s[S_XM], s[S_VM], s[S_XD], s[S_VD], s[S_XH], s[S_VH] = xm, vm, xd, vd, xh, vh
    s[S_FL], s[S_FHAT], s[S_XLPREV] = fl, fhat, xlp
    s[S_IAMP], s[S_ACCF], s[S_XB], s[S_VB] = iamp, accf, xb, vb
    if reactive:
        s[S_XA], s[S_VA], s[S_RFX_T], s[S_RFX_X], s[S_RFX_ON] = xa, va, rt, rx, ron
        s[S_EF] = ef
    if finger:
        s[S_XF], s[S_VF] = xf, vf
    else:
        s[S_XF], s[S_VF] = xh, vh      # a fingertip that takes hold later starts at rest on the handle
    s[S_FM] = fmx
    s[S_AH] = ah
    s[S_FCONTACT] = fs
    return contact_any


@njit(cache=True, _nrt=False, error_model="numpy")
def _substeps_lti(s, p, xu0, xu1, g, i_cmd):
    """All substeps of one servo period of the LTI device: transmission T(s) -> handle mass."""
    dt = p[P_DT]
    nsub = int(p[P_NSUB])
    vu = (xu1 - xu0) / (dt * nsub)
    ku = p[P_KU_PER_N] * g
    bu = p[P_BU_PER_N] * g
    kf = p[P_KF]
    lowpass = p[P_AMP_LOWPASS] != 0.0
    alpha = p[P_AMP_ALPHA]
    beta = p[P_ACC_BETA]
    inv_mh = 1.0 / p[P_MH]
    kind, sk, salpha, smb, skf, sbf = p[P_S_KIND], p[P_S_K], p[P_S_ALPHA], p[P_S_MB], p[P_S_KF], p[P_S_BF]
    sk1, mxdecay, fmx = p[P_S_K1], p[P_S_MXDECAY], s[S_FM]
    nl = int(p[P_LTI_N])
    a0 = P_LTI_MATS
    b0 = a0 + nl * nl
    c0 = b0 + nl
    d0 = c0 + nl
    xh, vh = s[S_XH], s[S_VH]
    iamp, accf, xb, vb = s[S_IAMP], s[S_ACCF], s[S_XB], s[S_VB]
    z = s[S_LTI:S_LTI + nl]
    tmp = s[S_LTI_TMP:S_LTI_TMP + nl]
    ah = 0.0
    fs = 0.0
    contact_any = 0.0
    dxu = (xu1 - xu0) / nsub
    for j in range(nsub):
        xu = xu0 + dxu * (j + 1)
        if lowpass:
            iamp += alpha * (i_cmd - iamp)
        else:
            iamp = i_cmd
        ff = kf * iamp
        fs, ab, flag, fmx = _contact(kind, sk, salpha, smb, skf, sbf, sk1, mxdecay, dt, xh, vh, xb, vb, fmx)
        if flag > 0.0:
            contact_any = 1.0
        fu = -ku * (xh - xu) - bu * (vh - vu)
        fe = p[d0] * ff
        for r in range(nl):
            fe += p[c0 + r] * z[r]
        for r in range(nl):
            acc = p[b0 + r] * ff
            for c in range(nl):
                acc += p[a0 + r * nl + c] * z[c]
            tmp[r] = acc
        for r in range(nl):
            z[r] = tmp[r]
        ah = (fe + fu + fs) * inv_mh
        vh += ah * dt
        xh += vh * dt
        if kind == 2.0:
            vb += ab * dt
            xb += vb * dt
        accf += beta * (ah - accf)
    s[S_XH], s[S_VH], s[S_XM], s[S_VM] = xh, vh, xh, vh
    s[S_FM] = fmx
    s[S_IAMP], s[S_ACCF], s[S_XB], s[S_VB] = iamp, accf, xb, vb
    s[S_AH] = ah
    s[S_FCONTACT] = fs
    return contact_any


command_rule_nb = njit(cache=True, _nrt=False, inline="always", error_model="numpy")(command_rule)


@njit(cache=True, _nrt=False, error_model="numpy")
def tick(s, p, rs, traj, grip, k, i_cmd):
    """Advance the device by one servo period (all substeps) and return its sensor readings.

    Parameters
    ----------
    s : ndarray float64 (N_STATE,)
        State, updated in place.
    p : ndarray float64 (N_PARAM,)
        Parameters (see module doc).
    rs : ndarray uint64 (1,)
        Noise generator state.
    traj : ndarray float64 (n,)
        Desired hand position (m) at servo ticks since the user was set; held
        at its last value past the end.
    grip : ndarray float64 (n,)
        Grip force (N) at the same ticks.
    k : int
        Tick index into ``traj``/``grip`` at the start of this period.
    i_cmd : float
        Current applied during this period (A), i.e. the command of the
        previous tick (one-cycle output delay is handled by the caller).

    Returns
    -------
    position_m, accel_m_s2, grip_N : float
        Quantized encoder position (handle space), accelerometer reading and
        grip-sensor reading at the end of the period.
    over_temperature : float
        1.0 if the modelled winding temperature rise exceeds its limit.
    """
    n = traj.shape[0]
    k0 = k if k < n else n - 1
    k1 = k + 1 if k + 1 < n else n - 1
    xu0 = traj[k0]
    xu1 = traj[k1]
    g = grip[k0]
    imax = p[P_IMAX]
    if i_cmd > imax:
        i_cmd = imax
    elif i_cmd < -imax:
        i_cmd = -imax
    if p[P_MOTOR_ON] == 0.0:
        i_cmd = 0.0
    au = 0.0
    if p[P_HAND_ON] != 0.0:
        # desired hand acceleration over this period: the reactive hand's feedforward
        km1 = k - 1 if k - 1 >= 0 else 0
        km1 = km1 if km1 < n else n - 1
        per = p[P_DT] * p[P_NSUB]
        au = (xu1 - 2.0 * xu0 + traj[km1]) / (per * per) if k + 1 < n and k >= 1 else 0.0
    if p[P_MODEL] == 1.0:
        contact_any = _substeps_lti(s, p, xu0, xu1, g, i_cmd)
    else:
        contact_any = _substeps_nonlinear(s, p, xu0, xu1, au, g, i_cmd)
    s[S_CONTACT] = contact_any
    s[S_XU] = xu1
    s[S_VU] = (xu1 - xu0) * (1.0 / (p[P_DT] * p[P_NSUB]))
    # first-order winding temperature rise (I^2 R heating)
    s[S_TEMP] = p[P_THERM_A] * s[S_TEMP] + (1.0 - p[P_THERM_A]) * p[P_THERM_GAIN] * i_cmd * i_cmd
    # sensors: encoder (eq. 3.2-3.3 mapped to the handle), accelerometer, grip
    res = p[P_ENC_RES]
    pos = res * math.floor(s[S_XM] / res)
    a = s[S_ACCF]
    if p[P_ACC_NOISE] > 0.0:
        a += p[P_ACC_NOISE] * _xorshift_normal(rs)
    ares = p[P_ACC_RES]
    a = ares * math.floor(a / ares + 0.5)
    if a > p[P_ACC_RANGE]:
        a = p[P_ACC_RANGE]
    elif a < -p[P_ACC_RANGE]:
        a = -p[P_ACC_RANGE]
    gres = p[P_GRIP_RES]
    gq = gres * math.floor(g / gres + 0.5)
    if gq > p[P_GRIP_MAX]:
        gq = p[P_GRIP_MAX]
    elif gq < 0.0:
        gq = 0.0
    hot = 1.0 if s[S_TEMP] > p[P_TEMP_MAX] else 0.0
    return pos, a, gq, hot
