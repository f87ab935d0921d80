"""HfamLibrary lookup (section 4.4.2), checks against a device, and the file round trip."""

import json
import re
import tracemalloc

import numpy as np
import pytest

from devices.base import DeviceInfo
from stimuli import HfamLibrary
from tests.support.cli import run_cli

INFO = DeviceInfo("t", 2000, 15.0, 0.15, 0.0235, 1.26, 4.0, 4.0, 10000.0, grip_range_N=(0.0, 10.0))


def make_lib(velocities=(0.03, 0.065, 0.081, 0.2), grips=(0.0, 5.0, 10.0), n_t=50, **kw):
    rng = np.random.default_rng(1)
    c = rng.uniform(-1.0, 1.0, (len(velocities), len(grips), n_t))
    return HfamLibrary(velocities, grips, c, 10000.0, INFO.force_per_amp_N_A, **kw)


def test_velocity_weights_thesis_example():
    """0.07 m/s between 0.065 and 0.081 m/s: the weights are 0.3125 and 0.6875 (section 4.4.2).

    The thesis text assigns 0.3125 to the lower transient, but linear interpolation
    (which it motivates by transient magnitude being linear in velocity) gives 0.3125
    to the *upper* one: (0.07 - 0.065)/(0.081 - 0.065) = 0.3125. The swapped reading
    would jump from the 0.081 m/s transient at 0.0651 m/s to the 0.065 m/s one at
    0.0649 m/s; see docs/hfam_library.md.
    """
    lib = make_lib(grips=(2.0,))
    i0, i1, j0, j1, w00, w01, w10, w11 = lib.weights(0.07, 2.0)
    assert (lib.velocities_m_s[i0], lib.velocities_m_s[i1]) == (0.065, 0.081)
    assert w00 == pytest.approx(0.6875, abs=1e-12) and w10 == pytest.approx(0.3125, abs=1e-12)
    C = lib.currents_A
    np.testing.assert_allclose(lib.current(0.07, 2.0), 0.6875 * C[1, 0] + 0.3125 * C[2, 0], rtol=1e-12)


def test_velocity_interpolation_is_exact_for_linear_libraries_and_continuous():
    v = np.array([0.03, 0.065, 0.081, 0.2])
    shape = np.sin(np.linspace(0, 6, 40))
    lib = HfamLibrary(v, (1.0,), (v[:, None, None] * shape[None, None, :]), 1e4, 2.35)
    for vin in (0.04, 0.07, 0.0801, 0.15):
        np.testing.assert_allclose(lib.current(vin, 1.0), vin * shape, rtol=1e-12, atol=1e-15)
    eps = 1e-9
    for knot in v[1:-1]:
        np.testing.assert_allclose(lib.current(knot - eps, 1.0), lib.current(knot + eps, 1.0), atol=1e-7)
    # negative incoming velocity (moving down) uses its magnitude
    np.testing.assert_allclose(lib.current(-0.07, 2.0), lib.current(0.07, 2.0))


def test_bilinear_grip_interpolation():
    lib = make_lib()
    C = lib.currents_A
    wv = (0.07 - 0.065) / (0.081 - 0.065)
    wg = (6.5 - 5.0) / 5.0
    expected = ((1 - wv) * (1 - wg) * C[1, 1] + (1 - wv) * wg * C[1, 2]
                + wv * (1 - wg) * C[2, 1] + wv * wg * C[2, 2])
    np.testing.assert_allclose(lib.current(0.07, 6.5), expected, rtol=1e-12)
    # exact library points reproduce the stored transient
    np.testing.assert_array_equal(lib.current(0.081, 5.0), C[2, 1])
    # grip outside the range clamps
    np.testing.assert_array_equal(lib.current(0.2, 25.0), C[3, 2])
    np.testing.assert_array_equal(lib.current(0.2, -3.0), C[3, 0])
    # NaN grip -> lowest level (smallest currents); NaN velocity -> zeros, never NaN
    np.testing.assert_array_equal(lib.current(0.2, float("nan")), C[3, 0])
    assert np.all(lib.current(float("nan"), 5.0) == 0.0)


