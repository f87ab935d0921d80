"""Scene collision detection and config/scene file validation."""

import json
import math

import numpy as np
import pytest

from renderer import RendererConfig, load_config, load_scene
from renderer.scene import Box, Plane, Scene, Sphere, Wall, parse_scene


def test_wall_signed_depth_and_normal():
    w = Wall(0.01)
    assert w.penetration((0.0, 0.0, 0.004)) == (pytest.approx(0.006), (0.0, 0.0, 1.0))
    assert w.penetration((0.0, 0.0, 0.02))[0] == pytest.approx(-0.01)


def test_plane_normalises_and_measures_depth():
    p = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 2.0))
    assert p.normal == (0.0, 0.0, 1.0)
    d, n = Plane((1.0, 0.0, 0.0), (1.0, 1.0, 0.0)).penetration((0.0, 0.0, 0.0))
    assert d == pytest.approx(1 / math.sqrt(2))
    assert n == pytest.approx((1 / math.sqrt(2), 1 / math.sqrt(2), 0.0))


def test_sphere_depth_and_radial_normal():
    s = Sphere((0.0, 0.0, -0.05), 0.05)
    d, n = s.penetration((0.0, 0.0, -0.01))
    assert d == pytest.approx(0.01)
    assert n == pytest.approx((0.0, 0.0, 1.0))
    d, n = s.penetration((0.1, 0.0, -0.05))
    assert d == pytest.approx(-0.05)
    assert n == pytest.approx((1.0, 0.0, 0.0))


def test_box_inside_uses_nearest_face_outside_euclidean():
    b = Box((0.0, 0.0, 0.0), (0.1, 0.2, 0.05))
    d, n = b.penetration((0.0, 0.0, 0.04))  # 1 cm below the top face
    assert d == pytest.approx(0.01)
    assert n == (0.0, 0.0, 1.0)
    d, n = b.penetration((0.095, 0.0, 0.0))  # 5 mm from the +x face
    assert d == pytest.approx(0.005)
    assert n == (1.0, 0.0, 0.0)
    d, n = b.penetration((0.13, 0.0, 0.09))  # outside a corner edge: 3 cm in x, 4 cm in z
    assert d == pytest.approx(-0.05)
    assert n == pytest.approx((0.6, 0.0, 0.8))


def test_scene_deepest_penetration_wins():
    scene = Scene((Wall(0.0), Sphere((0.0, 0.0, -0.02), 0.03)))
    # at z = -0.005: wall depth 5 mm, sphere depth 30 - 15 = 15 mm -> sphere wins
    d, nz = scene.penetration_1d(-0.005)
    assert d == pytest.approx(0.015)
    assert nz == pytest.approx(1.0)
    # at z = 0.02 both outside: the nearest (wall, -20 mm vs sphere -10 mm) -> sphere is nearer
    d, _ = scene.penetration_1d(0.02)
    assert d == pytest.approx(-0.01)
    assert Scene((Wall(0.0),)).single_wall == Wall(0.0)
    assert scene.single_wall is None


def test_parse_scene_round_trip_and_errors():
    data = {"objects": [{"shape": "wall", "height_m": 0.001},
                        {"shape": "box", "center_m": [0, 0, -0.1], "half_extents_m": [0.1, 0.1, 0.1]},
                        {"shape": "plane", "point_m": [0, 0, 0], "normal": [0, 0, 1]},
                        {"shape": "sphere", "center_m": [0, 0, 0], "radius_m": 0.01}]}
    scene = parse_scene(data)
    assert parse_scene(scene.to_dict()) == scene
    with pytest.raises(ValueError, match=r"objects\[0\]\.shape: unknown shape 'cone'"):
        parse_scene({"objects": [{"shape": "cone"}]})
    with pytest.raises(ValueError, match=r"objects\[0\]: unknown key 'radius'"):
        parse_scene({"objects": [{"shape": "sphere", "radius": 1.0}]})
    with pytest.raises(ValueError, match=r"objects\[0\]\.radius_m must be > 0"):
        parse_scene({"objects": [{"shape": "sphere", "radius_m": -1.0}]})
    with pytest.raises(ValueError, match=r"half_extents_m must be all > 0"):
        parse_scene({"objects": [{"shape": "box", "half_extents_m": [1, 0, 1]}]})
    with pytest.raises(ValueError, match="normal must be a non-zero vector"):
        parse_scene({"objects": [{"shape": "plane", "normal": [0, 0, 0]}]})
    # a tiny normal still has a direction (its squared length underflowed to 0: audit renderer_config_tiny_normal)
    tiny = parse_scene({"objects": [{"shape": "plane", "normal": [0, 1e-200, 1e-200]}]}).objects[0]
    assert tiny.normal == pytest.approx((0.0, 2 ** -0.5, 2 ** -0.5), rel=1e-12)
    with pytest.raises(ValueError, match="non-empty list"):
        parse_scene({"objects": []})


