"""The 3-D renderer on the 3-DOF simulated device: the 1-DOF equivalence, transients along the normal,
penetration cuts, events, bad scenes and the command."""

import math

import numpy as np
import pytest
import trimesh

import stimuli
from devices.sim import Sim3Device, SimDevice, TapTrajectory
from renderer.config import RendererConfig, load_config
from renderer.loop import ServoLoop
from renderer.loop3 import ServoLoop3, surface_point_above
from renderer.scene import Mesh, Plane, Scene, Sphere
from renderer.scene3 import pack_scene

SPEEDS = [0.05, 0.1, 0.15]


def _one_dof(transient, sample="placeholder", seed=4):
    dev = SimDevice(seed=seed)
    dev.set_sample(sample)
    dev.set_user(TapTrajectory(SPEEDS, n_taps=3), grip_N=2.0)
    return ServoLoop(dev, RendererConfig(stiffness_N_m=680.0), transient).run(duration_s=2.6)


def _three_dof(transient, compiled=True, seed=4):
    dev = Sim3Device(seed=seed)
    dev.set_user(TapTrajectory(SPEEDS, n_taps=3), grip_N=2.0)
    cfg = RendererConfig(stiffness_N_m=680.0, scene=Scene((Plane((0, 0, 0), (0, 0, 1)),)))
    return ServoLoop3(dev, cfg, transient, compiled_sim=compiled).run(duration_s=2.6)


@pytest.fixture(scope="module")
def pairs():
    """The same taps (same seed) on the 1-DOF renderer + sim and on the 3-D renderer + 3-DOF sim, a plane
    normal to z, without and with each parametric transient."""
    out = {}
    for name, tr in (("none", None), ("pulse", stimuli.Pulse()), ("sinusoid", stimuli.DecayingSinusoid())):
        out[name] = (_one_dof(tr), _three_dof(tr))
    return out


@pytest.mark.parametrize("name", ["none", "pulse", "sinusoid"])
def test_a_plane_normal_to_z_reproduces_the_1dof_traces(pairs, name):
    a, b = pairs[name]
    assert len(a.log["position_m"]) == len(b.log["z_m"]) == 26000
    assert np.max(np.abs(a.log["position_m"] - b.log["z_m"])) <= 1e-9
    assert np.max(np.abs(a.log["current_A"] * 2.35 - b.log["force_z_N"])) <= 1e-6
    assert np.max(np.abs(b.log["x_m"])) == 0.0 and np.max(np.abs(b.log["y_m"])) == 0.0
    assert [e.tick for e in a.events] == [e.tick for e in b.events] and len(a.events) == 3
    for ea, eb in zip(a.events, b.events):
        assert eb.incoming_velocity_m_s == pytest.approx(ea.incoming_velocity_m_s, abs=1e-9)
        assert eb.max_penetration_m == pytest.approx(ea.max_penetration_m, abs=1e-9)
        assert (eb.normal_x, eb.normal_y, eb.normal_z) == (0.0, 0.0, 1.0) and eb.object == "plane0"


def test_the_per_tick_3d_loop_gives_the_compiled_loops_numbers(pairs):
    b = pairs["pulse"][1]
    c = _three_dof(stimuli.Pulse(), compiled=False)
    assert np.array_equal(b.log["z_m"], c.log["z_m"]) and np.array_equal(b.log["force_z_N"], c.log["force_z_N"])


def test_the_penetration_cut_equals_the_1dof_figures(pairs):
    """Cut = depth without the transient / with it, per tap: the same on both renderers for a plane normal to z."""
    def cuts(k):
        base = [e.max_penetration_m for e in pairs["none"][k].events]
        return {t: [b / e.max_penetration_m for b, e in zip(base, pairs[t][k].events)] for t in ("pulse", "sinusoid")}
    one, three = cuts(0), cuts(1)
    for t in ("pulse", "sinusoid"):
        np.testing.assert_allclose(three[t], one[t], rtol=1e-9)
        assert min(one[t]) > 1.1        # the transients do cut (Table 4.1's, docs/sim.md: ~2.1x and ~1.4x)


