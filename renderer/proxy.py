"""The god-object (finger-proxy) point proxy of the 3-D renderer, compiled (numba): no allocation per tick.

Zilles & Salisbury 1995 ("god object"), Ruspini, Kolarov & Khatib 1997 (finger proxy), as CHAI3D's
``cAlgorithmFingerProxy``: the proxy is a point that never enters an object. Each tick it moves from where
it is towards the goal (the device's endpoint) along a straight segment; the first surface the segment
crosses stops it there (continuous collision: whatever the speed, nothing is tunnelled through) and
becomes a constraint plane (the surface's tangent plane at the hit); the goal is then projected onto the
constraint planes -- one plane, the line where two meet, the corner of three -- and the proxy swept again
towards the projection, up to three constraints. The proxy rests ``EPS_M`` outside the surface it touches.

Friction (CHAI3D's stick-slip): with ``d_n`` the depth of the endpoint behind the surface and ``t`` the
proxy's tangential offset from the endpoint, the proxy stays where it was while ``|t| <= mu_s d_n`` (the
tangential force ``k |t|`` within the static cone), else it slides to ``mu_d d_n`` of the frictionless
position (the tangential force ``mu_d`` times the normal force); once sliding, the dynamic cone decides
when it sticks again.

Scene arrays: ``renderer.scene3`` (object table, triangles, BVH nodes). Proxy state ``ps`` (``PS_*``,
``renderer.proxy_layout``).
"""

from __future__ import annotations

import math

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

# the proxy state's layout (numba-free, shared with renderer.law3 and renderer.loop3)
from .proxy_layout import (  # noqa: F401 -- re-exported: proxy.PS_*, proxy.N_PS, proxy.EPS_M
    BARY_TOL, EPS_M, N_PS, PS_NC, PS_NX, PS_NY, PS_NZ, PS_OBJ, PS_PX, PS_PY, PS_PZ, PS_SLIP, PS_SNX, PS_SNY,
    PS_SNZ, PS_SX, PS_SY, PS_SZ, PS_WAS,
)
from .scene3 import K_MESH, K_PLANE, K_SPHERE, O_A0, O_A1, O_KIND, O_MUD, O_MUS, O_SHADE

INF = math.inf


@njit(cache=True, _nrt=False, inline="always")
def _seg_box(lo0, lo1, lo2, hi0, hi1, hi2, ax, ay, az, ix, iy, iz):
    """Whether segment a + t d, t in [0, 1] (``i`` = 1/d per axis, inf for 0) meets the box (slab test)."""
    t0 = 0.0
    t1 = 1.0
    for k in range(3):
        if k == 0:
            a, inv, lo, hi = ax, ix, lo0, hi0
        elif k == 1:
            a, inv, lo, hi = ay, iy, lo1, hi1
        else:
            a, inv, lo, hi = az, iz, lo2, hi2
        if inv == INF or inv == -INF:
            if a < lo or a > hi:
                return False
            continue
        ta = (lo - a) * inv
        tb = (hi - a) * inv
        if ta > tb:
            ta, tb = tb, ta
        if ta > t0:
            t0 = ta
        if tb < t1:
            t1 = tb
        if t0 > t1:
            return False
    return True


@njit(cache=True, _nrt=False)
def _seg_mesh(tri, node, stack, n0, ax, ay, az, dx, dy, dz, tbest):
    """Earliest front-face hit (t < ``tbest``) of segment a + t d on the mesh whose BVH root is ``n0``.

    Returns (t, triangle index, barycentric u, v); t = inf for none. Möller-Trumbore per triangle."""
    ix = 1.0 / dx if dx != 0.0 else INF
    iy = 1.0 / dy if dy != 0.0 else INF
    iz = 1.0 / dz if dz != 0.0 else INF
    best_t = tbest
    best_i = -1
    bu = 0.0
    bv = 0.0
    sp = 0
    stack[0] = n0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp]
        if not _seg_box(node[i, 0], node[i, 1], node[i, 2], node[i, 3], node[i, 4], node[i, 5], ax, ay, az, ix, iy, iz):
            continue
        a = node[i, 6]
        if a >= 0.0:
            stack[sp] = int(a)
            stack[sp + 1] = int(node[i, 7])
            sp += 2
            continue
        s = int(-a) - 1
        for q in range(s, s + int(node[i, 7])):
            # front faces only (the segment enters the solid): d . n < 0
            if dx * tri[q, 9] + dy * tri[q, 10] + dz * tri[q, 11] >= 0.0:
                continue
            e1x, e1y, e1z = tri[q, 3], tri[q, 4], tri[q, 5]
            e2x, e2y, e2z = tri[q, 6], tri[q, 7], tri[q, 8]
            px = dy * e2z - dz * e2y
            py = dz * e2x - dx * e2z
            pz = dx * e2y - dy * e2x
            det = e1x * px + e1y * py + e1z * pz
            if det <= 0.0:
                continue
            inv = 1.0 / det
            sx = ax - tri[q, 0]
            sy = ay - tri[q, 1]
            sz = az - tri[q, 2]
            u = (sx * px + sy * py + sz * pz) * inv
            if u < -BARY_TOL or u > 1.0 + BARY_TOL:
                continue
            qx = sy * e1z - sz * e1y
            qy = sz * e1x - sx * e1z
            qz = sx * e1y - sy * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < -BARY_TOL or u + v > 1.0 + BARY_TOL:
                continue
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            # a start within rounding behind the face (the proxy rests EPS_M outside) counts as t = 0
            if t < -1e-6 or t >= best_t:
                continue
            if t < 0.0:
                t = 0.0
            best_t = t
            best_i = q
            bu = u
            bv = v
    if best_i < 0:
        return INF, -1, 0.0, 0.0
    return best_t, best_i, bu, bv