def test_config_file_toml_and_json(tmp_path):
    toml = tmp_path / "scene.toml"
    toml.write_text('stiffness_N_m = 340\nrate_hz = 10000\ndamping_N_s_m = 1.5\n'
                    '[scene]\nobjects = [ { shape = "wall", height_m = 0.002 } ]\n')
    cfg = load_config(toml)
    assert cfg.stiffness_N_m == 340.0 and cfg.rate_hz == 10000.0 and cfg.damping_N_s_m == 1.5
    assert cfg.effective_scene.single_wall == Wall(0.002)
    assert load_scene(toml) == cfg.effective_scene
    js = tmp_path / "cfg.json"
    js.write_text(json.dumps(cfg.to_dict()))
    assert load_config(js) == cfg
    assert load_config(toml, stiffness_N_m=100.0).stiffness_N_m == 100.0


@pytest.mark.parametrize("text, key", [
    ("stiffness_N_m = -5\n", "stiffness_N_m must be >= 0"),
    ("rate_hz = 0\n", "rate_hz must be > 0"),
    ("rate_hz = -100\n", "rate_hz must be > 0"),
    ("stifness_N_m = 5\n", "unknown key 'stifness_N_m'"),
    ("damping_N_s_m = -1\n", "damping_N_s_m must be >= 0"),
    ('[scene]\nobjects = [ { shape = "torus" } ]\n', "scene.objects\\[0\\].shape: unknown shape 'torus'"),
    ('[scene]\nobjects = [ { shape = "wall", heigth_m = 0 } ]\n', "unknown key 'heigth_m'"),
    ('[scene]\nobjcts = []\n', "scene: unknown key 'objcts'"),
    ("pacing = 'yolo'\n", "pacing must be one of"),
])
def test_config_file_errors_name_file_and_key(tmp_path, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=key) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_config_parse_errors_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"stiffness_N_m": 1,\n "rate_hz": }')
    with pytest.raises(ValueError, match=r"bad.json: invalid JSON at line 2"):
        load_config(bad)
    with pytest.raises(FileNotFoundError, match="nope.toml"):
        load_config(tmp_path / "nope.toml")


def test_config_dataclass_validates_in_code():
    with pytest.raises(ValueError, match="stiffness_N_m"):
        RendererConfig(stiffness_N_m=-1.0)
    with pytest.raises(ValueError, match="rate_hz"):
        RendererConfig(rate_hz=0.0)
    with pytest.raises(ValueError, match="stiffness_N_m must be a finite number"):
        RendererConfig(stiffness_N_m=math.nan)
    with pytest.raises(ValueError, match="thermal_attenuate_frac"):
        RendererConfig(thermal_attenuate_frac=0.95, thermal_end_frac=0.9)


def test_one_dof_fast_path_matches_the_3d_query():
    scene = Scene((Wall(0.001), Plane((0.0, 0.0, -0.002), (0.0, 0.3, 1.0)), Sphere((0.001, 0.0, -0.03), 0.031),
                   Box((0.0, 0.0, -0.05), (0.02, 0.01, 0.0495)), Box((0.03, 0.0, 0.0), (0.01, 0.01, 0.01))))
    for obj in scene.objects + (scene,):
        for z in np.linspace(-0.12, 0.05, 341):
            d, n = (obj.penetration((0.0, 0.0, z)) if obj is not scene else scene.penetration((0.0, 0.0, z)))
            d1, nz = obj.penetration_1d(z)
            assert d1 == pytest.approx(d, abs=1e-15)
            assert nz == pytest.approx(n[2], abs=1e-12)


