"""Swept sine (eq. 3.11-3.12), recording files and their validation, ETFE (section 3.4.2)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from devices.identify.etfe import detrend_ramp, etfe, quantization_step
from devices.identify.recording import read_recording, write_recording
from devices.identify.sweep import SweepConfig, swept_sine
from devices.identify.synthetic import synthetic_recording
from devices.model import ZpkModel

FS = 10_000.0


def plant():
    """Resonance at 130 Hz on a spring-like low end, plus 0.2 ms delay."""
    p = 2 * np.pi * 130 * (-0.08 + 1j)
    return ZpkModel([-2 * np.pi * 8.0], [p, np.conj(p), -2 * np.pi * 600.0], 4e6, 2e-4)


def test_sweep_follows_eq_3_11_3_12():
    cfg = SweepConfig(amplitude_A=0.5, f_start_hz=10.0, f_end_hz=500.0, duration_s=1.0, fs_hz=FS, repetitions=2)
    u = swept_sine(cfg)
    n = cfg.n_samples
    assert u.size == 2 * n and np.max(np.abs(u)) <= 0.5 + 1e-12
    np.testing.assert_array_equal(u[:n], u[n:])  # played twice back to back
    k = np.arange(n)
    f_k = 10.0 + k / (2 * (n - 1)) * 490.0
    np.testing.assert_allclose(u[:n], 0.5 * np.sin(2 * np.pi * f_k * k / FS), atol=1e-12)
    # the instantaneous frequency rises linearly from f_i to f_f: check it from the analytic signal
    phase = np.unwrap(np.angle(signal.hilbert(u[:n])))
    f_inst = np.diff(phase) * FS / (2 * np.pi)
    assert np.median(f_inst[n // 2 - 200 : n // 2 + 200]) == pytest.approx(255.0, rel=0.02)
    np.testing.assert_allclose(swept_sine(cfg, -1), -u)


def test_sweep_rejects_band_above_nyquist_and_bad_values():
    with pytest.raises(ValueError, match="Nyquist"):
        SweepConfig(f_end_hz=6000.0, fs_hz=FS)
    with pytest.raises(ValueError, match="amplitude_A"):
        SweepConfig(amplitude_A=float("nan"))
    with pytest.raises(ValueError, match="repetitions"):
        SweepConfig(repetitions=0)
    with pytest.raises(ValueError, match="polarity"):
        swept_sine(SweepConfig(), 2)


def test_detrend_ramp_zero_at_both_ends():
    y = np.linspace(3, 7, 101) + np.sin(np.arange(101))
    d = detrend_ramp(y)
    assert d[0] == 0 and abs(d[-1]) < 1e-12
    np.testing.assert_allclose(d[50], y[50] - y[0] - 0.5 * (y[-1] - y[0]))


@pytest.mark.parametrize("detrend, f_lo", [("ramp", 60.0), ("periodic", 6.0)])
def test_etfe_recovers_known_response_with_polarity_reversal(detrend, f_lo):
    m = plant()
    cfg = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=1.0, fs_hz=FS)
    recs = [synthetic_recording(m, None, cfg, polarity=(-1) ** i, accel_noise_m_s2=0.005, seed=i) for i in range(4)]
    e = etfe(recs, "accel_m_s2", label="test", detrend=detrend)
    assert e.f_hz[0] >= 5.0 and e.f_hz[-1] <= 1000.0 and e.n_trials == 4
    assert np.allclose(np.diff(e.f_hz), FS / cfg.n_samples)  # bins n fs / N (eq. 3.16)
    # the truth at these bins is the Tustin model with the delay rounded to 2 samples
    z, p, k = m.to_discrete(FS)
    _, hd = signal.freqz_zpk(z, p, k, worN=e.f_hz, fs=FS)
    truth = hd * np.exp(-2j * np.pi * e.f_hz * 2 / FS)
    sel = (e.f_hz > f_lo) & (e.f_hz < 900)
    err_db = 20 * np.log10(np.abs(e.H[sel] / truth[sel]))
    err_deg = np.degrees(np.angle(e.H[sel] / truth[sel]))
    assert np.max(np.abs(err_db)) < 0.3 and np.max(np.abs(err_deg)) < 2.0
    assert np.min(e.coherence[sel]) > 0.99
    # without sign handling, averaging +/- polarity outputs would cancel: the magnitude would collapse
    assert np.median(np.abs(e.H[sel])) > 0.5 * np.median(np.abs(truth[sel]))


def test_ramp_detrend_distorts_lowest_bins_periodic_does_not():
    """Eq. 3.13 forces y_0 = y_{N-1}; for this plant that costs > 1 dB near 10 Hz (documented)."""
    m = plant()
    cfg = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=1.0, fs_hz=FS)
    rec = synthetic_recording(m, None, cfg)
    i = 5  # 10 Hz
    z, p, k = m.to_discrete(FS)
    for detrend, bound in (("ramp", (0.5, 10.0)), ("periodic", (0.0, 1e-6))):
        e = etfe([rec], detrend=detrend, smooth=1)
        _, hd = signal.freqz_zpk(z, p, k, worN=e.f_hz[i : i + 1], fs=FS)
        err = abs(20 * np.log10(abs(e.H[i] / (hd[0] * np.exp(-2j * np.pi * e.f_hz[i] * 2 / FS)))))
        assert bound[0] <= err <= bound[1], (detrend, err)


def test_coherence_drops_with_noise():
    m = plant()
    cfg = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=1.0, fs_hz=FS)
    quiet = etfe([synthetic_recording(m, None, cfg, accel_noise_m_s2=0.01, seed=i) for i in range(3)])
    noisy = etfe([synthetic_recording(m, None, cfg, accel_noise_m_s2=3.0, seed=i) for i in range(3)])
    assert np.mean(noisy.coherence) < np.mean(quiet.coherence) - 0.1


def test_position_etfe_resolvable_band_from_quantization():
    m = plant()
    mx = ZpkModel([], [2 * np.pi * 20 * (-0.3 + 1j), 2 * np.pi * 20 * (-0.3 - 1j)], 0.002 * (2 * np.pi * 20) ** 2)
    cfg = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=1.0, fs_hz=FS)
    lsb = 2e-5
    rec = synthetic_recording(m, mx, cfg, position_lsb_m=lsb)
    assert quantization_step(rec.position_m) == pytest.approx(lsb, rel=1e-6)
    e = etfe([rec], "position_m")
    # amplitude 0.75 A * |G(f)| falls below 2 LSB near 100 Hz for this plant
    f_expected = e.f_hz[np.abs(mx.frequency_response(e.f_hz)) * 0.75 >= 2 * lsb][-1]
    assert e.resolvable_hi_hz == pytest.approx(f_expected, rel=0.15)
    assert etfe([rec], "accel_m_s2").resolvable_hi_hz >= 999.0  # unquantized accel: whole band


def _write(tmp_path, rec, name="rec.csv"):
    return write_recording(tmp_path / name, rec)


def _small_rec():
    cfg = SweepConfig(amplitude_A=0.5, f_start_hz=5.0, f_end_hz=400.0, duration_s=0.2, fs_hz=2000.0)
    return synthetic_recording(plant(), None, cfg, grip_N=1.5)


def test_recording_round_trip(tmp_path):
    rec = _small_rec()
    path = _write(tmp_path, rec)
    assert path.read_text().splitlines()[0] == "t_s,current_A,accel_m_s2,position_m,grip_N"
    side = json.loads(path.with_suffix(".json").read_text())
    for key in ("fs_hz", "f_start_hz", "f_end_hz", "duration_s", "amplitude_A", "repetitions"):
        assert key in side
    back = read_recording(path)
    np.testing.assert_allclose(back.current_A, rec.current_A, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back.accel_m_s2, rec.accel_m_s2, rtol=1e-9, atol=1e-12)
    assert back.sweep == rec.sweep and back.meta["grip_target_N"] == 1.5


def _corrupt(path, line_no, column, value):
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line_no - 1].split(",")
    cells[header.index(column)] = value
    lines[line_no - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_recording_with_nan_names_line_and_column(tmp_path):
    path = _write(tmp_path, _small_rec())
    _corrupt(path, 57, "accel_m_s2", "nan")
    with pytest.raises(ValueError, match=r"rec\.csv: line 57, column 'accel_m_s2'"):
        read_recording(path)


def test_recording_with_dropped_samples(tmp_path):
    path = _write(tmp_path, _small_rec())
    lines = path.read_text().splitlines()
    del lines[100:103]  # three samples lost
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="dropped-sample gap between lines 100 and 101"):
        read_recording(path)


def test_recording_too_short(tmp_path):
    path = _write(tmp_path, _small_rec())
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:500]) + "\n")
    with pytest.raises(ValueError, match="too few samples for the sweep"):
        read_recording(path)


def test_recording_band_above_nyquist(tmp_path):
    path = _write(tmp_path, _small_rec())
    side = path.with_suffix(".json")
    data = json.loads(side.read_text())
    data["f_end_hz"] = 1500.0  # fs 2000 Hz
    side.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"rec\.json.*Nyquist"):
        read_recording(path)


def test_recording_sidecar_and_column_errors(tmp_path):
    path = _write(tmp_path, _small_rec())
    side = path.with_suffix(".json")
    data = json.loads(side.read_text())
    del data["amplitude_A"]
    side.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="missing key 'amplitude_A'"):
        read_recording(path)
    side.unlink()
    with pytest.raises(FileNotFoundError, match="sidecar"):
        read_recording(path)
    path2 = _write(tmp_path, _small_rec(), "rec2.csv")
    text = path2.read_text().replace("grip_N", "grip", 1)
    path2.write_text(text)
    with pytest.raises(ValueError, match="missing column.*grip_N"):
        read_recording(path2)