@njit(cache=True, _nrt=False, inline="always")
def first_hit(obj, tri, node, stack, ax, ay, az, bx, by, bz):
    """The first surface the segment a -> b enters, over all objects.

    Returns
    -------
    t : float
        Segment parameter of the hit in [0, 1], inf for none.
    j : int
        The object hit (-1 for none).
    nx, ny, nz : float
        Its outward unit normal there.
    snx, sny, snz : float
        The shaded normal (vertex normals interpolated; the normal itself without shading).
    sx, sy, sz : float
        A point of the surface: the plane's own point for a plane (so a wall's depth is exact), the hit.
    """
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    best_t = INF
    best_j = -1
    nx = ny = nz = 0.0
    snx = sny = snz = 0.0
    sx = sy = sz = 0.0
    for j in range(obj.shape[0]):
        kind = obj[j, O_KIND]
        if kind == K_PLANE:
            qx, qy, qz = obj[j, O_A0], obj[j, O_A0 + 1], obj[j, O_A0 + 2]
            mx, my, mz = obj[j, O_A0 + 3], obj[j, O_A0 + 4], obj[j, O_A0 + 5]
            s1 = mx * (bx - qx) + my * (by - qy) + mz * (bz - qz)
            if s1 >= 0.0:
                continue
            s0 = mx * (ax - qx) + my * (ay - qy) + mz * (az - qz)
            if s0 <= s1:
                continue
            t = s0 / (s0 - s1) if s0 > 0.0 else 0.0
            if t < best_t:
                best_t, best_j = t, j
                nx, ny, nz = mx, my, mz
                snx, sny, snz = mx, my, mz
                sx, sy, sz = qx, qy, qz
        elif kind == K_SPHERE:
            cx, cy, cz, r = obj[j, O_A0], obj[j, O_A0 + 1], obj[j, O_A0 + 2], obj[j, O_A0 + 3]
            ox, oy, oz = ax - cx, ay - cy, az - cz
            c0 = ox * ox + oy * oy + oz * oz - r * r
            if c0 <= 0.0:
                t = 0.0      # the start on or inside: the hit is where it is
            else:
                a2 = dx * dx + dy * dy + dz * dz
                b2 = ox * dx + oy * dy + oz * dz
                if a2 == 0.0 or b2 >= 0.0:
                    continue
                disc = b2 * b2 - a2 * c0
                if disc < 0.0:
                    continue
                t = (-b2 - math.sqrt(disc)) / a2
                if t > 1.0:
                    continue
                if t < 0.0:
                    t = 0.0
            if t < best_t:
                hx, hy, hz = ox + t * dx, oy + t * dy, oz + t * dz
                hn = math.sqrt(hx * hx + hy * hy + hz * hz)
                if hn == 0.0:
                    hx, hy, hz, hn = 0.0, 0.0, 1.0, 1.0
                best_t, best_j = t, j
                nx, ny, nz = hx / hn, hy / hn, hz / hn
                snx, sny, snz = nx, ny, nz
                sx, sy, sz = cx + r * nx, cy + r * ny, cz + r * nz
        elif kind == K_MESH:
            t, q, u, v = _seg_mesh(tri, node, stack, int(obj[j, O_A0]), ax, ay, az, dx, dy, dz,
                                   best_t if best_t <= 1.0 else 1.0 + 1e-12)
            if q >= 0 and t <= 1.0 and t < best_t:
                best_t, best_j = t, j
                nx, ny, nz = tri[q, 9], tri[q, 10], tri[q, 11]
                sx, sy, sz = ax + t * dx, ay + t * dy, az + t * dz
                if obj[j, O_SHADE] != 0.0:
                    w0 = 1.0 - u - v
                    snx = w0 * tri[q, 12] + u * tri[q, 15] + v * tri[q, 18]
                    sny = w0 * tri[q, 13] + u * tri[q, 16] + v * tri[q, 19]
                    snz = w0 * tri[q, 14] + u * tri[q, 17] + v * tri[q, 20]
                    sn = math.sqrt(snx * snx + sny * sny + snz * snz)
                    if sn > 0.0:
                        snx, sny, snz = snx / sn, sny / sn, snz / sn
                    else:
                        snx, sny, snz = nx, ny, nz
                else:
                    snx, sny, snz = nx, ny, nz
    return best_t, best_j, nx, ny, nz, snx, sny, snz, sx, sy, sz


