"""The 3-DOF simulated device's two lateral axes: plain scalar code, no numba (compiled by the 3-D servo law).

Across the tap direction the simulated endpoint is a lumped mass (the 1-DOF chain's motor, drum and handle
masses in handle space, plus the device's and the linkage's inertia along that axis) with viscous and Coulomb
friction (Karnopp's stick band, as the 1-DOF kernel's eq. 3.35), held by the person's grip impedance
(Table 3.1's k_u, b_u scaled with grip, as along the tap) to a hand that does not move across the tap. The
force commanded at one tick is applied during the period after the next (one period of output delay, like
the tap axis). ``devices.sim.sim3.Sim3Device`` calls :func:`lateral_step` per tick in Python;
``renderer.law3`` compiles the same function into its loop (one source).

Arrays (float64):

* ``lat``: ``LAT_*`` state: positions (m) and velocities (m/s) of the two axes, the forces held for the
  next period (N);
* ``lp``: ``LP_*`` parameters.
"""

from __future__ import annotations

# ---- lateral state
LAT_QV, LAT_VV, LAT_QW, LAT_VW, LAT_HV, LAT_HW = range(6)
N_LAT = 8
# ---- lateral parameters
(LP_MV, LP_MW, LP_CV, LP_CW, LP_BV, LP_BW, LP_KU_PER_N, LP_BU_PER_N, LP_DT, LP_NSUB, LP_VSTICK, LP_RES,
 LP_FGV, LP_FGW) = range(14)
N_LP = 16


def lateral_step(lat, lp, fv, fw, g):
    """Advance both lateral axes by one servo period (``LP_NSUB`` semi-implicit Euler substeps).

    Parameters
    ----------
    lat, lp : float64 arrays
        State (updated in place) and parameters (module doc).
    fv, fw : float
        Forces (N) commanded now along the two lateral axes: applied from the next period on.
    g : float
        Grip force (N): the grip impedance is ``k_u g / g_nom``, ``b_u g / g_nom`` (Table 3.1).
    """
    av_f = lat[4]
    aw_f = lat[5]
    lat[4] = fv
    lat[5] = fw
    dt = lp[8]
    nsub = int(lp[9])
    vstick = lp[10]
    ku = lp[6] * g
    bu = lp[7] * g
    for axis in range(2):
        m = lp[0 + axis]
        c = lp[2 + axis]
        b = lp[4 + axis]
        f_ext = (av_f if axis == 0 else aw_f) + lp[12 + axis]
        q = lat[2 * axis]
        v = lat[2 * axis + 1]
        if v == 0.0 and c > 0.0 and vstick > 0.0 and abs(f_ext - ku * q - (bu + b) * v) <= c:
            # at rest and held by static friction: every substep below would find it stuck again, with the
            # same force (q and v unchanged), so the period's result is known without them (the common case:
            # no force across the tap). ``q + 0.0`` as the substeps' ``q += 0.0 * dt`` gives (-0.0 -> 0.0)
            lat[2 * axis] = q + 0.0
            lat[2 * axis + 1] = 0.0
            continue
        for _ in range(nsub):
            f = f_ext - ku * q - (bu + b) * v
            # Karnopp stick-slip Coulomb friction (the 1-DOF kernel's rule, eq. 3.35)
            stuck = False
            if c > 0.0:
                if abs(v) < vstick:
                    if abs(f) <= c:
                        stuck = True
                    else:
                        f += -c if f > 0.0 else c
                else:
                    f += -c if v > 0.0 else c
            if stuck:
                v = 0.0
            else:
                v += f / m * dt
            q += v * dt
        lat[2 * axis] = q
        lat[2 * axis + 1] = v