def test_the_3dof_sim_is_the_1dof_sim_along_the_tap_by_construction():
    one, three = SimDevice(seed=2), Sim3Device(seed=2)
    assert np.array_equal(one._p, three.tap._p)          # the same parameter array, untouched by a vertical tap
    three.set_user(TapTrajectory(0.1), grip_N=2.0, target_m=(0.01, -0.02, 0.005), direction=(1.0, 0.0, -1.0))
    one.set_user(TapTrajectory(0.1), grip_N=2.0)
    assert np.array_equal(one._p, three.tap._p)          # any direction: a Cartesian endpoint is isotropic
    u = np.array(three.tap_axis)
    np.testing.assert_allclose(u, [-math.sqrt(0.5), 0.0, math.sqrt(0.5)], atol=1e-15)


def _tap_events(scene, direction, target, transient=None, k=680.0, taps=2, linkage=None, shading=False):
    dev = Sim3Device(seed=1, linkage=linkage)
    dev.set_user(TapTrajectory([0.08, 0.12], n_taps=taps), grip_N=2.0, target_m=target, direction=direction)
    loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=k, scene=scene), transient or stimuli.Pulse())
    res = loop.run(duration_s=TapTrajectory([0.08, 0.12], n_taps=taps).duration_s)
    return res, loop


def _angles_deg(res, normals):
    """Largest angle (deg) between the played transient force and the given normal, per event."""
    tv = np.stack([res.log["transient_x_N"], res.log["transient_y_N"], res.log["transient_z_N"]], axis=1)
    out = []
    for ev, n in zip(res.events, normals):
        seg = tv[ev.tick + 1:ev.tick + 1 + ev.transient_samples]
        mag = np.linalg.norm(seg, axis=1)
        seg = seg[mag > 1e-9]
        assert len(seg) > 50
        cos = (seg @ np.asarray(n)) / np.linalg.norm(seg, axis=1)
        out.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max()))
    return out


def test_transients_push_along_the_contact_normal_on_tilted_planes_spheres_and_mesh_facets(tmp_path):
    n = np.array([0.4, -0.3, 1.0]) / np.linalg.norm([0.4, -0.3, 1.0])
    res, _ = _tap_events(Scene((Plane((0, 0, 0), tuple(n)),)), -n, (0.0, 0.0, 0.0))
    assert len(res.events) == 2 and max(_angles_deg(res, [n, n])) < 1.0
    # a sphere tapped obliquely: the normal at the contact point
    res, _ = _tap_events(Scene((Sphere((0.0, 0.0, -0.01), 0.01),)), (0.3, 0.0, -1.0), (-0.003, 0.0, 0.0))
    normals = [np.array([e.x_m, e.y_m, e.z_m + 0.01]) / np.linalg.norm([e.x_m, e.y_m, e.z_m + 0.01])
               for e in res.events]
    assert len(res.events) == 2 and max(_angles_deg(res, normals)) < 1.0
    # a mesh facet (an icosphere read from STL): the facet's normal
    path = tmp_path / "ico.stl"
    trimesh.creation.icosphere(subdivisions=1, radius=0.015).export(path)
    scene = Scene((Mesh(str(path), offset_m=(0.0, 0.0, -0.015)),))
    pk = pack_scene(scene, 680.0)
    point, normal, _ = surface_point_above(pk)
    res, _ = _tap_events(scene, (0.0, 0.0, -1.0), point)
    assert len(res.events) == 2
    facet = [np.array([e.normal_x, e.normal_y, e.normal_z]) for e in res.events]
    np.testing.assert_allclose(facet[0], normal, atol=1e-12)
    assert max(_angles_deg(res, facet)) < 1.0


