"""The 3-D servo law, compiled (numba): proxy, wall force, contact events, transient along the normal, saturation.

The 1-DOF law (``renderer.law``) in three dimensions, one tick between a sample and the force command:

1. sensor validation (a NaN or out-of-range coordinate holds the last good sample, ``max_bad_samples`` in a
   row stop with zero force; a disconnect stops at once);
2. per-axis sliding least-squares velocity (O(1)), and the double-written position rings the impact's
   velocity fit reads;
3. the playing transient's sample (N);
4. the god-object proxy towards the endpoint (``renderer.proxy``): contact, normal, depth ``d``;
5. contact events: armed and a new contact -> an impact (the event's work in Python after the command:
   the incoming velocity's normal component ``v_n``, the object's transient written into the buffer);
   re-armed once out of contact by ``rearm_margin_m`` from the last surface for ``rearm_hold_s`` and the
   transient done;
6. the wall force ``k d n`` plus friction (eq. 2.1), its magnitude limited to the continuous force; the
   transient ``F_t n_e`` along the event's (shaded) normal limited to the peak force; their sum's
   magnitude to the peak force (section 4.4.2, on the force vector);
7. the passivity observer (Hannaford & Ryu 2002) along the contact normal: the wall force's normal
   component times the endpoint's normal displacement plus the change of ``wall_energy(k, F_c, d)``;
8. the winding model on the force's equivalent current (``|F| / force_per_amp``);
9. the log row.

:func:`run_sim3` runs it with the 3-DOF simulated device's physics (the 1-DOF kernel along the tap,
``devices.sim.lateral`` across), as ``renderer.law.run_sim`` does for the 1-DOF device.
"""

from __future__ import annotations

import math

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from devices.sim import kernel as SK
from devices.sim import lateral as LAT
from devices.sim.layout import (D_ACC, D_GRIP, D_HELD, D_LAST, D_LIMIT, D_PERIOD, D_POS, D_REJECTED, D_STATUS,
                                D_T, D_TICK, D_USER_TICK, HOT_STATUS, P_MOTOR_ON)

from . import proxy as PX
# the arrays' layout (numba-free, shared with renderer.loop3)
from .law3_layout import (  # noqa: F401 -- re-exported: law3.C_*, law3.W_*, law3.LOG_COLUMNS, ...
    CODE_CLOSED, CODE_DISCONNECTED, CODE_IMPACT, CODE_OK, CODE_SENSOR, CODE_UNSTABLE, C_ALPHA, C_AMAX, C_AMIN,
    C_CAP, C_C_SCALE, C_C_SHIFT, C_DEV_FPK, C_FC, C_FPK, C_GMAX, C_GMIN, C_HEAT, C_HOLD_B, C_HOLD_K, C_HOLD_N,
    C_FS, C_HOLD_ON, C_INV_KF, C_SAME_MAX, C_INV_SPAN, C_MARGIN, C_MAX_BAD, C_MOTOR, C_NRING, C_PLIM, C_PO_DECAY, C_PO_LIMIT,
    C_TBUF, C_T_ATT, C_T_END, C_WV, LOG_COLUMNS, N_C, N_LOG, STATUS_DISCONNECTED, STATUS_SENSOR_INVALID, W_ARMED,
    W_BAD_TOTAL, W_CLOSED_ACC, W_CLOSED_CLIP, W_CLOSED_PEN, W_CODE, W_ENX, W_ENY, W_ENZ, W_EV_ACC, W_EV_CLIP,
    W_EV_OBJ, W_EV_ON, W_EV_PEN, W_FLAGS, W_GRIP, W_GTH, W_HX, W_HY, W_LAST_ACC, W_LAST_GRIP, W_LI, W_LNX, W_LNY,
    W_LNZ, W_LSX, W_LSY, W_LSZ, W_LX, W_LY, W_LZ, W_N, W_NBAD, W_OUT_N, W_PI, W_PNEW, W_PO, W_PO_E, W_PO_F,
    W_PO_U, W_PO_X, W_PO_Y, W_PO_Z, W_PS, W_RING, W_S0X, W_S0Y, W_S0Z, W_S1X, W_S1Y, W_S1Z, W_T, W_TEMP, W_TJ,
    W_SAME, W_TLEN, W_TRING, W_VX, W_VY, W_VZ,
)
from .passivity import wall_energy
from .ring import advance
from .scene3 import O_K

