"""The 3-D simulated loop compiled ahead of time (renderer.sim_aot.LOOP3) against the JIT one: the same proxy,
law and physics, the same log tick for tick; built by the background builder after a first 3-D run; loaded
without numba, scipy or trimesh; the two builds kept apart."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from devices.sim import Sim3Device, TapTrajectory
from devices.sim import lateral as LAT
from renderer import sim_aot
from renderer.config import load_config
from renderer.loop3 import ServoLoop3, surface_point_above
from renderer.scene3 import pack_scene

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "examples" / "samples_table.toml"


def _cli_run(env, out, *extra):
    return subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim:3d", "--taps", "1", "--no-figure",
                           "--out", str(out), *extra], env=env, cwd=ROOT, capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def aot3_dir(tmp_path_factory):
    """One 3-D build for the module, made the way users get it: the first ``renderer run --device sim:3d``
    (JIT) starts the detached background builder of the 3-D loop; the next run uses the build."""
    base = tmp_path_factory.mktemp("sim3-loop")
    runs = tmp_path_factory.mktemp("runs3")
    env = {**os.environ, "HFAM_SIM_AOT_DIR": str(base), "HFAM_SIM_AOT": "auto"}
    first = _cli_run(env, runs / "first")
    assert first.returncode == 0, first.stderr
    assert "compiling the simulated 3-D loop ahead of time in the background" in first.stderr
    assert json.loads((runs / "first" / "run.json").read_text())["aot"] is False
    key = sim_aot.source_key(sim_aot.LOOP3)
    ext = sim_aot.extension_path(key, base, sim_aot.LOOP3)
    deadline = time.monotonic() + 400.0
    while not ext.is_file() and time.monotonic() < deadline:
        assert not (base / f"{key}.failed").exists(), (base / f"{key}.failed").read_text()
        time.sleep(0.5)
    assert ext.is_file(), "the background 3-D build did not finish in 400 s"
    assert not (base / f"{key}.lock").exists()
    manifest = json.loads((ext.parent / "manifest.json").read_text())
    assert manifest["key"] == key and manifest["module"] == "_hfam_sim3_loop"
    assert set(manifest["sources"]) == {p.name for p in sim_aot.SOURCES3}
    # the next run uses it and starts no builder; its log is the first run's, bit for bit
    second = _cli_run(env, runs / "second")
    assert second.returncode == 0 and "compiling" not in second.stderr, second.stderr
    assert json.loads((runs / "second" / "run.json").read_text())["aot"] is True
    with np.load(runs / "first" / "log.npz") as a, np.load(runs / "second" / "log.npz") as b:
        assert a.files == b.files and all(np.array_equal(a[k], b[k]) for k in a.files)
    return base


def _use(monkeypatch, base, mode):
    monkeypatch.setenv("HFAM_SIM_AOT_DIR", str(base))
    monkeypatch.setenv("HFAM_SIM_AOT", mode)
    monkeypatch.setattr(sim_aot, "_loaded", {})


def _table_run(compiled=True, seconds=1.6):
    """Two samples of the table tapped 30 degrees off vertical (boxes: mesh facets and edges, the table's
    friction, the catalog's pulse and sinusoid), then a slide across the table."""
    cfg = load_config(TABLE)
    dev = Sim3Device(seed=3)
    packed = pack_scene(cfg.effective_scene, cfg.stiffness_N_m, dev.info.specs())
    point, _, _ = surface_point_above(packed, "pulse_firm")
    dev.set_user(TapTrajectory([0.08, 0.15], n_taps=2, approach_height_m=0.008), grip_N=2.0, target_m=point,
                 direction=(-0.5, 0.0, -math.sqrt(0.75)))
    loop = ServoLoop3(dev, cfg, compiled_sim=compiled)
    return loop.run(duration_s=seconds), dev


def test_the_aot_3d_loop_gives_the_jit_log_tick_for_tick(aot3_dir, monkeypatch):
    _use(monkeypatch, aot3_dir, "off")
    jit, jdev = _table_run()
    _use(monkeypatch, aot3_dir, "nobuild")
    assert sim_aot.loop3_kernels().aot
    aot, adev = _table_run()
    assert jit.timing["aot"] is False and aot.timing["aot"] is True
    assert jit.timing["ticks"] == aot.timing["ticks"] == 16_000
    for name in jit.log:
        assert np.array_equal(jit.log[name], aot.log[name]), name
    assert [(e.tick, e.object, e.incoming_velocity_m_s, e.max_penetration_m) for e in jit.events] == \
        [(e.tick, e.object, e.incoming_velocity_m_s, e.max_penetration_m) for e in aot.events]
    # the device's own state after the run agrees too (tap axis, lateral axes)
    assert np.array_equal(jdev.tap.fused_arrays()[1], adev.tap.fused_arrays()[1])
    assert np.array_equal(jdev.lat, adev.lat) and jdev.read().position_m == adev.read().position_m
    # the taps really met the sample, with its transient along the tilted tap
    assert [e.object for e in aot.events] == ["pulse_firm", "pulse_firm"]
    assert 0.05 < aot.events[0].incoming_velocity_m_s < 0.12
    assert np.max(np.abs(aot.log["force_transient_N"])) > 0.05


def test_the_aot_per_tick_law_and_proxy_are_the_jit_ones(aot3_dir, monkeypatch):
    """The per-tick path (``law3_tick`` between read() and command_force(), what hardware runs) and the
    proxy's placement query (``first_hit``) from the build give the JIT's numbers."""
    _use(monkeypatch, aot3_dir, "off")
    jit, _ = _table_run(compiled=False, seconds=0.6)
    packed = pack_scene(load_config(TABLE).effective_scene, 680.0)
    spots = [surface_point_above(packed, name) for name in packed.names[1:]]
    _use(monkeypatch, aot3_dir, "nobuild")
    aot, _ = _table_run(compiled=False, seconds=0.6)
    assert not jit.timing["compiled_sim"] and not aot.timing["compiled_sim"]
    for name in jit.log:
        assert np.array_equal(jit.log[name], aot.log[name]), name
    assert [surface_point_above(packed, name) for name in packed.names[1:]] == spots
    assert spots[0][2] == "very_firm" and spots[0][0][2] == pytest.approx(-0.02, abs=1e-12)


def test_a_3d_run_with_the_build_imports_neither_numba_nor_scipy_nor_trimesh(aot3_dir, tmp_path):
    code = ("import sys; from renderer.__main__ import main; "
            f"rc = main(['run', '--device', 'sim:3d', '--config', {str(TABLE)!r}, '--tap-object', 'firm', "
            f"'--taps', '2', '--no-figure', '--out', {str(tmp_path / 'r')!r}]); "
            "print('LOADED', [m for m in ('numba', 'scipy', 'trimesh') if m in sys.modules], rc)")
    env = {**os.environ, "HFAM_SIM_AOT_DIR": str(aot3_dir), "HFAM_SIM_AOT": "nobuild"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert "LOADED [] 0" in out.stdout, out.stdout
    events = (tmp_path / "r" / "events.csv").read_text().splitlines()
    assert len(events) == 3 and all(",firm," in row for row in events[1:])


def test_the_two_builds_live_side_by_side(tmp_path, monkeypatch):
    """Building one target removes that target's older builds only: a new 3-D build leaves the 1-DOF one
    (and the other way round); a build without a module in its manifest is a 1-DOF one."""
    monkeypatch.setenv("HFAM_SIM_AOT_DIR", str(tmp_path))
    assert sim_aot.source_key(sim_aot.LOOP1) != sim_aot.source_key(sim_aot.LOOP3)
    for key, module in (("aaaa000000000000", None), ("bbbb000000000000", "_hfam_sim3_loop")):
        (tmp_path / key).mkdir()
        (tmp_path / key / "manifest.json").write_text(json.dumps({"key": key} | ({"module": module} if module else {})))

    def fake(out_dir, target):
        (Path(out_dir) / sim_aot.extension_path(base=tmp_path, target=target).name).write_bytes(b"built")
        return {}

    monkeypatch.setattr(sim_aot, "_compile", fake)
    monkeypatch.setattr(sim_aot, "_check_loads", lambda path, target: None)
    sim_aot.build(tmp_path, target=sim_aot.LOOP3)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["aaaa000000000000", sim_aot.source_key(sim_aot.LOOP3)])
    sim_aot.build(tmp_path, target=sim_aot.LOOP1)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([sim_aot.source_key(sim_aot.LOOP1),
                                                                  sim_aot.source_key(sim_aot.LOOP3)])
    assert sim_aot.extension_path(target=sim_aot.LOOP1).read_bytes() == b"built"
    assert sim_aot.extension_path(target=sim_aot.LOOP3).read_bytes() == b"built"


def test_the_builder_refuses_an_unknown_target(capsys):
    assert sim_aot.main(["--target", "4d"]) == 2
    assert "error: --target must be one of 1d, 3d, got '4d'" in capsys.readouterr().err


def test_a_lateral_axis_at_rest_skips_its_substeps_with_the_same_result():
    """``lateral_step``'s shortcut for an axis held at rest by static friction gives what its substeps give
    (the reference: the same step with the shortcut's condition made false by a tiny velocity that the
    first substep zeroes again), over random forces, positions and grips."""
    dev = Sim3Device()
    lp = dev.lp.copy()
    rng = np.random.default_rng(5)
    held = slid = 0
    for _ in range(2000):
        lat = np.zeros(LAT.N_LAT)
        lat[LAT.LAT_QV], lat[LAT.LAT_QW] = rng.normal(0.0, 2e-4, 2)
        lat[LAT.LAT_HV], lat[LAT.LAT_HW] = rng.normal(0.0, 1.5 * lp[LAT.LP_CV], 2)
        g = float(rng.uniform(0.5, 8.0))
        fv, fw = rng.normal(0.0, 0.5, 2)
        fast = lat.copy()
        LAT.lateral_step(fast, lp, fv, fw, g)
        ref = lat.copy()
        _substeps_only(ref, lp, fv, fw, g)
        assert np.array_equal(fast, ref)
        held += fast[LAT.LAT_VV] == 0.0
        slid += fast[LAT.LAT_VV] != 0.0
    assert held > 200 and slid > 200          # both branches were exercised


def _substeps_only(lat, lp, fv, fw, g):
    """``devices.sim.lateral.lateral_step`` without its at-rest shortcut (the substeps, as written there)."""
    av_f, aw_f = lat[4], lat[5]
    lat[4], lat[5] = fv, fw
    dt, nsub, vstick = lp[8], int(lp[9]), lp[10]
    ku, bu = lp[6] * g, lp[7] * g
    for axis in range(2):
        m, c, b = lp[axis], lp[2 + axis], lp[4 + axis]
        f_ext = (av_f if axis == 0 else aw_f) + lp[12 + axis]
        q, v = lat[2 * axis], lat[2 * axis + 1]
        for _ in range(nsub):
            f = f_ext - ku * q - (bu + b) * v
            stuck = False
            if c > 0.0:
                if abs(v) < vstick:
                    if abs(f) <= c:
                        stuck = True
                    else:
                        f += -c if f > 0.0 else c
                else:
                    f += -c if v > 0.0 else c
            v = 0.0 if stuck else v + f / m * dt
            q += v * dt
        lat[2 * axis], lat[2 * axis + 1] = q, v


def test_a_plane_only_3d_run_never_reads_a_mesh_file_and_boxes_are_trimesh_boxes():
    """Scenes of planes, spheres and boxes pack without trimesh (a subprocess shows it is never imported);
    the boxes are trimesh's own (``trimesh.creation.box``, translated): the same corners and face normals,
    vertex normals within rounding."""
    import trimesh

    from renderer.scene import Box
    from renderer.scene3 import box_arrays

    rng = np.random.default_rng(2)
    for _ in range(50):
        half, centre = rng.uniform(0.001, 0.03, 3), rng.uniform(-0.03, 0.03, 3)
        tri, fn, vn = box_arrays(Box(tuple(centre), tuple(half)))
        ref = trimesh.creation.box(extents=[2 * h for h in half])
        ref.apply_translation(centre)
        assert np.array_equal(tri, ref.triangles) and np.array_equal(fn, ref.face_normals)
        np.testing.assert_allclose(vn, ref.vertex_normals[ref.faces], rtol=0, atol=1e-15)
    code = (f"import sys; from renderer.config import load_config; from renderer.scene3 import pack_scene; "
            f"p = pack_scene(load_config({str(TABLE)!r}).effective_scene, 680.0); "
            "print(p.tri.shape, 'trimesh' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "(108, 21) False", out.stderr
