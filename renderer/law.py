"""The servo law of the haptic loop, compiled once and used by every loop (thesis Fig. 4.9).

:func:`law_tick` is one tick of the law between a sensor sample and the motor current: sensor
validation, the sliding least-squares velocity, the playing transient's sample, collision of the
proxy with the scene, contact events (impact, re-arm), the proportional wall with entry damping
(eq. 2.1, section 2.2.2), per-channel and summed saturation (section 4.4.2) and the winding thermal
model, and the tick's log row. ``renderer.loop.ServoLoop`` calls it once per tick between a device's
``read()`` and ``command()`` (hardware, paced simulations); :func:`run_sim` runs it together with the
simulated device's physics (``devices.sim.kernel.tick``) for many ticks in one compiled call, so an
as-fast-as-possible simulation costs the physics and the law and nothing else. One source of the law
for both; the work of an impact (the velocity fit, the transient lookup, the event record) stays in
Python, after the tick's command, in both.

Arrays (all float64):

* ``c`` -- constants (``C_*``), then the scene's objects, ``OBJ_STRIDE`` numbers each: shape code
  (``renderer.scene.SHAPE_CODES``) and the numbers of ``Shape.numbers()``;
* ``w`` -- state (``W_*``), then the double-written position ring (``2 nring`` samples from
  ``W_RING``) and the transient buffer (``nbuf`` samples of current, A, from ``c[C_TBUF]``);
* ``log`` -- (``N_LOG``, capacity): one row per channel of ``LOG_COLUMNS`` (each channel contiguous, so a
  run's log columns are views, not copies), a ring whose column ``w[W_LI]`` is written.

``w[W_CODE]`` after a tick holds bits: ``CODE_IMPACT`` (an impact fired: do the event work after the
command), ``CODE_CLOSED`` (the open event closed, at a re-arm or a new impact: its maximum
penetration, peak |acceleration| and amplifier-clip flag are in ``W_CLOSED_*``), ``CODE_SENSOR`` (too
many invalid samples in a row), ``CODE_DISCONNECTED`` or ``CODE_UNSTABLE`` (the wall's passivity
observer ``W_PO_E`` exceeded ``C_PO_LIMIT``: the loop generates energy); the last three stop with zero
current.
"""

from __future__ import annotations

import math

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from devices.sim import kernel as SK

from .passivity import wall_energy
from .ring import advance
from .scene import SHAPE_CODES, box_1d, plane_1d, sphere_1d, wall_1d

# the arrays' layout (numba-free, shared with renderer.loop and renderer.sim_aot)
from .law_layout import *  # noqa: F401,F403 -- re-exported: law.C_*, law.W_*, law.CODE_*, law.LOG_COLUMNS


# the scene's shapes, compiled from renderer.scene's own functions
_wall_1d = njit(cache=True, _nrt=False, inline="always")(wall_1d)
_plane_1d = njit(cache=True, _nrt=False, inline="always")(plane_1d)
_sphere_1d = njit(cache=True, _nrt=False, inline="always")(sphere_1d)
_box_1d = njit(cache=True, _nrt=False, inline="always")(box_1d)
# the energy the wall stores (its passivity observer), compiled from renderer.passivity's own function
_wall_energy = njit(cache=True, _nrt=False, inline="always")(wall_energy)
# the position ring's time grid (renderer.ring)
_ring_advance = njit(cache=True, _nrt=False, inline="always")(advance)
_WALL, _PLANE, _SPHERE, _BOX = (SHAPE_CODES[k] for k in ("wall", "plane", "sphere", "box"))



@njit(cache=True, _nrt=False, inline="always")
def _ring_push(c, w, nring, pos):
    """Append ``pos`` (m) to the double-written position ring and update the sliding least-squares sums."""
    wv = c[C_WV]
    po = int(w[W_PO])
    pi = int(w[W_PI])
    old = w[W_RING + po]
    po += 1
    if po == nring:
        po = 0
    w[W_RING + pi] = pos
    w[W_RING + pi + nring] = pos
    w[W_PNEW] = pi
    pi += 1
    if pi == nring:
        pi = 0
    w[W_PO] = po
    w[W_PI] = pi
    s0 = w[W_S0]
    w[W_S1] = w[W_S1] + (wv - 1.0) * pos - s0 + old
    w[W_S0] = s0 + pos - old


@njit(cache=True, _nrt=False, inline="always")
def _clamp(x, limit):
    """``x`` limited to +/- ``limit`` and whether it was beyond (a NaN passes unclipped)."""
    if x > limit:
        return limit, True
    if x < -limit:
        return -limit, True
    return x, False