def test_out_of_range_scaling_and_cap():
    lib = make_lib(max_extrapolation=1.5)
    C = lib.currents_A
    np.testing.assert_allclose(lib.current(0.015, 0.0), 0.5 * C[0, 0], rtol=1e-12)  # 0.015/0.03
    np.testing.assert_allclose(lib.current(0.25, 0.0), 1.25 * C[3, 0], rtol=1e-12)  # 0.25/0.2
    np.testing.assert_allclose(lib.current(1.0, 0.0), 1.5 * C[3, 0], rtol=1e-12)  # capped (5x -> 1.5x)
    assert np.all(lib.current(0.0, 0.0) == 0.0)
    lib2 = make_lib(max_extrapolation=3.0)
    np.testing.assert_allclose(lib2.current(1.0, 0.0), 3.0 * lib2.currents_A[3, 0], rtol=1e-12)
    with pytest.raises(ValueError, match="max_extrapolation"):
        make_lib(max_extrapolation=0.5)


def test_gain_and_waveform_in_newtons():
    lib = make_lib(gain=0.8)
    np.testing.assert_allclose(lib.current(0.081, 5.0), 0.8 * lib.currents_A[2, 1])
    np.testing.assert_allclose(lib.waveform(0.081, 5.0, 10000.0), 0.8 * 2.35 * lib.currents_A[2, 1])
    assert lib.max_samples(10000.0) == 50 and lib.name == "hfam"
    with pytest.raises(ValueError, match="does not match the servo rate"):
        lib.waveform(0.1, 1.0, 1000.0)


def test_current_into_matches_and_does_not_allocate():
    lib = make_lib(n_t=1000)
    buf = np.full(1200, np.nan)
    assert lib.current_into(0.07, 6.5, buf) == 1000
    np.testing.assert_allclose(buf[:1000], lib.current(0.07, 6.5), rtol=1e-12)
    assert np.isnan(buf[1000:]).all()  # beyond n_t untouched
    for v, g in ((0.01, 1.0), (0.3, 12.0), (0.1, 3.0)):  # warm up every branch
        lib.current_into(v, g, buf)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for k in range(200):
        lib.current_into(0.03 + 0.001 * k, 0.05 * k, buf)
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename") if s.size_diff > 0)
    assert grown < 2000  # no per-call arrays (1000 doubles would be 8 kB each)
    with pytest.raises(ValueError, match="needs 1000"):
        lib.current_into(0.1, 1.0, np.empty(10))


@pytest.mark.parametrize("velocities,match", [
    ((0.1, 0.1, 0.2), "strictly increasing"),
    ((0.2, 0.1, 0.3), "strictly increasing"),
    ((0.0, 0.1, 0.3), "> 0"),
    ((0.1, float("nan"), 0.3), "NaN"),
])
def test_bad_velocities_refused(velocities, match):
    with pytest.raises(ValueError, match=match):
        HfamLibrary(velocities, (1.0,), np.zeros((3, 1, 5)), 1e4, 2.35)


def test_bad_shapes_and_values_refused():
    with pytest.raises(ValueError, match="shape"):
        HfamLibrary((0.1, 0.2), (1.0,), np.zeros((2, 2, 5)), 1e4, 2.35)
    c = np.zeros((2, 1, 5))
    c[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match="velocity 0.2 m/s, grip 1.0 N, sample 3"):
        HfamLibrary((0.1, 0.2), (1.0,), c, 1e4, 2.35)


def test_save_load_round_trip_is_exact(tmp_path):
    lib = make_lib(gain=0.85, max_extrapolation=2.0, metadata={"settings": {"smooth_hz": 500.0}, "note": "x"},
                   desired_accel_m_s2=np.random.default_rng(2).normal(size=(4, 50)))
    path = lib.save(tmp_path / "lib.npz")
    back = HfamLibrary.load(path)
    for key in ("velocities_m_s", "grips_N", "currents_A", "desired_accel_m_s2"):
        np.testing.assert_array_equal(getattr(back, key), getattr(lib, key))
        assert getattr(back, key).dtype == np.float64
    assert (back.fs_hz, back.force_per_amp_N_A, back.gain, back.max_extrapolation) == (10000.0, lib.force_per_amp_N_A, 0.85, 2.0)
    assert back.metadata["settings"] == {"smooth_hz": 500.0} and back.metadata["format"] == "hfam-library"
    np.testing.assert_array_equal(back.current(0.07, 6.5), lib.current(0.07, 6.5))
    assert not (tmp_path / "lib.npz.tmp").exists()
    # the gain can be overridden on load
    assert HfamLibrary.load(path, gain=1.0).gain == 1.0


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        HfamLibrary.load(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    with pytest.raises(ValueError, match="bad.npz"):
        HfamLibrary.load(bad)
    partial = tmp_path / "partial.npz"
    np.savez(partial, velocities_m_s=np.array([0.1, 0.2]))
    with pytest.raises(ValueError, match=r"partial.npz: missing array\(s\) grips_N"):
        HfamLibrary.load(partial)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, velocities_m_s=np.array([0.1, 0.2]), grips_N=np.array([1.0]), currents_A=np.zeros((2, 1, 3)),
             fs_hz=1e4, force_per_amp_N_A=2.35, metadata_json=np.array(json.dumps({"format": "other"})))
    with pytest.raises(ValueError, match="wrong.npz: format 'other'"):
        HfamLibrary.load(wrong)


