"""Automatic LTI fitting (section 3.4.4 automated): exact recovery, delay, weights, failure, known LTI sim."""

from __future__ import annotations

import numpy as np
import pytest

from devices.identify.etfe import Etfe, etfe
from devices.identify.fit import FitError, FitOptions, combine_curves, fit_errors, fit_etfes, fit_frequency_response
from devices.identify.record import record_condition
from devices.identify.sweep import SweepConfig
from devices.model import ZpkModel


def fifth_order(delay_s=0.0):
    """A 5th-order rational function: real pole, two resonances, a lightly damped zero pair."""
    up = 2 * np.pi * np.array([130.0, 400.0]) * (-0.05 + 1j)
    poles = np.concatenate([[-2 * np.pi * 50], up, np.conj(up)])
    zeros = [-2 * np.pi * 5, 2 * np.pi * 250 * (-0.1 + 1j), 2 * np.pi * 250 * (-0.1 - 1j)]
    return ZpkModel(zeros, poles, 3e5, delay_s)


def test_fifth_order_recovered_to_1e_6_without_noise():
    truth = fifth_order()
    f = np.arange(10.0, 1000.0, 0.5)
    res = fit_frequency_response(f, truth.frequency_response(f))  # order and delay automatic
    m = res.model
    assert m.order == 5 and m.delay_s == 0.0
    rel = np.abs(m.frequency_response(f) / truth.frequency_response(f) - 1)
    assert np.max(rel) < 1e-6
    np.testing.assert_allclose(np.sort_complex(m.poles_rad_s), np.sort_complex(truth.poles_rad_s), rtol=1e-6)
    np.testing.assert_allclose(np.sort_complex(m.zeros_rad_s), np.sort_complex(truth.zeros_rad_s), rtol=1e-6)
    assert m.gain == pytest.approx(truth.gain, rel=1e-6)
    assert res.metrics["rms_db"] < 1e-6 and m.is_stable
    # the error-versus-order table is reported; lower orders are clearly worse
    rows = {r["order"]: r for r in res.table}
    assert rows[4]["rms_db"] > 0.5 and rows[5]["rms_db"] < 1e-6


def test_delay_estimated():
    truth = fifth_order(delay_s=2.5e-4)
    f = np.arange(10.0, 1000.0, 0.5)
    m = fit_frequency_response(f, truth.frequency_response(f)).model
    assert m.delay_s == pytest.approx(2.5e-4, abs=1e-7)
    assert np.max(np.abs(m.frequency_response(f) / truth.frequency_response(f) - 1)) < 1e-5


def test_fixed_order_and_unreachable_error_raises():
    truth = fifth_order()
    f = np.arange(10.0, 1000.0, 0.5)
    H = truth.frequency_response(f)
    with pytest.raises(FitError, match="did not reach the requested error.*no model written"):
        fit_frequency_response(f, H, options=FitOptions(order=2, max_rms_db=0.5))
    res = fit_frequency_response(f, H, options=FitOptions(order=3, max_rms_db=100, max_rms_phase_deg=180))
    assert res.model.order == 3 and res.metrics["rms_db"] > 1.0


