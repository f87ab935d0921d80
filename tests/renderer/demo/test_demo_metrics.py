"""Demo metrics on synthetic signals with known answers."""

import numpy as np
import pytest

from renderer.demo import metrics as dm

FS = 10_000.0


def decaying_sine(f_hz, amp=50.0, tau_s=0.015, n_pre=100, n_post=1000, fs=FS):
    t = np.arange(-n_pre, n_post) / fs
    x = amp * np.exp(-np.clip(t, 0, None) / tau_s) * np.sin(2 * np.pi * f_hz * np.clip(t, 0, None))
    return t, x


def test_bandpass_passes_in_band_and_rejects_out_of_band():
    t = np.arange(20_000) / FS
    inband = np.sin(2 * np.pi * 200 * t)
    low = np.sin(2 * np.pi * 2 * t)
    high = np.sin(2 * np.pi * 3000 * t)
    y = dm.bandpass(inband + low + high, FS)
    mid = slice(5000, 15000)
    # zero-phase: the in-band tone passes without phase shift
    assert np.max(np.abs(y[mid] - inband[mid])) < 0.05
    assert np.std(dm.bandpass(low, FS)[mid]) < 0.01
    assert np.std(dm.bandpass(high, FS)[mid]) < 0.02


def test_nrmse_and_correlation_known_values():
    rng = np.random.default_rng(1)
    ref = rng.standard_normal(1000)
    assert dm.nrmse(ref, ref) == 0.0
    assert dm.correlation(ref, ref) == pytest.approx(1.0)
    assert dm.nrmse(np.zeros_like(ref), ref) == pytest.approx(1.0)
    # half amplitude: perfectly correlated, NRMSE 0.5
    assert dm.nrmse(0.5 * ref, ref) == pytest.approx(0.5)
    assert dm.correlation(0.5 * ref, ref) == pytest.approx(1.0)
    assert dm.correlation(-ref, ref) == pytest.approx(-1.0)
    assert np.isnan(dm.nrmse(ref, np.zeros_like(ref)))


@pytest.mark.parametrize("f_hz", [35.0, 120.0, 310.0, 640.0])
def test_dominant_frequency_of_decaying_sinusoid(f_hz):
    _, x = decaying_sine(f_hz, n_pre=0)
    assert dm.dominant_frequency(x, FS) == pytest.approx(f_hz, rel=0.03, abs=2.0)


def test_contact_metrics_peak_and_frequency():
    _, x = decaying_sine(300.0, amp=80.0)
    peak, f = dm.contact_metrics(x, FS)
    assert 60.0 < peak <= 80.0  # sin never hits exactly the envelope peak at t=0
    assert f == pytest.approx(300.0, abs=6.0)


def test_compare_refines_alignment_within_bound():
    _, ref = decaying_sine(250.0)
    late = np.roll(ref, 3)  # 0.3 ms late, within the 0.5 ms search
    c = dm.compare(late, ref, FS)
    assert c.lag_samples == 3
    assert c.correlation > 0.999 and c.nrmse < 0.02
    # beyond the search bound the error shows: alignment refinement is bounded
    much_later = np.roll(ref, 12)
    c2 = dm.compare(much_later, ref, FS)
    assert abs(c2.lag_samples) <= 5
    assert c2.correlation < 0.5


def test_compare_distinguishes_wrong_frequency_and_amplitude():
    _, ref = decaying_sine(250.0)
    _, slow = decaying_sine(60.0)
    c = dm.compare(slow, ref, FS)
    assert c.correlation < 0.5 and c.nrmse > 0.8
    c_big = dm.compare(1.6 * ref, ref, FS)
    assert c_big.correlation > 0.999
    assert c_big.nrmse == pytest.approx(0.6, abs=0.01)


def test_cut_window_and_recording_template_line_up():
    t = np.arange(5000) / FS
    x = np.zeros_like(t)
    x[2000] = 1.0  # impact marker at t = 0.2 s
    w = dm.cut_window(t, x, 0.2, FS)
    assert w.shape == (1100,) and w[100] == 1.0
    t_rel = np.arange(-5, 995) / FS
    a = np.zeros_like(t_rel)
    a[5] = 1.0  # sample at t_rel = 0
    w2 = dm.window_from_recording(t_rel, a, FS)
    assert w2.shape == (1100,) and w2[100] == 1.0 and w2.sum() == 1.0
    # a window reaching past the end of a run repeats the end value instead of failing
    w3 = dm.cut_window(t, x + 2.0, 0.495, FS)
    assert w3.shape == (1100,) and w3[-1] == 2.0