def test_check_device():
    lib = make_lib()  # |currents| <= 1 A, grips 0..10 N, 10 kHz, 2.35 N/A
    lib.check_device(INFO, 10000.0)
    with pytest.raises(ValueError, match="sample rate 10000.0 Hz does not match the servo rate 1000"):
        lib.check_device(INFO, 1000.0)
    with pytest.raises(ValueError, match="do not cover device 't' grip range 0.0..12.0"):
        lib.check_device(DeviceInfo("t", 2000, 15.0, 0.15, 0.0235, 1.26, 4.0, 4.0, 1e4, grip_range_N=(0.0, 12.0)), 1e4)
    with pytest.raises(ValueError, match="force constant"):
        lib.check_device(DeviceInfo("t", 2000, 30.0, 0.15, 0.0235, 1.26, 4.0, 4.0, 1e4), 1e4)
    with pytest.raises(ValueError, match="exceeds device 't' peak limit 0.5 A"):
        lib.check_device(DeviceInfo("t", 2000, 15.0, 0.15, 0.0235, 0.2, 0.5, 0.5, 1e4), 1e4)
    # a single-grip library is grip-independent: no grip-range check
    make_lib(grips=(2.0,)).check_device(DeviceInfo("t", 2000, 15.0, 0.15, 0.0235, 1.26, 4.0, 4.0, 1e4,
                                                   grip_range_N=(0.0, 12.0)), 1e4)


def _rewrite(src, dst, **changes):
    """Copy the library archive ``src`` to ``dst`` with members replaced (``None`` drops one)."""
    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = value
    np.savez(dst, **arrays)
    return dst


@pytest.mark.parametrize("case,match", [
    ("fs_vec", r"fs_hz must be a single number"),
    ("fs_str", r"fs_hz must be a single number"),
    ("cur_obj", r"member 'currents_A' of the HFAM library cannot be read"),
    ("cur_str", r"currents_A must be a numeric array"),
    ("meta_list", r"metadata_json must be a JSON object, got list"),
    ("meta_ver_str", r"metadata_json format_version must be an integer, got 'x'"),
    ("corrupt_mid", r"member 'currents_A' of the HFAM library is corrupt \(Bad CRC-32"),
])
def test_show_refuses_damaged_library_members_naming_file_and_key(tmp_path, capsys, case, match):
    """Audit lib_*.txt: each damaged member was a raw traceback or a message without file/key; now one error line."""
    good = make_lib().save(tmp_path / "good.npz")
    bad = tmp_path / f"{case}.npz"
    if case == "fs_vec":
        _rewrite(good, bad, fs_hz=np.array([1e4, 1e4]))
    elif case == "fs_str":
        _rewrite(good, bad, fs_hz=np.array("abc"))
    elif case == "cur_obj":
        _rewrite(good, bad, currents_A=np.array([None, 1], dtype=object))
    elif case == "cur_str":
        _rewrite(good, bad, currents_A=np.array(["a", "b"]))
    elif case == "meta_list":
        _rewrite(good, bad, metadata_json=np.array(json.dumps([1, 2])))
    elif case == "meta_ver_str":
        _rewrite(good, bad, metadata_json=np.array(json.dumps({"format": "hfam-library", "format_version": "x"})))
    else:  # flip one byte in the middle of the (stored, uncompressed) currents_A member: its CRC no longer matches
        _rewrite(good, bad)
        raw = bytearray(bad.read_bytes())
        at = raw.index(b"currents_A.npy") + 400
        raw[at] ^= 0xFF
        bad.write_bytes(bytes(raw))
    res = run_cli(capsys, "stimuli", "show", str(bad), "--out", str(tmp_path / "s.png"))
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad}:"), res.stderr
    assert re.search(match, lines[0]), lines[0]