@njit(cache=True, _nrt=False, inline="always")
def _valid_or_last(w, slot, x, lo, hi):
    """``x`` if inside [lo, hi] (kept in ``w[slot]`` as the last good value), else that last good value
    (NaN is never inside); and whether it was held."""
    if lo <= x <= hi:
        w[slot] = x
        return x, False
    return w[slot], True


@njit(cache=True, _nrt=False, inline="always")
def penetration(c, z):
    """Deepest signed penetration (m) of the proxy (0, 0, z) over the scene's objects and the normal's
    z component (``renderer.scene.Scene.penetration_1d``)."""
    best_d = -math.inf
    best_nz = 1.0
    for j in range(int(c[C_NOBJ])):
        o = C_OBJ + OBJ_STRIDE * j
        kind = c[o]
        if kind == _WALL:
            d, nz = _wall_1d(c[o + 1], z)
        elif kind == _PLANE:
            d, nz = _plane_1d(c[o + 1], c[o + 2], c[o + 3], c[o + 4], c[o + 5], c[o + 6], z)
        elif kind == _SPHERE:
            d, nz = _sphere_1d(c[o + 1], c[o + 2], c[o + 3], c[o + 4], z)
        else:
            d, nz = _box_1d(c[o + 1], c[o + 2], c[o + 3], c[o + 4], c[o + 5], c[o + 6], z)
        if d > best_d:
            best_d = d
            best_nz = nz
    return best_d, best_nz