def test_a_study_can_place_samples_on_a_table_and_tap_each_by_name():
    cfg = load_config("examples/samples_table.toml")
    dev = Sim3Device(seed=0)
    pk = pack_scene(cfg.effective_scene, cfg.stiffness_N_m, dev.info.specs())
    seen = {}
    for name in ("pulse_firm", "soft", "sinusoid_soft", "hfam_firm"):
        point, normal, hit = surface_point_above(pk, name)
        assert hit == name and normal == pytest.approx((0.0, 0.0, 1.0))
        dev.set_user(TapTrajectory(0.1, n_taps=1), grip_N=2.0, target_m=point)
        res = ServoLoop3(dev, cfg).run(duration_s=TapTrajectory(0.1, n_taps=1).duration_s)
        assert [e.object for e in res.events] == [name]
        seen[name] = res.events[0]
    assert seen["pulse_firm"].transient == "pulse" and seen["soft"].transient == "none"
    assert seen["hfam_firm"].transient == "hfam" and seen["hfam_firm"].transient_samples > 0
    assert seen["soft"].max_penetration_m > 1.3 * seen["pulse_firm"].max_penetration_m
    with pytest.raises(ValueError, match="no object named 'cork'"):
        surface_point_above(pk, "cork")


def test_a_linkage_makes_the_endpoint_impedance_direction_dependent():
    """The same tap down and sideways: identical on the Cartesian device; on the delta and the serial arm the
    tap axis carries the linkage's inertia along it (u^T J^-T M_q J^-1 u) and its friction, and the taps differ."""
    from devices.sim.layout import P_MH
    from devices.sim.linkage import LINKAGES
    depth, mass, speed = {}, {}, {}
    for linkage in (None, "delta", "serial"):
        for label, direction, normal in (("down", (0, 0, -1), (0, 0, 1)), ("side", (1, 0, 0), (-1, 0, 0))):
            scene = Scene((Plane((0, 0, 0), normal),))
            res, loop = _tap_events(scene, direction, (0.0, 0.0, 0.0), transient=stimuli.NoTransient(), taps=1,
                                    linkage=linkage)
            assert len(res.events) == 1, (linkage, label)
            depth[(linkage, label)] = res.events[0].max_penetration_m
            mass[(linkage, label)] = loop.device.tap._p[P_MH]
            speed[(linkage, label)] = res.events[0].incoming_velocity_m_s
    # every tap arrives near the planned 0.08 m/s (the linkage's friction and inertia slow it a little)
    assert all(0.07 < v < 0.085 for v in speed.values()), speed
    assert depth[(None, "down")] == depth[(None, "side")]
    for linkage in ("delta", "serial"):
        m_x = LINKAGES[linkage].endpoint_inertia((0.0, 0.0, 0.0))
        assert mass[(linkage, "down")] == pytest.approx(0.014 + m_x[2, 2], rel=1e-12)
        assert mass[(linkage, "side")] == pytest.approx(0.014 + m_x[0, 0], rel=1e-12)
        assert abs(depth[(linkage, "down")] / depth[(linkage, "side")] - 1.0) > 0.015


def test_the_persons_reflex_discounts_the_drag_a_linkage_adds_along_the_tap():
    """The person's contact reflex (0.3 N) is raised along a linkage's tap axis by the friction it adds plus its
    inertia times the plan's ramp acceleration (0.08 m/s over 20 ms: 4 m/s^2), so the grip's load of the tool's
    own drag at the end of the approach is not taken for the surface; a Cartesian endpoint keeps the person."""
    from devices.sim.layout import P_HAND_FTHR
    from devices.sim.linkage import LINKAGES
    for linkage, direction in ((None, (1.0, 0.0, 0.0)), ("delta", (0.0, 0.0, -1.0)), ("serial", (1.0, 0.0, 0.0))):
        dev = Sim3Device(seed=1, linkage=linkage)
        dev.set_user(TapTrajectory([0.08, 0.12], n_taps=1), grip_N=2.0, direction=direction)
        if linkage is None:
            assert dev.tap._p[P_HAND_FTHR] == 0.3
            continue
        u = -np.asarray(direction)
        link = LINKAGES[linkage]
        extra = link.friction_along((0, 0, 0), u) + float(u @ link.endpoint_inertia((0, 0, 0)) @ u) * 0.08 / 0.02
        assert dev.tap._p[P_HAND_FTHR] == pytest.approx(0.3 + extra, rel=1e-12)
        assert extra > 0.07
    dev = Sim3Device(seed=1, linkage="serial")
    dev.set_user(TapTrajectory(0.08), grip_N=2.0, direction=(1.0, 0.0, 0.0), hand="prescribed")
    assert dev.tap.hand == "prescribed"