@njit(cache=True, _nrt=False, inline="always")
def _sweep(obj, tri, node, stack, ps, bx, by, bz):
    """Move the proxy from where it is towards b, stopping ``EPS_M`` outside the first surface crossed.

    Returns (hit object or -1, normal, shaded normal, surface point) of the stop."""
    ax, ay, az = ps[PS_PX], ps[PS_PY], ps[PS_PZ]
    t, j, nx, ny, nz, snx, sny, snz, sx, sy, sz = first_hit(obj, tri, node, stack, ax, ay, az, bx, by, bz)
    if j < 0:
        ps[PS_PX], ps[PS_PY], ps[PS_PZ] = bx, by, bz
        return -1, nx, ny, nz, snx, sny, snz, sx, sy, sz
    hx = ax + t * (bx - ax)
    hy = ay + t * (by - ay)
    hz = az + t * (bz - az)
    # on the surface, then EPS_M out along its normal
    off = nx * (hx - sx) + ny * (hy - sy) + nz * (hz - sz)   # hit's height above the surface (rounding)
    step = EPS_M - off if off < EPS_M else 0.0
    ps[PS_PX] = hx + step * nx
    ps[PS_PY] = hy + step * ny
    ps[PS_PZ] = hz + step * nz
    return j, nx, ny, nz, snx, sny, snz, sx, sy, sz