# an explicit signature: compiled (or loaded from the cache) at import, and a device that reports an
# int or a numpy scalar never triggers a new compilation in the middle of a paced loop
@njit("float64(float64[::1], float64[::1], float64[:, ::1], float64, float64, float64, float64, int64)", cache=True, _nrt=False)
def law_tick(c, w, log, t, pos, acc, grip, status):
    """One tick of the servo law (module doc): returns the motor current (A) to command now.

    Parameters
    ----------
    c, w : float64 arrays
        Constants and state (module doc).
    log : float64 array (N_LOG, capacity)
        Log ring, one row per channel; column ``w[W_LI]`` is written.
    t, pos, acc, grip : float
        The device's sample: time (s, the sample's own: the velocity ring goes by it, ``renderer.ring``),
        position (m, + up), acceleration (m/s^2), grip (N).
    status : int
        The sample's status bits (``devices.base.Status``).

    Returns
    -------
    current_A : float
        After saturation and the thermal model; 0 when the tick stops the loop (``w[W_CODE]`` >= 2).
    """
    code = CODE_OK
    flags = 0
    if status != 0:
        if status & STATUS_DISCONNECTED:
            w[W_CODE] = CODE_DISCONNECTED
            return 0.0
        if status & STATUS_SENSOR_INVALID:
            flags = 8
            pos = w[W_LAST_POS]
            acc = w[W_LAST_ACC]
            grip = w[W_LAST_GRIP]
    # (1) validate: out of range or NaN -> hold the last good value and flag it
    pos, held = _valid_or_last(w, W_LAST_POS, pos, -c[C_PLIM], c[C_PLIM])
    if held:
        flags |= 1
    acc, held = _valid_or_last(w, W_LAST_ACC, acc, -c[C_ALIM], c[C_ALIM])
    if held:
        flags |= 2
    grip, held = _valid_or_last(w, W_LAST_GRIP, grip, c[C_GMIN], c[C_GMAX])
    if held:
        flags |= 4
    w[W_FLAGS] = flags
    if flags:
        w[W_NBAD] += 1.0
        w[W_BAD_TOTAL] += 1.0
        if w[W_NBAD] >= c[C_MAX_BAD]:
            w[W_CODE] = CODE_SENSOR
            return 0.0
    else:
        w[W_NBAD] = 0.0
    # (2) sliding least-squares velocity, O(1) (renderer.velocity.ls_constants), over a ring of one position per
    # servo period of the sample's own clock (renderer.ring): a sample read again adds nothing, samples the host
    # missed are filled in
    nring = int(c[C_NRING])
    steps = _ring_advance(w, W_TRING, W_SAME, c[C_FS], c[C_SAME_MAX], t)
    if steps == 0:
        vel = w[W_VEL]
    else:
        if steps > 1:
            # the missed samples on the straight line from the newest slot to this sample: the ring's last ones
            last = w[W_RING + int(w[W_PNEW])]
            for j in range(max(1, steps - nring + 1), steps):
                _ring_push(c, w, nring, last + (pos - last) * (j / steps))
        _ring_push(c, w, nring, pos)
        vel = (w[W_S1] - c[C_C_SHIFT] * w[W_S0]) * c[C_C_SCALE]
    # transient playback: the sample for this tick was fixed before this tick's event check
    tj = w[W_TJ]
    tlen = w[W_TLEN]
    g_th = w[W_GTH]
    if tj < tlen:
        i_t = w[int(c[C_TBUF]) + int(tj)] * g_th
        tj += 1.0
    else:
        i_t = 0.0
    # collision and contact events
    d, nz = penetration(c, pos)
    # passivity observer (Hannaford & Ryu 2002) of the proportional wall: the work its force, held over the
    # last period, did on the handle plus the change of the energy it stores, with a leak. A spring-like
    # wall only leaks a little through sampling (of order k T v^2 per tap); an unstable loop keeps
    # generating energy, every cycle
    u = _wall_energy(c[C_K], c[C_PO_FC], d, nz)
    if w[W_PO_U] == w[W_PO_U]:
        e_po = w[W_PO_E] * c[C_PO_DECAY] + w[W_PO_F] * (pos - w[W_PO_X]) + u - w[W_PO_U]
    else:   # the first tick after priming (NaN): the account starts here (renderer.loop.ServoLoop._prime)
        e_po = 0.0
    w[W_PO_E] = e_po
    w[W_PO_X] = pos
    w[W_PO_U] = u
    if e_po > c[C_PO_LIMIT]:
        w[W_CODE] = CODE_UNSTABLE
        return 0.0
    armed = w[W_ARMED] != 0.0
    if d > 0.0:
        if armed:  # impact: the event's work is done after command() (the caller)
            w[W_ARMED] = 0.0
            code = CODE_IMPACT
            if w[W_EV_ON] != 0.0:
                code |= CODE_CLOSED
                w[W_CLOSED_PEN], w[W_CLOSED_ACC], w[W_CLOSED_CLIP] = w[W_EV_PEN], w[W_EV_ACC], w[W_EV_CLIP]
            w[W_EV_ON] = 1.0
            w[W_EV_PEN] = d
            w[W_EV_ACC] = 0.0
            w[W_EV_CLIP] = 0.0
        else:
            w[W_OUT_N] = 0.0
        f_p = c[C_K] * d * nz
        damp = c[C_DAMP]
        if damp > 0.0 and vel * nz < 0.0:
            f_p -= damp * vel
    else:
        f_p = 0.0
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
    # (3) saturate per channel, then the sum (section 4.4.2); thermal model
    i_p, hit = _clamp(f_p * c[C_INV_KF], c[C_IC])
    clip = 1 if hit else 0
    i_t_req = i_t
    i_t, hit = _clamp(i_t, c[C_IPK])
    if hit:
        clip |= 2
    i, hit = _clamp(i_p + i_t, c[C_IAMP])
    if hit:
        clip |= 4
    if c[C_MOTOR] == 0.0 or i != i:
        i = 0.0
        w[W_PO_F] = 0.0
    else:
        w[W_PO_F] = i_p * c[C_KF]
    # winding thermal model: attenuate, then end, transients before the limit
    temp = w[W_TEMP]
    temp += (c[C_HEAT] * i * i - temp) * c[C_ALPHA]
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
    # the open event's extremes (an impact this tick opened it with this tick's depth)
    if w[W_EV_ON] != 0.0:
        if d > w[W_EV_PEN]:
            w[W_EV_PEN] = d
        if acc > w[W_EV_ACC]:
            w[W_EV_ACC] = acc
        elif -acc > w[W_EV_ACC]:
            w[W_EV_ACC] = -acc
        if clip & 4:
            w[W_EV_CLIP] = 1.0
    # what the caller's event work needs
    w[W_VEL] = vel
    w[W_D] = d
    w[W_NZ] = nz
    w[W_T] = t
    w[W_GRIP] = grip
    # (5) log column
    li = int(w[W_LI])
    log[0, li] = t
    log[1, li] = pos
    log[2, li] = vel
    log[3, li] = d
    log[4, li] = f_p
    log[5, li] = i_t_req * c[C_KF]
    log[6, li] = i
    log[7, li] = clip
    log[8, li] = acc
    log[9, li] = grip
    log[10, li] = temp
    log[11, li] = flags
    li += 1
    if li == int(c[C_CAP]):
        li = 0
    w[W_LI] = li
    w[W_N] += 1.0
    w[W_CODE] = code
    return i