_wall_energy = njit(cache=True, _nrt=False, inline="always")(wall_energy)
# the position rings' time grid (renderer.ring)
_ring_advance = njit(cache=True, _nrt=False, inline="always")(advance)
# run_sim3's per-tick callees inlined into it (numba's IR inliner: the same operations in the same order, so
# the same results, bit for bit): as calls, each tick pushed ~100 arguments on the stack (a numba array is 7-9
# of them) into law3_tick and the physics step, ~15 % of the 3-D simulated loop's time. The proxy stays a call:
# inlined as well, it doubled the ahead-of-time build's time and saved nothing measurable.
_physics_tick = njit(_nrt=False, inline="always")(SK.tick.py_func)
_lateral_step = njit(_nrt=False, inline="always")(LAT.lateral_step)


@njit(cache=True, _nrt=False, inline="always")
def _ring(w, base, nring, wv, pi, po, x, s0i, s1i):
    old = w[base + po]
    w[base + pi] = x
    w[base + pi + nring] = x
    s0 = w[s0i]
    s1 = w[s1i] + (wv - 1.0) * x - s0 + old
    s0 += x - old
    w[s0i] = s0
    w[s1i] = s1
    return s0, s1


@njit(cache=True, _nrt=False, inline="always")
def _push3(c, w, nring, x, y, z):
    """Append a position (m) to the three rings; the sliding least-squares velocities (m/s) after it."""
    wv = c[C_WV]
    pi = int(w[W_PI])
    po = int(w[W_PO])
    s0, s1 = _ring(w, W_RING, nring, wv, pi, po, x, W_S0X, W_S1X)
    vx = (s1 - c[C_C_SHIFT] * s0) * c[C_C_SCALE]
    s0, s1 = _ring(w, W_RING + 2 * nring, nring, wv, pi, po, y, W_S0Y, W_S1Y)
    vy = (s1 - c[C_C_SHIFT] * s0) * c[C_C_SCALE]
    s0, s1 = _ring(w, W_RING + 4 * nring, nring, wv, pi, po, z, W_S0Z, W_S1Z)
    vz = (s1 - c[C_C_SHIFT] * s0) * c[C_C_SCALE]
    w[W_PNEW] = pi
    pi += 1
    if pi == nring:
        pi = 0
    po += 1
    if po == nring:
        po = 0
    w[W_PI] = pi
    w[W_PO] = po
    return vx, vy, vz