BAD = {
    "open": ("mesh", "not closed"),
    "empty": ("mesh", "empty"),
    "degenerate": ("mesh", "degenerate triangle"),
    "huge": ("box", "beyond the device's workspace"),
    "stiff": ("sphere", "above the device's stable bound"),
    "zero_normal": ("plane", "non-zero vector"),
}


def _bad_scene(tmp_path, kind):
    obj = {
        "open": '{ shape = "mesh", path = "open.stl", name = "lid" }',
        "empty": '{ shape = "mesh", path = "empty.obj", name = "lid" }',
        "degenerate": '{ shape = "mesh", path = "degenerate.obj", name = "lid" }',
        "huge": '{ shape = "box", center_m = [0, 0, -0.05], half_extents_m = [0.2, 0.2, 0.01], name = "lid" }',
        "stiff": '{ shape = "sphere", center_m = [0, 0, -0.01], radius_m = 0.01, stiffness_N_m = 1e5, name = "lid" }',
        "zero_normal": '{ shape = "plane", point_m = [0, 0, 0], normal = [0, 0, 0], name = "lid" }',
    }[kind]
    box = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    trimesh.Trimesh(box.vertices, box.faces[:-1]).export(tmp_path / "open.stl")
    (tmp_path / "empty.obj").write_text("# nothing\n")
    verts = np.vstack([box.vertices, [[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.002, 0.0, 0.0]]])
    (tmp_path / "degenerate.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in verts) +
                                             "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces) +
                                             "f 9 10 11\n")
    path = tmp_path / f"{kind}.toml"
    path.write_text(f'stiffness_N_m = 680.0\n[scene]\nobjects = [ {{ shape = "plane", point_m = [0, 0, -0.02], '
                    f'normal = [0, 0, 1], name = "table" }}, {obj} ]\n')
    return path