def test_bad_data_refused():
    f = np.arange(10.0, 100.0)
    H = np.ones(f.size, complex)
    H[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fit_frequency_response(f, H)
    with pytest.raises(ValueError, match="outside the data's band"):
        fit_frequency_response(f, np.ones(f.size, complex), options=FitOptions(band_hz=(5.0, 50.0)))
    with pytest.raises(ValueError, match="weight"):
        FitOptions(weight="median")


def test_fit_errors_figures():
    f = np.geomspace(10, 1000, 300)
    H = np.exp(-1j * f / 1000)
    e = fit_errors(f, H, H * 10 ** (1 / 20) * np.exp(1j * np.radians(5)))
    assert e["rms_db"] == pytest.approx(1.0) and e["rms_phase_deg"] == pytest.approx(5.0)
    assert e["worst_band_db"] == pytest.approx(1.0) and e["max_abs_db"] == pytest.approx(1.0)


def _curve(model, scale, label):
    f = np.arange(10.0, 1000.0, 1.0)
    H = model.frequency_response(f) * scale
    return Etfe(f, H, H, np.ones(f.size), "accel_m_s2", 1, 0.0, label)


def test_weights_envelopes_and_mean():
    """high fits the upper envelope (HFAM), low the lower (cancellation), mean the average (sec. 3.4.4)."""
    base = fifth_order()
    curves = [_curve(base, 1.0, "a"), _curve(base, 2.0, "b")]  # +6 dB everywhere
    f, hi, _ = combine_curves(curves, "high")
    _, lo, _ = combine_curves(curves, "low")
    _, mean, _ = combine_curves(curves, "mean")
    np.testing.assert_allclose(np.abs(hi), np.abs(curves[1].H))
    np.testing.assert_allclose(np.abs(lo), np.abs(curves[0].H))
    np.testing.assert_allclose(np.abs(mean), np.sqrt(2) * np.abs(curves[0].H))  # +3 dB: mean in dB
    g = {w: fit_etfes(curves, FitOptions(weight=w, delay_s=0.0)).model for w in ("high", "low", "mean")}
    ref = np.abs(base.frequency_response([130.0]))[0]
    assert np.abs(g["high"].frequency_response([130.0]))[0] == pytest.approx(2 * ref, rel=1e-3)
    assert np.abs(g["low"].frequency_response([130.0]))[0] == pytest.approx(ref, rel=1e-3)
    assert g["mean"].fit["weight"] == "mean" and g["mean"].fit["n_curves"] == 2


def test_known_lti_sim_fitted_within_1_db_and_10_deg():
    """sim:lti with its encoder/ADC quantization and accelerometer noise on; truth = its analytic model."""
    from devices.sim import SimDevice

    dev = SimDevice.from_spec("lti", seed=3)
    dev.open()
    try:
        sweep = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=2.0,
                            fs_hz=dev.info.servo_rate_hz)
        recs = record_condition(dev, sweep, grip_N=2.0, trials=2)
        assert all(np.ptp(r.accel_m_s2) > 0 for r in recs)
        truth = dev.linear_model(2.0, "accel_m_s2")
    finally:
        dev.close()
    res = fit_etfes([etfe(recs, "accel_m_s2")], FitOptions(band_hz=(10.0, 1000.0)))
    f = np.arange(20.0, 500.0, 0.5)
    ratio = res.model.frequency_response(f) / truth.frequency_response(f)
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) < 1.0
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 10.0
    assert res.model.is_stable and res.metrics["rms_db"] < 1.0


def test_minimum_phase_option_mirrors_rhp_zeros_keeps_magnitude():
    up = 2 * np.pi * 130.0 * (-0.05 + 1j)
    rhp = 2 * np.pi * 300.0 * (0.3 + 1j)  # a right-half-plane zero pair inside the band
    truth = ZpkModel([rhp, np.conj(rhp)], [up, np.conj(up), -2 * np.pi * 50.0, -2 * np.pi * 700.0], 1e6, 1e-4)
    f = np.arange(10.0, 1000.0, 0.5)
    H = truth.frequency_response(f)
    plain = fit_frequency_response(f, H).model
    assert plain.fit["nonminimum_phase_zeros"] == 2
    mp = fit_frequency_response(f, H, options=FitOptions(minimum_phase=True, max_rms_phase_deg=180)).model
    assert np.all(mp.zeros_rad_s.real <= 0) and mp.fit["reflected_zeros"] == 2
    np.testing.assert_allclose(np.abs(mp.frequency_response(f)), np.abs(plain.frequency_response(f)), rtol=1e-9)
    assert mp.fit["rms_phase_deg"] > plain.fit["rms_phase_deg"]  # the phase change is reported, not hidden