def _law3_tick(c, w, obj, tri, node, stack, log, t, x, y, z, acc, grip, status):
    """One tick of the 3-D law (module doc); returns the force (fx, fy, fz) to command (N, device frame)."""
    code = int(CODE_OK)    # int(): not a literal's type, which numba's inliner would freeze (run_sim3)
    flags = 0
    if status & STATUS_DISCONNECTED:
        w[W_CODE] = CODE_DISCONNECTED
        return 0.0, 0.0, 0.0
    plim = c[C_PLIM]
    if (status & STATUS_SENSOR_INVALID) or not (-plim <= x <= plim and -plim <= y <= plim and -plim <= z <= plim):
        flags |= 1 if not (status & STATUS_SENSOR_INVALID) else 8
        x, y, z = w[W_LX], w[W_LY], w[W_LZ]
    else:
        w[W_LX], w[W_LY], w[W_LZ] = x, y, z
    if acc != acc:   # NaN: the device has no accelerometer (devices.base.DeviceState), not a sensor fault
        acc = 0.0
    elif not (c[C_AMIN] <= acc <= c[C_AMAX]):
        flags |= 2
        acc = w[W_LAST_ACC]
    else:
        w[W_LAST_ACC] = acc
    if not (c[C_GMIN] <= grip <= c[C_GMAX]):
        flags |= 4
        grip = w[W_LAST_GRIP]
    else:
        w[W_LAST_GRIP] = grip
    w[W_FLAGS] = flags
    if flags:
        w[W_NBAD] += 1.0
        w[W_BAD_TOTAL] += 1.0
        if w[W_NBAD] >= c[C_MAX_BAD]:
            w[W_CODE] = CODE_SENSOR
            return 0.0, 0.0, 0.0
    else:
        w[W_NBAD] = 0.0
    # velocity: sliding least squares per axis, and the rings of the impact fit, one position per servo period of
    # the sample's own clock (renderer.ring): a sample read again adds nothing, samples the host missed are filled in
    nring = int(c[C_NRING])
    steps = _ring_advance(w, W_TRING, W_SAME, c[C_FS], c[C_SAME_MAX], t)
    if steps == 0:
        vx, vy, vz = w[W_VX], w[W_VY], w[W_VZ]
    else:
        if steps > 1:
            # the missed samples on the straight line from the newest slot to this sample: the rings' last ones
            # (not k, j: below they are the contact's stiffness, a float, and an object index; numba types a name once)
            i_new = int(w[W_PNEW])
            lx, ly, lz = w[W_RING + i_new], w[W_RING + 2 * nring + i_new], w[W_RING + 4 * nring + i_new]
            for i_fill in range(max(1, steps - nring + 1), steps):
                frac = i_fill / steps
                _push3(c, w, nring, lx + (x - lx) * frac, ly + (y - ly) * frac, lz + (z - lz) * frac)
        vx, vy, vz = _push3(c, w, nring, x, y, z)
    # the transient's sample for this tick (fixed before this tick's event check)
    tj = w[W_TJ]
    tlen = w[W_TLEN]
    g_th = w[W_GTH]
    if tj < tlen:
        f_t = w[int(c[C_TBUF]) + int(tj)] * g_th
        tj += 1.0
    else:
        f_t = 0.0
    # the proxy
    ps = w[W_PS:W_PS + PX.N_PS]
    n_c = PX.proxy_step(obj, tri, node, stack, ps, x, y, z)
    fx = fy = fz = 0.0
    d = 0.0
    k = 0.0
    armed = w[W_ARMED] != 0.0
    if n_c > 0:
        j = int(ps[PX.PS_OBJ])
        k = obj[j, O_K]
        fx, fy, fz, d = PX.proxy_force(ps, k, x, y, z)
        w[W_LNX], w[W_LNY], w[W_LNZ] = ps[PX.PS_NX], ps[PX.PS_NY], ps[PX.PS_NZ]
        w[W_LSX], w[W_LSY], w[W_LSZ] = ps[PX.PS_SX], ps[PX.PS_SY], ps[PX.PS_SZ]
        if armed:
            w[W_ARMED] = 0.0
            code = int(CODE_IMPACT)
            if w[W_EV_ON] != 0.0:
                code |= CODE_CLOSED
                w[W_CLOSED_PEN], w[W_CLOSED_ACC], w[W_CLOSED_CLIP] = w[W_EV_PEN], w[W_EV_ACC], w[W_EV_CLIP]
            w[W_EV_ON] = 1.0
            w[W_EV_PEN] = d
            w[W_EV_ACC] = 0.0
            w[W_EV_CLIP] = 0.0
            w[W_EV_OBJ] = j
            # the transient's direction: the (shaded) normal at the new contact
            w[W_ENX], w[W_ENY], w[W_ENZ] = ps[PX.PS_SNX], ps[PX.PS_SNY], ps[PX.PS_SNZ]
        else:
            w[W_OUT_N] = 0.0
    else:
        # out of contact: the endpoint's signed depth behind the last surface touched (< 0 outside)
        d = w[W_LNX] * (w[W_LSX] - x) + w[W_LNY] * (w[W_LSY] - y) + w[W_LNZ] * (w[W_LSZ] - z)
        if not armed:
            if d < -c[C_MARGIN] and tj >= tlen:
                w[W_OUT_N] += 1.0
                if w[W_OUT_N] >= c[C_HOLD_N]:
                    w[W_ARMED] = 1.0
                    if w[W_EV_ON] != 0.0:
                        code |= CODE_CLOSED
                        w[W_CLOSED_PEN], w[W_CLOSED_ACC], w[W_CLOSED_CLIP] = w[W_EV_PEN], w[W_EV_ACC], w[W_EV_CLIP]
                        w[W_EV_ON] = 0.0
            else:
                w[W_OUT_N] = 0.0
    # the hold channel: a 1-DOF scene on a 3-axis device keeps x and y where they started
    if c[C_HOLD_ON] != 0.0:
        fx += -c[C_HOLD_K] * (x - w[W_HX]) - c[C_HOLD_B] * vx
        fy += -c[C_HOLD_K] * (y - w[W_HY]) - c[C_HOLD_B] * vy
    # passivity observer along the contact normal (the wall's channel only)
    nx, ny, nz = w[W_LNX], w[W_LNY], w[W_LNZ]
    u = _wall_energy(k, c[C_FC], d, 1.0) if n_c > 0 else 0.0
    e_po = w[W_PO_E] * c[C_PO_DECAY] + w[W_PO_F] * (nx * (x - w[W_PO_X]) + ny * (y - w[W_PO_Y]) + nz * (z - w[W_PO_Z])) \
        + u - w[W_PO_U]
    w[W_PO_E] = e_po
    w[W_PO_X] = x
    w[W_PO_Y] = y
    w[W_PO_Z] = z
    w[W_PO_U] = u
    if e_po > c[C_PO_LIMIT]:
        w[W_CODE] = CODE_UNSTABLE
        return 0.0, 0.0, 0.0
    # saturation on the force vector's magnitude: the wall to the continuous force, the transient and the sum
    # to the peak force
    clip = int(0)
    f_wall = math.sqrt(fx * fx + fy * fy + fz * fz)
    fc = c[C_FC]
    if f_wall > fc:
        s = fc / f_wall
        fx *= s
        fy *= s
        fz *= s
        clip = int(1)
    fpk = c[C_FPK]
    f_t_req = f_t
    if f_t > fpk:
        f_t = fpk
        clip |= 2
    elif f_t < -fpk:
        f_t = -fpk
        clip |= 2
    w_fn = fx * nx + fy * ny + fz * nz      # the wall force's normal component, for the observer
    ox = fx + f_t * w[W_ENX]
    oy = fy + f_t * w[W_ENY]
    oz = fz + f_t * w[W_ENZ]
    f_sum = math.sqrt(ox * ox + oy * oy + oz * oz)
    if f_sum > fpk:
        s = fpk / f_sum
        ox *= s
        oy *= s
        oz *= s
        clip |= 4
    if c[C_MOTOR] == 0.0 or not (f_sum == f_sum):
        ox = oy = oz = 0.0
        w[W_PO_F] = 0.0
    else:
        w[W_PO_F] = w_fn
    # winding model on the equivalent current; transients fade, then end, before its limit
    i_eq = math.sqrt(ox * ox + oy * oy + oz * oz) * c[C_INV_KF]
    temp = w[W_TEMP]
    temp += (c[C_HEAT] * i_eq * i_eq - temp) * c[C_ALPHA]
    if temp > c[C_T_ATT]:
        g_th = (c[C_T_END] - temp) * c[C_INV_SPAN]
        if g_th <= 0.0:
            g_th = 0.0
            tj = tlen
    else:
        g_th = 1.0
    w[W_TEMP] = temp
    w[W_GTH] = g_th
    w[W_TJ] = tj
    if w[W_EV_ON] != 0.0:
        if n_c > 0 and d > w[W_EV_PEN]:
            w[W_EV_PEN] = d
        a = acc if acc >= 0.0 else -acc
        if a > w[W_EV_ACC]:
            w[W_EV_ACC] = a
        if clip & 4:
            w[W_EV_CLIP] = 1.0
    w[W_VX], w[W_VY], w[W_VZ] = vx, vy, vz
    w[W_T] = t
    w[W_GRIP] = grip
    li = int(w[W_LI])
    log[0, li] = t
    log[1, li] = x
    log[2, li] = y
    log[3, li] = z
    log[4, li] = ps[PX.PS_PX]
    log[5, li] = ps[PX.PS_PY]
    log[6, li] = ps[PX.PS_PZ]
    log[7, li] = d
    log[8, li] = nx
    log[9, li] = ny
    log[10, li] = nz
    log[11, li] = ox
    log[12, li] = oy
    log[13, li] = oz
    log[14, li] = f_wall
    log[15, li] = f_t_req
    log[16, li] = ps[PX.PS_OBJ] if n_c > 0 else -1.0
    log[17, li] = clip
    log[18, li] = acc
    log[19, li] = grip
    log[20, li] = temp
    log[21, li] = flags
    log[22, li] = f_t * w[W_ENX]
    log[23, li] = f_t * w[W_ENY]
    log[24, li] = f_t * w[W_ENZ]
    li += 1
    if li == int(c[C_CAP]):
        li = 0
    w[W_LI] = li
    w[W_N] += 1.0
    w[W_CODE] = code
    return ox, oy, oz