@njit(cache=True, _nrt=False)
def proxy_step(obj, tri, node, stack, ps, gx, gy, gz):
    """One tick of the proxy towards the goal g (the endpoint, m): module doc. Updates ``ps``.

    Returns
    -------
    n_c : int
        Constraints met this tick (0: free; the proxy is at the goal).
    """
    was = ps[PS_NC] > 0.0
    ox, oy, oz = ps[PS_PX], ps[PS_PY], ps[PS_PZ]
    n1x = n1y = n1z = d1 = n2x = n2y = n2z = d2 = 0.0
    n_c = 0
    bx, by, bz = gx, gy, gz
    j0 = -1
    for it in range(4):
        j, nx, ny, nz, snx, sny, snz, sx, sy, sz = _sweep(obj, tri, node, stack, ps, bx, by, bz)
        if j < 0:
            break
        if n_c == 0:
            j0 = j
            ps[PS_OBJ] = j
            ps[PS_NX], ps[PS_NY], ps[PS_NZ] = nx, ny, nz
            ps[PS_SNX], ps[PS_SNY], ps[PS_SNZ] = snx, sny, snz
            ps[PS_SX], ps[PS_SY], ps[PS_SZ] = sx, sy, sz
        if n_c == 3:
            break
        dd = nx * sx + ny * sy + nz * sz + EPS_M     # the constraint plane n . p = dd (EPS_M outside)
        if n_c == 0:
            n1x, n1y, n1z, d1 = nx, ny, nz, dd
            s = n1x * gx + n1y * gy + n1z * gz - d1
            bx, by, bz = gx - s * n1x, gy - s * n1y, gz - s * n1z
            n_c = 1
        elif n_c == 1:
            lx = n1y * nz - n1z * ny
            ly = n1z * nx - n1x * nz
            lz = n1x * ny - n1y * nx
            ll = lx * lx + ly * ly + lz * lz
            if ll < 1e-12:     # the same plane again (a shared edge): stay on it
                break
            n2x, n2y, n2z, d2 = nx, ny, nz, dd
            # a point of both planes, then the goal projected onto their line
            ax_ = n2y * lz - n2z * ly
            ay_ = n2z * lx - n2x * lz
            az_ = n2x * ly - n2y * lx
            bx_ = ly * n1z - lz * n1y
            by_ = lz * n1x - lx * n1z
            bz_ = lx * n1y - ly * n1x
            x0 = (d1 * ax_ + d2 * bx_) / ll
            y0 = (d1 * ay_ + d2 * by_) / ll
            z0 = (d1 * az_ + d2 * bz_) / ll
            s = (lx * (gx - x0) + ly * (gy - y0) + lz * (gz - z0)) / ll
            bx, by, bz = x0 + s * lx, y0 + s * ly, z0 + s * lz
            n_c = 2
        else:
            # the corner of three planes (Cramer's rule); nearly parallel planes: stay where it is
            c23x = n2y * nz - n2z * ny
            c23y = n2z * nx - n2x * nz
            c23z = n2x * ny - n2y * nx
            det = n1x * c23x + n1y * c23y + n1z * c23z
            n_c = 3
            if abs(det) < 1e-9:
                break
            c31x = ny * n1z - nz * n1y
            c31y = nz * n1x - nx * n1z
            c31z = nx * n1y - ny * n1x
            c12x = n1y * n2z - n1z * n2y
            c12y = n1z * n2x - n1x * n2z
            c12z = n1x * n2y - n1y * n2x
            bx = (d1 * c23x + d2 * c31x + dd * c12x) / det
            by = (d1 * c23y + d2 * c31y + dd * c12y) / det
            bz = (d1 * c23z + d2 * c31z + dd * c12z) / det
    ps[PS_NC] = n_c
    if n_c == 0:
        ps[PS_SLIP] = 0.0
        ps[PS_WAS] = 0.0
        return 0
    # friction: stick-slip against the frictionless position just found
    mus = obj[j0, O_MUS]
    if was and mus > 0.0 and ps[PS_WAS] == j0 + 1.0:
        nx, ny, nz = ps[PS_NX], ps[PS_NY], ps[PS_NZ]
        d_n = nx * (ps[PS_SX] - gx) + ny * (ps[PS_SY] - gy) + nz * (ps[PS_SZ] - gz)
        # tangential offset of the old proxy from the frictionless one
        tx, ty, tz = ox - ps[PS_PX], oy - ps[PS_PY], oz - ps[PS_PZ]
        tn = tx * nx + ty * ny + tz * nz
        tx, ty, tz = tx - tn * nx, ty - tn * ny, tz - tn * nz
        tl = math.sqrt(tx * tx + ty * ty + tz * tz)
        mu = obj[j0, O_MUD] if ps[PS_SLIP] != 0.0 else mus
        if d_n > 0.0 and tl <= mu * d_n:
            ps[PS_PX], ps[PS_PY], ps[PS_PZ] = ox, oy, oz      # stuck: the proxy stays (it was outside)
            ps[PS_SLIP] = 0.0
        elif d_n > 0.0 and tl > 0.0:
            f = obj[j0, O_MUD] * d_n / tl
            fx, fy, fz = ps[PS_PX], ps[PS_PY], ps[PS_PZ]
            # slide to mu_d d_n short of the frictionless position, swept (a chord of a curved surface
            # may dip inside it)
            ps[PS_PX], ps[PS_PY], ps[PS_PZ] = fx, fy, fz
            _sweep(obj, tri, node, stack, ps, fx + f * tx, fy + f * ty, fz + f * tz)
            ps[PS_SLIP] = 1.0
    ps[PS_WAS] = j0 + 1.0
    return n_c


@njit(cache=True, _nrt=False)
def proxy_force(ps, k, gx, gy, gz):
    """The wall force (N) of a proxy in contact: ``k d n`` along the normal (``d`` the endpoint's depth
    behind the surface point) plus ``k`` times the proxy's tangential offset (friction), eq. 2.1 in 3-D.

    Returns (fx, fy, fz, d)."""
    nx, ny, nz = ps[PS_NX], ps[PS_NY], ps[PS_NZ]
    d = nx * (ps[PS_SX] - gx) + ny * (ps[PS_SY] - gy) + nz * (ps[PS_SZ] - gz)
    rx, ry, rz = ps[PS_PX] - gx, ps[PS_PY] - gy, ps[PS_PZ] - gz
    rn = rx * nx + ry * ny + rz * nz
    tx, ty, tz = rx - rn * nx, ry - rn * ny, rz - rn * nz
    fn = k * d
    return fn * nx + k * tx, fn * ny + k * ty, fn * nz + k * tz, d