@pytest.mark.parametrize("kind", sorted(BAD))
def test_a_bad_scene_is_one_error_line_naming_file_and_object_and_nothing_reaches_a_motor(tmp_path, kind, capsys):
    from renderer.__main__ import main
    path = _bad_scene(tmp_path, kind)
    code = main(["run", "--device", "sim:3d", "--config", str(path), "--taps", "1", "--out", str(tmp_path / "out"),
                 "--no-figure"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error: ") and str(path) in err[0], err
    assert BAD[kind][1] in err[0]
    assert "objects[1]" in err[0]
    if kind != "zero_normal":
        assert "(lid)" in err[0]
    assert not (tmp_path / "out").exists()


def test_nothing_is_commanded_before_a_bad_scene_is_refused(tmp_path):
    class Spy(Sim3Device):
        sent = 0

        def _send_force(self, *f):
            Spy.sent += 1
            super()._send_force(*f)

    cfg = load_config(_bad_scene(tmp_path, "stiff"))
    dev = Spy()
    with pytest.raises(ValueError, match="stable bound"):
        ServoLoop3(dev, cfg).run(duration_s=0.1)
    assert Spy.sent == 0 and not dev.is_open


def test_renderer_run_draws_a_3d_run(tmp_path, capsys):
    from renderer.__main__ import main
    from renderer.loop import RunResult
    out = tmp_path / "run"
    code = main(["run", "--device", "sim:3d", "--config", "examples/samples_table.toml", "--tap-object",
                 "pulse_firm", "--taps", "2", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    for name in ("events.csv", "run.json", "log.npz", "run.png", "run.svg", "run.plot.csv"):
        assert (out / name).is_file()
    text = (out / "events.csv").read_text().splitlines()
    assert text[0].endswith("object,normal_x,normal_y,normal_z,x_m,y_m,z_m") and len(text) == 3
    assert ",pulse_firm," in text[1]
    res = RunResult.load(out)
    assert "proxy_z_m" in res.log and len(res.events) == 2


def test_a_1dof_wall_scene_on_the_3dof_device_renders_along_z_with_x_and_y_held(pairs):
    """The default scene (one horizontal wall) on sim:3d: the hold channel keeps x and y at their start, and z
    is the 1-DOF run's (the hold's forces are lateral: the tap axis never sees them)."""
    dev = Sim3Device(seed=4)
    dev.set_user(TapTrajectory(SPEEDS, n_taps=3), grip_N=2.0)
    loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=680.0))
    res = loop.run(duration_s=2.6)
    assert res.timing["hold_channel"] is True
    assert np.max(np.abs(res.log["z_m"] - pairs["none"][0].log["position_m"])) <= 1e-9
    assert np.max(np.abs(res.log["x_m"])) == 0.0
    # a tap 17 degrees off vertical: the hold keeps the endpoint within a fifth of the free lateral travel
    travel = {}
    for scene in (Scene((loop.scene.objects[0],)), Scene((Plane((0, 0, 0), (0, 0, 1)),))):
        dev = Sim3Device(seed=4)
        dev.set_user(TapTrajectory([0.1], n_taps=2), grip_N=2.0, direction=(0.3, 0.0, -1.0))
        res = ServoLoop3(dev, RendererConfig(stiffness_N_m=680.0, scene=scene)).run(duration_s=1.5)
        travel[res.timing["hold_channel"]] = np.ptp(res.log["x_m"])
    assert travel[True] < 0.25 * travel[False]


def test_with_force_shading_the_transient_follows_the_interpolated_normal(tmp_path):
    """An icosphere (80 facets) tapped off a vertex with force shading: its vertex normals are radial, so the
    shaded normal at the contact is nearly the sphere's; the transient follows it, not the facet's."""
    from renderer.scene import SurfaceProps
    path = tmp_path / "ico.stl"
    trimesh.creation.icosphere(subdivisions=1, radius=0.015).export(path)
    centre = np.array([0.0, 0.0, -0.015])
    scene = Scene((Mesh(str(path), offset_m=tuple(centre), props=SurfaceProps(force_shading=True)),))
    res, _ = _tap_events(scene, (0.0, 0.0, -1.0), (0.004, 0.003, 0.0))
    assert len(res.events) == 2
    for ev in res.events:
        facet = np.array([ev.normal_x, ev.normal_y, ev.normal_z])
        radial = np.array([ev.x_m, ev.y_m, ev.z_m]) - centre
        radial /= np.linalg.norm(radial)
        tv = np.stack([res.log[f"transient_{a}_N"][ev.tick + 1:ev.tick + 20] for a in "xyz"], axis=1)
        tv = tv[np.linalg.norm(tv, axis=1) > 0]
        direction = tv[0] / np.linalg.norm(tv[0])
        off_facet = math.degrees(math.acos(min(1.0, float(facet @ direction))))
        off_radial = math.degrees(math.acos(min(1.0, float(radial @ direction))))
        facet_radial = math.degrees(math.acos(min(1.0, float(facet @ radial))))
        assert off_facet > 1.0                     # shading turned the transient off the facet's normal ...
        assert off_radial < 0.5 * facet_radial     # ... towards the smooth surface's