def test_endpoint_weights_match_pinv_and_savgol():
    """The closed-form quadratic endpoint derivative agrees with the least-squares pseudo-inverse and with
    scipy's Savitzky-Golay coefficients for every window the estimator can use (and beyond)."""
    from scipy.signal import savgol_coeffs

    from renderer.velocity import endpoint_derivative_weights

    dt = 1e-4
    for window in range(3, 201):
        u = np.arange(window, dtype=float) - (window - 1)
        ref = np.linalg.pinv(np.stack([np.ones(window), u, u * u], axis=1))[1] / dt
        sg = savgol_coeffs(window, 2, deriv=1, delta=dt, pos=window - 1, use="dot")
        w = np.array(endpoint_derivative_weights(window, dt))
        scale = np.max(np.abs(ref))
        assert np.max(np.abs(w - ref)) < 1e-10 * scale, window
        assert np.max(np.abs(w - sg)) < 1e-10 * scale, window
        assert abs(float(np.sum(w))) < 1e-9 * scale  # a constant has no slope
    with pytest.raises(ValueError, match=">= 3 samples"):
        endpoint_derivative_weights(2, dt)


def test_velocity_fits_are_exact_on_polynomials():
    import array

    from renderer.velocity import ImpactVelocityEstimator, endpoint_derivative_weights, ls_constants, ls_slope_ring

    dt = 1e-4
    t = np.arange(200) * dt
    line = 0.01 - 0.1 * t
    ring = array.array("d", line)
    assert ls_slope_ring(ring, 199, 40, dt) == pytest.approx(-0.1, rel=1e-9)
    c_shift, c_scale = ls_constants(40, dt)
    y = line[-40:]
    assert (np.sum(np.arange(40) * y) - c_shift * np.sum(y)) * c_scale == pytest.approx(-0.1, rel=1e-9)
    # quadratic: x = x0 - v t + a t^2 / 2; derivative at the newest sample is exact
    quad = 0.01 - 0.3 * t + 0.5 * 20.0 * t * t
    w = endpoint_derivative_weights(30, dt)
    assert float(np.dot(w, quad[-30:])) == pytest.approx(-0.3 + 20.0 * t[-1], rel=1e-8)
    est = ImpactVelocityEstimator(dt, 7.85e-6)
    ring2 = array.array("d", np.concatenate([quad[-100:], quad[-100:]]))
    est.bind(ring2)
    assert est.at(99, 0.3) == pytest.approx(-0.3 + 20.0 * t[-1], rel=1e-8)
    assert est(array.array("d", quad[-100:]), 99) == pytest.approx(-0.3 + 20.0 * t[-1], rel=1e-8)
    assert est.window_for(0.05) == est.w_max == 100 and est.window_for(0.4) == 20 and est.window_for(5.0) == 20
    # the weight tables are shared by every estimator of the process (the 3-D loop has one per axis): none can
    # change them for the others
    other = ImpactVelocityEstimator(dt, 7.85e-6)
    assert other.weights is est.weights and other.weight_arrays is est.weight_arrays
    with pytest.raises(TypeError):
        est.weights[30] = [0.0] * 30
    with pytest.raises(TypeError):
        est.weights[30][0] = 0.0
    with pytest.raises(ValueError):
        est.weight_arrays[30][0] = 0.0


@pytest.mark.parametrize("name,content,match", [
    ("list.json", b"[1, 2]", ": a renderer config must be a table/object of settings, got list"),
    ("num.json", b"5", ": a renderer config must be a table/object of settings, got int"),
    ("shape_list.toml", b'[scene]\nobjects = [ { shape = ["wall"] } ]\n',
     ": scene.objects[0].shape: unknown shape ['wall']"),
    ("maxtr.toml", b"max_transient_s = 1e9\n", ": max_transient_s must be at most 10 s"),
    ("bigint.toml", b"max_transient_s = 1" + b"0" * 400 + b"\n",
     ": max_transient_s must be a finite number, got an integer too large"),
    ("nonutf.toml", b"stiffness_N_m = 340\n# \xff\n", ":2: renderer config is not UTF-8 text (invalid start byte"),
])
def test_renderer_run_refuses_config_of_wrong_type_naming_file_and_key(tmp_path, name, content, match):
    """Audit renderer_config_{list,num,shape_list,maxtr,nonutf}.txt: raw TypeError / MemoryError tracebacks or a
    codec message without the file; now ``python -m renderer run`` exits 2 with one line naming file and key."""
    import subprocess
    import sys
    path = tmp_path / name
    path.write_bytes(content)
    res = subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim", "--config", str(path), "--taps",
                          "1", "--out", str(tmp_path / "RR")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}{match}"), res.stderr
    assert not (tmp_path / "RR").exists()
