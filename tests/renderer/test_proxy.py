"""The god-object proxy (renderer/proxy.py): never inside, no tunnelling, stick-slip friction, transients along
the normal, a passive wall over random 3-D trajectories.

The random sweeps run in numba (the proxy itself is compiled): 10,000 trajectories in a few seconds.
"""

import math

import numpy as np
import pytest
import trimesh

from plumbing.jitcache import njit
from renderer import law3 as L3
from renderer import proxy as PX
from renderer.scene import Box, Mesh, Plane, Scene, Sphere
from renderer.scene3 import K_MESH, K_PLANE, K_SPHERE, O_A0, O_KIND, STACK_DEPTH, pack_scene

N_TRAJ = 10_000
STEPS = 120


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    """A convex 320-triangle icosphere (radius 12 mm) written as STL, read back through trimesh."""
    path = tmp_path_factory.mktemp("mesh") / "ico.stl"
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.012)
    m.export(path)
    return str(path)


@pytest.fixture(scope="module")
def scenes(mesh_file):
    """Scenes whose every object is convex (planes, spheres, boxes, the icosphere): inside is exact."""
    corner = Scene((Plane((0, 0, 0), (0, 0, 1)), Plane((0, 0, 0), (1, 0, 0)), Plane((0, 0, 0), (0, 1, 0))))
    boxes = Scene((Box((0, 0, 0), (0.01, 0.01, 0.01)), Box((0.02, 0.0, -0.005), (0.005, 0.02, 0.003))))
    mixed = Scene((Plane((0, 0, -0.02), (0.2, 0.1, 1.0)), Sphere((0.0, 0.02, 0.0), 0.008),
                   Mesh(mesh_file, offset_m=(0.0, -0.015, 0.0)), Box((0.02, 0.0, 0.0), (0.004, 0.004, 0.004))))
    plate = Scene((Box((0, 0, 0), (0.02, 0.02, 0.0005)),))
    return {name: pack_scene(s, 680.0) for name, s in
            (("corner", corner), ("boxes", boxes), ("mixed", mixed), ("plate", plate))}


@njit(cache=True, _nrt=False)
def _depth(obj, tri, node, stack, x, y, z):
    """Largest penetration (m) of point (x, y, z) into any object (all convex: planes, spheres, convex meshes)."""
    worst = -math.inf
    for j in range(obj.shape[0]):
        kind = obj[j, O_KIND]
        if kind == K_PLANE:
            d = (obj[j, O_A0] - x) * obj[j, O_A0 + 3] + (obj[j, O_A0 + 1] - y) * obj[j, O_A0 + 4] + \
                (obj[j, O_A0 + 2] - z) * obj[j, O_A0 + 5]
        elif kind == K_SPHERE:
            d = obj[j, O_A0 + 3] - math.sqrt((x - obj[j, O_A0]) ** 2 + (y - obj[j, O_A0 + 1]) ** 2 +
                                             (z - obj[j, O_A0 + 2]) ** 2)
        else:
            # a convex mesh: the smallest distance behind its face planes, over its BVH's leaves
            d = math.inf
            sp = 1
            stack[0] = int(obj[j, O_A0])
            while sp > 0:
                sp -= 1
                i = stack[sp]
                if node[i, 6] >= 0:
                    stack[sp] = int(node[i, 6])
                    stack[sp + 1] = int(node[i, 7])
                    sp += 2
                    continue
                s = int(-node[i, 6]) - 1
                for q in range(s, s + int(node[i, 7])):
                    e = (tri[q, 0] - x) * tri[q, 9] + (tri[q, 1] - y) * tri[q, 10] + (tri[q, 2] - z) * tri[q, 11]
                    if e < d:
                        d = e
        if d > worst:
            worst = d
    return worst


@njit(cache=True, _nrt=False)
def _sweep_random(obj, tri, node, stack, ps, seed, n_traj, steps, span, jump):
    """Random endpoint paths (a random walk with occasional jumps of up to ``jump`` m, aimed at objects,
    edges, vertices and corners); returns (worst proxy depth, contact ticks, worst depth of the proxy
    *before* it met anything, i.e. a check of the checker)."""
    np.random.seed(seed)
    worst = -math.inf
    contacts = 0
    for _ in range(n_traj):
        # start outside everything, well above
        ps[0], ps[1], ps[2] = 0.0, 0.0, 0.2
        ps[3] = 0.0
        ps[14] = 0.0
        ps[15] = 0.0
        gx = (np.random.random() - 0.5) * span
        gy = (np.random.random() - 0.5) * span
        gz = (np.random.random() - 0.5) * span
        for _ in range(steps):
            if np.random.random() < 0.1:
                gx = (np.random.random() - 0.5) * span
                gy = (np.random.random() - 0.5) * span
                gz = (np.random.random() - 0.5) * span
            else:
                gx += (np.random.random() - 0.5) * jump
                gy += (np.random.random() - 0.5) * jump
                gz += (np.random.random() - 0.5) * jump
            if PX.proxy_step(obj, tri, node, stack, ps, gx, gy, gz) > 0:
                contacts += 1
            d = _depth(obj, tri, node, stack, ps[0], ps[1], ps[2])
            if d > worst:
                worst = d
    return worst, contacts