# nogil: while a run is in here, other threads (a UI, the study's audio callback, a web server) keep running
@njit(cache=True, _nrt=False, nogil=True)
def run_sim(c, w, log, dev, sp, ss, srs, traj, grip, n_max):
    """Up to ``n_max`` ticks of the law on the simulated device (``devices.sim.kernel.tick``) in one call.

    Each tick: the law on the device's current sample, then the device's ``command()`` (NaN -> 0 and
    counted, clamp to the amplifier, the current applied during the *next* period, as
    ``SimDevice.command``), which advances the physics one servo period. Returns early after a tick
    whose ``w[W_CODE]`` is not ``CODE_OK``: after the command for an impact, before it for a stop.

    Parameters
    ----------
    c, w, log : arrays of :func:`law_tick`.
    dev : float64 array (N_DEV,)
        The device's Python-side state (``D_*``), read and written.
    sp, ss, srs, traj, grip : arrays of ``devices.sim.kernel.tick``.
    n_max : int

    Returns
    -------
    ticks : int
        Ticks run.
    """
    for j in range(n_max):
        i = law_tick(c, w, log, dev[D_T], dev[D_POS], dev[D_ACC], dev[D_GRIP], int(dev[D_STATUS]))
        code = w[W_CODE]
        if code >= CODE_SENSOR:
            return j
        # SimDevice.command(i): the device's own input rule, then one servo period of its physics
        i, status, rejected = SK.command_rule_nb(i, dev[D_LIMIT])
        dev[D_REJECTED] += rejected
        dev[D_LAST] = i
        applied = dev[D_HELD]
        dev[D_HELD] = i
        tick = dev[D_TICK] + 1.0
        dev[D_TICK] = tick
        p, a, g, hot = SK.tick(ss, sp, srs, traj, grip, int(tick - 1.0 - dev[D_USER_TICK]), applied)
        dev[D_T] = tick * dev[D_PERIOD]
        dev[D_POS] = p
        dev[D_ACC] = a
        dev[D_GRIP] = g
        dev[D_STATUS] = status | HOT_STATUS if hot != 0.0 else status
        if code != CODE_OK:
            return j + 1
    return n_max


