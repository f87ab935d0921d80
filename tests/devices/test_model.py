"""ZpkModel: frequency response, Tustin discretization, simulation, JSON round trip and validation."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from devices.model import ZpkModel, load_model

W0 = 2 * np.pi * 130.0  # resonance like the Phantom's (section 3.4.4)
ZETA = 0.08


def resonant(delay_s=0.0, **kw):
    """k * s / ((s - p)(s - p*)) * 1/(s/wa + 1): a band-pass resonance plus a pole."""
    p = W0 * (-ZETA + 1j * np.sqrt(1 - ZETA**2))
    wa = 2 * np.pi * 900.0
    return ZpkModel([-2 * np.pi * 5.0], [p, np.conj(p), -wa], 3.0e5, delay_s, **kw)


def test_frequency_response_matches_scipy_and_delay():
    m = resonant(delay_s=2.5e-4)
    f = np.linspace(1, 2000, 500)
    _, h = signal.freqs_zpk(m.zeros_rad_s, m.poles_rad_s, m.gain, worN=2 * np.pi * f)
    expected = h * np.exp(-2j * np.pi * f * 2.5e-4)
    np.testing.assert_allclose(m.frequency_response(f), expected, rtol=1e-12)
    # the delay only changes the phase, by -360 deg * f * d (-90 deg at 1 kHz for 0.25 ms)
    _, h1k = signal.freqs_zpk(m.zeros_rad_s, m.poles_rad_s, m.gain, worN=[2 * np.pi * 1000.0])
    ratio = m.frequency_response([1000.0])[0] / h1k[0]
    assert abs(ratio) == pytest.approx(1.0, abs=1e-12)
    assert np.angle(ratio, deg=True) == pytest.approx(-90.0, abs=1e-9)


def test_to_discrete_is_tustin():
    m = resonant()
    fs = 10_000.0
    z, p, k = m.to_discrete(fs)
    assert p.size == 3 and z.size == 3  # one extra zero at z=-1 per relative degree
    assert np.sum(np.isclose(z, -1.0)) == 2
    assert np.all(np.abs(p) < 1)
    # at low frequency the discrete response matches the continuous one (Tustin warping is small)
    f = np.array([20.0, 100.0, 130.0, 300.0])
    _, hd = signal.freqz_zpk(z, p, k, worN=f, fs=fs)
    hc = m.frequency_response(f)
    np.testing.assert_allclose(20 * np.log10(abs(hd)), 20 * np.log10(abs(hc)), atol=0.3)


def test_simulate_steady_state_sine_and_delay_rounding():
    fs = 10_000.0
    d = 3.3e-4  # 3.3 samples -> rounded to 3
    m = resonant(delay_s=d)
    assert m.delay_samples(fs) == 3
    t = np.arange(int(fs)) / fs
    f0 = 200.0
    u = np.sin(2 * np.pi * f0 * t)
    y = m.simulate(u, fs)
    # steady state over the last 0.5 s: amplitude and phase vs the Tustin response incl. 3-sample delay
    seg = slice(int(0.5 * fs), None)
    basis = np.exp(-2j * np.pi * f0 * t[seg])
    gain_est = 2 * np.mean(y[seg] * basis) / (2 * np.mean(u[seg] * basis))
    z, p, k = m.to_discrete(fs)
    _, hd = signal.freqz_zpk(z, p, k, worN=[f0], fs=fs)
    expected = hd[0] * np.exp(-2j * np.pi * f0 * 3 / fs)
    assert abs(gain_est - expected) / abs(expected) < 1e-3
    # first 3 output samples are the shifted-in zeros
    assert np.all(y[:3] == 0)
    assert np.all(np.isfinite(y))


def test_simulate_high_order_is_robust():
    # 12 lightly damped poles close together: polynomial (ba) filtering would lose precision
    fs = 10_000.0
    freqs = np.array([100, 130, 180, 240, 320, 410]) * 2 * np.pi
    poles = freqs * (-0.02 + 1j * np.sqrt(1 - 0.02**2))
    poles = np.concatenate([poles, np.conj(poles)])
    zeros = np.concatenate([(freqs * 1.1) * (-0.03 + 1j), (freqs * 1.1) * (-0.03 - 1j)])
    m = ZpkModel(zeros, poles, 1.0)
    u = np.zeros(20000)
    u[0] = 1.0
    y = m.simulate(u, fs)
    assert np.all(np.isfinite(y))
    # impulse response energy decays (stable)
    assert np.sum(y[-2000:] ** 2) < 1e-6 * np.sum(y[:2000] ** 2)


def test_static_gain_model_and_input_checks():
    m = ZpkModel([], [], 2.0, 0.0)
    np.testing.assert_allclose(m.simulate([1.0, -1.0, 0.5], 1000.0), [2.0, -2.0, 1.0])
    with pytest.raises(ValueError, match="NaN"):
        m.simulate([1.0, np.nan], 1000.0)
    with pytest.raises(ValueError, match="fs_hz"):
        m.simulate([1.0], 0.0)


def test_json_round_trip(tmp_path):
    m = resonant(delay_s=2.5e-4, output="position_m", band_hz=(10.0, 1000.0), grip_N=2.0,
                 fit={"rms_db": np.float64(0.4), "order": np.int64(3)}, source="unit test")
    path = m.save(tmp_path / "sub" / "model.json")
    data = json.loads(path.read_text())
    assert data["kind"] == "zpk" and data["output"] == "position_m" and data["grip_N"] == 2.0
    assert isinstance(data["poles_rad_s"][0], list) and len(data["poles_rad_s"][0]) == 2
    m2 = load_model(path)
    f = np.geomspace(10, 1000, 50)
    np.testing.assert_allclose(m2.frequency_response(f), m.frequency_response(f), rtol=1e-12)
    assert m2.band_hz == (10.0, 1000.0) and m2.fit == {"rms_db": 0.4, "order": 3} and m2.source == "unit test"
    import devices

    assert devices.load_model(path).order == 3


def _write(tmp_path, data, name="bad.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "change, key",
    [
        ({"poles_rad_s": [[10.0, 0.0]]}, "poles_rad_s"),  # unstable
        ({"poles_rad_s": [[0.0, 0.0]]}, "poles_rad_s"),  # marginal
        ({"zeros_rad_s": [[-1.0, 0.0], [-2.0, 0.0]], "poles_rad_s": [[-3.0, 0.0]]}, "zeros_rad_s"),  # improper
        ({"gain": float("nan")}, "gain"),
        ({"delay_s": -1.0}, "delay_s"),
        ({"poles_rad_s": [[-1.0, 5.0]]}, "poles_rad_s"),  # unpaired complex pole
        ({"poles_rad_s": [[-1.0]]}, "poles_rad_s"),
        ({"output": "velocity"}, "output"),
        ({"kind": "tf"}, "kind"),
    ],
)
def test_load_rejects_bad_models(tmp_path, change, key):
    good = resonant().to_dict()
    good.update(change)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(good))  # json.dumps writes NaN as a bare token, which json.loads accepts
    with pytest.raises(ValueError) as info:
        load_model(path)
    assert str(path) in str(info.value) and key in str(info.value)


@pytest.mark.parametrize("key", ["kind", "zeros_rad_s", "poles_rad_s", "gain", "delay_s", "input", "output"])
def test_load_rejects_missing_keys(tmp_path, key):
    data = resonant().to_dict()
    del data[key]
    path = _write(tmp_path, data)
    with pytest.raises(ValueError, match=f"{path}.*missing key '{key}'"):
        load_model(path)


def test_load_missing_file_and_bad_json(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path / "nope.json")
    path = tmp_path / "broken.json"
    path.write_text("{\"kind\": \"zpk\",\n oops}")
    with pytest.raises(ValueError, match="line 2"):
        load_model(path)


def test_unstable_model_constructs_but_cannot_be_saved(tmp_path):
    m = ZpkModel([], [0.0, 0.0], 1.0, output="position_m")  # free mass: 1/s^2
    assert not m.is_stable
    assert abs(m.frequency_response([10.0])[0]) == pytest.approx(1 / (2 * np.pi * 10) ** 2)
    with pytest.raises(ValueError, match="unstable"):
        m.save(tmp_path / "m.json")
    assert not (tmp_path / "m.json").exists()


def test_conjugates_are_symmetrized_and_frozen():
    p = -10 + 100j
    m = ZpkModel([], [p, np.conj(p) + 1e-9], 1.0)
    assert m.poles_rad_s[1] == np.conj(m.poles_rad_s[0])
    with pytest.raises(ValueError):
        m.poles_rad_s[0] = -1.0
    with pytest.raises(Exception):
        m.gain = 2.0