@pytest.mark.parametrize("name", ["corner", "boxes", "mixed", "plate"])
def test_the_proxy_is_never_inside_any_object_over_random_trajectories(scenes, name):
    pk = scenes[name]
    stack = np.zeros(STACK_DEPTH, np.int64)
    ps = np.zeros(PX.N_PS)
    span = 0.06 if name == "mixed" else 0.03
    worst, contacts = _sweep_random(pk.obj, pk.tri, pk.node, stack, ps, 7, N_TRAJ, STEPS, span, 0.004)
    assert contacts > 0.15 * N_TRAJ * STEPS   # many ticks press into something
    assert worst <= 1e-12, f"{name}: the proxy went {worst:.3g} m inside"   # it rests 1 nm outside
    assert worst > -1e-6      # and it does touch (within a micrometre of a surface)
    # the checker finds an endpoint inside
    assert _depth(pk.obj, pk.tri, pk.node, stack, 0.0, 0.0, -0.0001) > 0 or name == "mixed"


def test_three_plane_corner_holds_the_proxy_at_the_corner(scenes):
    pk = scenes["corner"]
    stack = np.zeros(STACK_DEPTH, np.int64)
    ps = np.zeros(PX.N_PS)
    ps[:3] = (0.01, 0.01, 0.01)
    n_c = PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, -0.004, -0.003, -0.005)
    assert n_c == 3
    np.testing.assert_allclose(ps[:3], [PX.EPS_M] * 3, atol=1e-12)


@pytest.mark.parametrize("speed", [2.0, 20.0])
def test_no_tunnelling_through_a_1_mm_plate(scenes, speed):
    """A tap at 2 m/s (0.2 mm per 10 kHz tick) and a 2 mm jump per tick (20 m/s) through a 1 mm plate."""
    pk = scenes["plate"]
    stack = np.zeros(STACK_DEPTH, np.int64)
    for x0, y0 in ((0.0, 0.0), (0.0199, -0.0199), (0.02, 0.0), (0.003, 0.02)):   # the middle, a corner, edges
        ps = np.zeros(PX.N_PS)
        ps[:3] = (x0, y0, 0.01)
        z = 0.01
        below = 0
        while z > -0.01:
            z -= speed * 1e-4
            PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, x0, y0, z)
            assert ps[2] >= 0.0005, f"tunnelled at ({x0}, {y0}): proxy z {ps[2]}"
            below += z < -0.0005
        assert below > 0   # the endpoint did pass below the plate


def _press_and_push(mu_s, mu_d, k, depth, push_force):
    """Press 'depth' into a plane with friction, then push tangentially until ``k * offset`` reaches
    ``push_force`` and beyond; returns (proxy travel while below it, tangential force while sliding)."""
    pk = pack_scene(Scene((Plane((0, 0, 0), (0, 0, 1)),)), k)
    pk.obj[0, 2], pk.obj[0, 3] = mu_s, mu_d
    stack = np.zeros(STACK_DEPTH, np.int64)
    ps = np.zeros(PX.N_PS)
    ps[:3] = (0.0, 0.0, 0.01)
    PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, 0.0, 0.0, -depth)
    start = ps[0]
    hold_travel, sliding, below = 0.0, [], True
    for i in range(1, 4001):
        x = i * 2e-6          # 2 um per tick: 20 mm/s
        PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, x, 0.0, -depth)
        fx, fy, fz, d = PX.proxy_force(ps, k, x, 0.0, -depth)
        below = below and -fx <= push_force    # until the push first exceeds push_force
        if below:
            hold_travel = max(hold_travel, abs(ps[0] - start))
        if ps[14] != 0.0:
            sliding.append(-fx / fz)
    return hold_travel, np.array(sliding)