@njit(cache=True, _nrt=False, nogil=True)
def run_homing(h, dev, sp, ss, srs, traj, grip, n_max):
    """Up to ``n_max`` ticks of :meth:`renderer.homing.HomingController.run`'s loop on the simulated device
    (``devices.sim.kernel.tick``) in one call: the same safety path (sensor plausibility, the clamp at the
    thermally safe current, the winding's heat), the same PD, passivity observer, contact and run-away
    checks, the same ``SimDevice.command`` (its input rule, one period of output delay) and the same stops,
    number for number (``tests/renderer/test_homing.py`` compares them tick for tick).

    Parameters
    ----------
    h : float64 array (N_HOMING,)
        The run's constants and the loop's state (``H_*`` of :mod:`renderer.law_layout`), read and written.
    dev : float64 array (N_DEV,)
        The device's Python-side state (``devices.sim.layout.D_*``), read and written.
    sp, ss, srs, traj, grip : arrays of ``devices.sim.kernel.tick``.
    n_max : int
        Ticks at most in this call (the caller's window of the hand's plan).

    Returns
    -------
    code : int
        ``HOME_*``: ``HOME_RAN`` when the ticks ran out (``n_max`` or the run's ``H_N``), a stop
        (disconnected, sensor, unstable, runaway, settled: the tick's command is sent only when the stop
        comes after it, as in the Python loop), or ``HOME_CHECK`` after a tick whose ``until()`` the caller
        checks (``H_CHECK_EVERY``), before that tick's settled test.
    """
    home = h[H_HOME]
    surface = h[H_SURFACE]
    armed_level = h[H_ARMED_LEVEL]
    kp = h[H_KP]
    kd = h[H_KD]
    inv_fpa = h[H_INV_FPA]
    imax = h[H_IMAX]
    alpha = h[H_ALPHA]
    inv_dt = h[H_INV_DT]
    n = int(h[H_N])
    n_min = int(h[H_NMIN])
    tol = h[H_TOL]
    vtol = h[H_VTOL]
    plim = h[H_PLIM]
    alim = h[H_ALIM]
    max_bad = int(h[H_MAX_BAD])
    fmax = h[H_FMAX]
    fpa = h[H_FPA]
    run_dist = h[H_RUN_DIST]
    run_speed = h[H_RUN_SPEED]
    decay = h[H_DECAY]
    elimit = h[H_ELIMIT]
    heat = h[H_HEAT]
    talpha = h[H_THERM_ALPHA]
    until_settled = h[H_UNTIL_SETTLED] != 0.0
    check_every = int(h[H_CHECK_EVERY])
    tick = int(h[H_TICK])
    x_prev = h[H_X_PREV]
    x = h[H_X]
    v = h[H_V]
    dx = h[H_DX]
    err = h[H_ERR]
    f_prev = h[H_F_PREV]
    away = h[H_AWAY]
    away_max = h[H_AWAY_MAX]
    armed = h[H_ARMED] != 0.0
    contacts = int(h[H_CONTACTS])
    temp = h[H_TEMP]
    energy = h[H_E]
    peak = h[H_PEAK]
    stored_prev = h[H_STORED]
    bad_row = int(h[H_BAD_ROW])
    bad_total = int(h[H_BAD_TOTAL])
    code = HOME_RAN
    j = 0
    while j < n_max and tick < n:
        j += 1
        tick += 1
        # (1) read and validate (renderer.safety.SafetyPath.sample)
        status = int(dev[D_STATUS])
        xs = dev[D_POS]
        if status & STATUS_DISCONNECTED:
            x = xs
            code = HOME_DISCONNECTED
            break
        acc = dev[D_ACC]
        if status & STATUS_SENSOR_INVALID or not (-plim <= xs <= plim) or not (-alim <= acc <= alim):
            bad_row += 1
            bad_total += 1
            x = x_prev
            if bad_row >= max_bad:
                code = HOME_SENSOR
                break
        else:
            bad_row = 0
            x = xs
        dx = x - x_prev
        v += alpha * (dx * inv_dt - v)
        x_prev = x
        # passivity observer (renderer.passivity.PassivityObserver.update)
        err = home - x
        stored = _wall_energy(kp, fmax, abs(err), 1.0)
        e = energy * decay + f_prev * dx + stored - stored_prev
        if e < 0.0:
            e = 0.0
        energy = e
        stored_prev = stored
        if e > peak:
            peak = e
            if e > elimit:
                code = HOME_UNSTABLE
                break
        if armed:
            if x < surface:
                contacts += 1
                armed = False
        elif x > armed_level:
            armed = True
        # (2) the homing law, (3) saturated (SafetyPath.current: NaN -> 0 A)
        i = (kp * (home - x) - kd * v) * inv_fpa
        if i > imax:
            i = imax
        elif i < -imax:
            i = -imax
        elif i != i:
            i = 0.0
        if (i == imax if err > 0.0 else i == -imax) and v * err < 0.0 and abs(v) > run_speed:
            away += abs(dx)
            if away > away_max:
                away_max = away
            if away > run_dist:
                code = HOME_RUNAWAY
                break
        else:
            away = 0.0
        f_prev = i * fpa
        temp = temp + (heat * i * i - temp) * talpha
        # (4) SimDevice.command(i): the device's input rule, then one servo period of its physics
        i, st, rejected = SK.command_rule_nb(i, dev[D_LIMIT])
        dev[D_REJECTED] += rejected
        dev[D_LAST] = i
        applied = dev[D_HELD]
        dev[D_HELD] = i
        t = dev[D_TICK] + 1.0
        dev[D_TICK] = t
        p, a, g, hot = SK.tick(ss, sp, srs, traj, grip, int(t - 1.0 - dev[D_USER_TICK]), applied)
        dev[D_T] = t * dev[D_PERIOD]
        dev[D_POS] = p
        dev[D_ACC] = a
        dev[D_GRIP] = g
        dev[D_STATUS] = st | HOT_STATUS if hot != 0.0 else st
        if check_every > 0 and tick % check_every == 0:
            code = HOME_CHECK
            break
        if until_settled and tick >= n_min and abs(x - home) < tol and abs(v) < vtol:
            code = HOME_SETTLED
            break
    h[H_TICK] = tick
    h[H_X_PREV] = x_prev
    h[H_X] = x
    h[H_V] = v
    h[H_DX] = dx
    h[H_ERR] = err
    h[H_F_PREV] = f_prev
    h[H_AWAY] = away
    h[H_AWAY_MAX] = away_max
    h[H_ARMED] = 1.0 if armed else 0.0
    h[H_CONTACTS] = contacts
    h[H_TEMP] = temp
    h[H_E] = energy
    h[H_PEAK] = peak
    h[H_STORED] = stored_prev
    h[H_BAD_ROW] = bad_row
    h[H_BAD_TOTAL] = bad_total
    return code