#: one tick of the law, called per tick by the paced loop (renderer.loop3) and the benchmarks
law3_tick = njit(cache=True, _nrt=False)(_law3_tick)
#: the same tick inlined into run_sim3
_law3_tick_inline = njit(_nrt=False, inline="always")(_law3_tick)


@njit(cache=True, _nrt=False, nogil=True)
def run_sim3(c, w, obj, tri, node, stack, log, dev, sp, ss, srs, traj, grip, lat, lp, frame, igrav, n_max):
    """Up to ``n_max`` ticks of :func:`law3_tick` on the 3-DOF simulated device in one call.

    Each tick: the endpoint from the tap axis's encoder and the lateral axes (device frame), the law,
    then the device's ``command_force`` (a NaN zeroes the command, the magnitude is clamped to the peak
    force) and ``_send_force``: the tap-frame components, the tap axis's current through the 1-DOF
    device's own command rule and physics step (``devices.sim.kernel``), the lateral axes'
    (``devices.sim.lateral``). Returns early, like ``renderer.law.run_sim``, at an impact or a stop.
    """
    fpk_dev = c[C_DEV_FPK]
    inv_kf = c[C_INV_KF]
    res = lp[LAT.LP_RES]
    for j in range(n_max):
        qu = dev[D_POS]
        qv = res * math.floor(lat[0] / res)
        qw = res * math.floor(lat[2] / res)
        x = frame[0] + frame[3] * qu + frame[6] * qv + frame[9] * qw
        y = frame[1] + frame[4] * qu + frame[7] * qv + frame[10] * qw
        z = frame[2] + frame[5] * qu + frame[8] * qv + frame[11] * qw
        fx, fy, fz = _law3_tick_inline(c, w, obj, tri, node, stack, log, dev[D_T], x, y, z, dev[D_ACC],
                                       dev[D_GRIP], int(dev[D_STATUS]))
        code = w[W_CODE]
        if code >= CODE_SENSOR:
            return j
        # Device.command_force: NaN -> zero (rejected), magnitude to the device's peak force
        m2 = fx * fx + fy * fy + fz * fz
        if not (m2 == m2) or m2 == math.inf:
            dev[D_REJECTED] += 1.0
            fx = fy = fz = 0.0
        elif m2 > fpk_dev * fpk_dev:
            s = fpk_dev / math.sqrt(m2)
            fx *= s
            fy *= s
            fz *= s
        fu = frame[3] * fx + frame[4] * fy + frame[5] * fz
        fv = frame[6] * fx + frame[7] * fy + frame[8] * fz
        fw = frame[9] * fx + frame[10] * fy + frame[11] * fz
        tick = dev[D_TICK] + 1.0
        kk = int(tick - 1.0 - dev[D_USER_TICK])
        n = grip.shape[0]
        g = grip[kk if kk < n else n - 1]
        if sp[P_MOTOR_ON] == 0.0:
            fv = fw = 0.0
        # SimDevice.command(fu / kf + gravity): the 1-DOF device's own input rule and physics step
        i, status, rejected = SK.command_rule_nb(fu * inv_kf + igrav, dev[D_LIMIT])
        dev[D_REJECTED] += rejected
        dev[D_LAST] = i
        applied = dev[D_HELD]
        dev[D_HELD] = i
        dev[D_TICK] = tick
        p, a, gq, hot = _physics_tick(ss, sp, srs, traj, grip, kk, applied)
        _lateral_step(lat, lp, fv, fw, g)
        dev[D_T] = tick * dev[D_PERIOD]
        dev[D_POS] = p
        dev[D_ACC] = a
        dev[D_GRIP] = gq
        dev[D_STATUS] = status | HOT_STATUS if hot != 0.0 else status
        if code != CODE_OK:
            return j + 1
    return n_max