def test_friction_sticks_below_the_static_limit_and_slides_at_the_dynamic_force():
    mu_s, mu_d, k, depth = 0.6, 0.35, 1000.0, 0.002      # normal force 2 N
    travel, ratio = _press_and_push(mu_s, mu_d, k, depth, 0.98 * mu_s * k * depth)
    assert travel == 0.0                       # below the static limit: the proxy does not move at all
    assert len(ratio) > 1000                   # above it: it slides
    assert np.median(ratio) == pytest.approx(mu_d, rel=0.02)
    assert np.all(np.abs(ratio - mu_d) <= 0.02 * mu_d)
    # the break-away force: the largest tangential force before sliding is the static one (within 2 %)
    pk = pack_scene(Scene((Plane((0, 0, 0), (0, 0, 1)),)), k)
    pk.obj[0, 2], pk.obj[0, 3] = mu_s, mu_d
    stack, ps = np.zeros(STACK_DEPTH, np.int64), np.zeros(PX.N_PS)
    ps[:3] = (0, 0, 0.01)
    PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, 0.0, 0.0, -depth)
    peak = 0.0
    for i in range(1, 3000):
        PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, i * 2e-6, 0.0, -depth)
        fx, _, fz, _ = PX.proxy_force(ps, k, i * 2e-6, 0.0, -depth)
        peak = max(peak, -fx / fz)
    assert peak == pytest.approx(mu_s, rel=0.02)


def test_frictionless_contact_pushes_along_the_normal_only(scenes):
    pk = pack_scene(Scene((Plane((0, 0, 0), (0.3, -0.2, 1.0)),)), 500.0)
    n = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    stack, ps = np.zeros(STACK_DEPTH, np.int64), np.zeros(PX.N_PS)
    ps[:3] = (0.0, 0.0, 0.01)
    for g in ([0.0, 0.0, -0.002], [0.004, 0.001, -0.003], [-0.01, 0.02, -0.001]):
        PX.proxy_step(pk.obj, pk.tri, pk.node, stack, ps, *g)
        f = np.array(PX.proxy_force(ps, 500.0, *g)[:3])
        depth = float(np.dot(-np.asarray(g), n))
        np.testing.assert_allclose(f, 500.0 * depth * n, rtol=1e-9, atol=1e-12)


@njit(cache=True, _nrt=False)
def _observer_sweep(c, w0, w, obj, tri, node, stack, log, seed, n_traj, steps, dt, status):
    """Random smooth endpoint paths through the scene fed to the 3-D law; the peak observer energy (J).
    ``status``: the device status of every tick, an argument so that the law gets the int64 of every caller (a
    constant 0 here would be typed Literal[int](0): a compile of the law of its own)."""
    np.random.seed(seed)
    peak = 0.0
    for _ in range(n_traj):
        for i in range(w.shape[0]):
            w[i] = w0[i]
        x, y, z = w0[L3.W_LX], w0[L3.W_LY], w0[L3.W_LZ]
        vx = vy = vz = 0.0
        for k in range(steps):
            # a random smooth path: a velocity that wanders (up to ~0.3 m/s), aimed down into the scene
            vx += (np.random.random() - 0.5) * 0.08
            vy += (np.random.random() - 0.5) * 0.08
            vz += (np.random.random() - 0.55) * 0.08
            s = math.sqrt(vx * vx + vy * vy + vz * vz)
            if s > 0.3:
                vx, vy, vz = vx * 0.3 / s, vy * 0.3 / s, vz * 0.3 / s
            x += vx * dt
            y += vy * dt
            z += vz * dt
            L3.law3_tick(c, w, obj, tri, node, stack, log, k * dt, x, y, z, 0.0, 2.0, status)
            if w[L3.W_PO_E] > peak:
                peak = w[L3.W_PO_E]
            if w[L3.W_CODE] >= 4:
                return peak
    return peak


def test_the_passivity_observer_stays_bounded_over_random_3d_trajectories(scenes, mesh_file):
    from devices.sim import Sim3Device
    from renderer.config import RendererConfig
    from renderer.loop3 import ServoLoop3
    scene = Scene((Plane((0, 0, -0.004), (0.1, 0.2, 1.0)), Sphere((0.006, 0.0, -0.002), 0.006),
                   Mesh(mesh_file, offset_m=(-0.01, 0.0, -0.01)), Box((0.0, 0.012, -0.004), (0.004, 0.004, 0.004))))
    dev = Sim3Device()
    dev.set_user(0.002, grip_N=2.0, target_m=(0.0, 0.0, 0.0))
    loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=1020.0, scene=scene))
    loop.prepare()
    loop.cap = 4
    loop.c[L3.C_CAP] = 4
    loop.log = np.zeros((L3.N_LOG, 4))
    with dev:
        loop._prime()
    w0 = loop.w.copy()
    w = loop.w
    pk = loop.packed
    peak = _observer_sweep(loop.c, w0, w, pk.obj, pk.tri, pk.node, loop.stack, loop.log, 3, N_TRAJ, 300, 1e-4, 0)
    limit = loop.c[L3.C_PO_LIMIT]
    assert np.isfinite(peak) and peak > 0.0
    assert peak < 0.5 * limit, f"peak observer energy {peak:.3g} J of the limit {limit:.3g} J"
