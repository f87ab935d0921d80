"""Identification on the simulated device: grip trend (nonlinear sim), model sets and interpolation,
time-domain validation, and the ``identify`` / ``fit`` commands end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from devices.__main__ import main as devices_main
from devices.identify import IdentifyConfig, identify_device, load_model_set
from devices.identify.modelset import ModelSet
from devices.identify.sweep import SweepConfig
from devices.identify.validate import nrmse, record_transients, validate_model
from devices.model import load_model
from devices.sim import SimDevice


def _sweep(dev, duration_s=1.0):
    return SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=duration_s,
                       fs_hz=dev.info.servo_rate_hz)


@pytest.fixture(scope="module")
def nonlinear_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ident_nl")
    dev = SimDevice.from_spec(None, seed=1)
    with dev:
        cfg = IdentifyConfig(grips_N=(1.0, 4.0), trials=2, sweep=_sweep(dev))
        report = identify_device(dev, cfg, out, log=lambda *_: None, device_spec="sim")
    return out, report


def test_nonlinear_sim_fits_reported_per_grip_and_resonance_drops_with_grip(nonlinear_run):
    out, report = nonlinear_run
    rows = {r["grip_N"]: r for r in report["grips"]}
    assert set(rows) == {1.0, 4.0}
    for r in rows.values():
        assert {"rms_db", "rms_phase_deg", "worst_band_db", "order", "delay_s"} <= set(r["accel"])
        assert r["accel"]["rms_db"] < 3.0 and abs(r["grip_measured_N"] - r["grip_N"]) < 0.05
    # section 3.4.6: higher grip, lower magnitude at the main resonance (ETFE and fitted model)
    # issue 16: with the default simulated person (an arm mass behind the grip) the drop is 0.26 dB (was > 1 dB
    # with the prescribed hand tied to ground)
    assert rows[4.0]["accel"]["peak_db"] < rows[1.0]["accel"]["peak_db"] - 0.1
    mset = load_model_set(out)
    m1, m4 = mset.model_at(1.0), mset.model_at(4.0)
    f = np.arange(40.0, 200.0, 0.5)
    assert np.max(np.abs(m4.frequency_response(f))) < np.max(np.abs(m1.frequency_response(f)))
    assert m1.grip_N == 1.0 and m4.grip_N == 4.0
    text = (out / "report.txt").read_text()
    assert "accel" in text and "position" in text and "NRMSE" in text
    for name in ("bode_accel.png", "bode_position.png", "model_set.json", "accel_g1N.json", "report.json"):
        assert (out / name).stat().st_size > 0
    assert (out / "bode_accel.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((out / "recordings").glob("g*N_t*.csv"))) == 4
    assert len(list((out / "recordings").glob("transients_g*N.csv"))) == 2


def test_interpolated_model_between_grips_matches_the_sim_at_that_grip():
    """Interpolation in dB and phase between the 1 N and 3 N models predicts the 2 N one."""
    dev = SimDevice.from_spec("lti")
    ms = [dev.linear_model(g, "accel_m_s2") for g in (1.0, 3.0)]
    ms = [type(m)(m.zeros_rad_s, m.poles_rad_s, m.gain, m.delay_s, band_hz=(10.0, 1000.0), grip_N=g)
          for m, g in zip(ms, (1.0, 3.0))]
    mset = ModelSet(np.array([1.0, 3.0]), {"accel_m_s2": ms})
    f = np.arange(20.0, 500.0, 1.0)
    truth = dev.linear_model(2.0, "accel_m_s2").frequency_response(f)
    h = mset.response_at(2.0, f)
    err_db = 20 * np.log10(np.abs(h / truth))
    # the low end (user spring, magnitude ~ 1/k_u(grip)) is the least linear in grip: about 1 dB at 20 Hz
    assert np.max(np.abs(err_db)) < 1.5 and np.max(np.abs(err_db[f >= 50])) < 0.5
    err_deg = np.degrees(np.angle(h / truth))
    assert np.max(np.abs(err_deg)) < 8.0 and np.max(np.abs(err_deg[f >= 200])) < 1.0
    # it lies between the neighbours at the resonance, and the refitted zpk model reproduces it
    i = int(np.argmin(np.abs(f - 128.0)))
    lo, hi = sorted(abs(m.frequency_response(f[i : i + 1])[0]) for m in ms)
    assert lo <= abs(h[i]) <= hi
    m2 = mset.model_at(2.0)
    assert m2.grip_N == 2.0 and m2.is_stable and m2.fit["interpolated_from_grip_N"] == [1.0, 3.0]
    r = m2.frequency_response(f) / h
    assert np.max(np.abs(20 * np.log10(np.abs(r)))) < 0.2
    # exact grips return the stored models; outside the range the nearest is used
    assert mset.model_at(1.0) is ms[0] and mset.model_at(7.0) is ms[1] and mset.model_at(0.0) is ms[0]


def test_model_set_save_load_and_errors(tmp_path):
    dev = SimDevice.from_spec("lti")
    ms = [dev.linear_model(g) for g in (1.0, 2.0)]
    mset = ModelSet(np.array([1.0, 2.0]), {"accel_m_s2": ms})
    path = mset.save(tmp_path)
    back = load_model_set(path)
    np.testing.assert_allclose(back.response_at(1.5, [100.0]), mset.response_at(1.5, [100.0]), rtol=1e-9)
    data = json.loads(path.read_text())
    del data["grip_N"]
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="missing key 'grip_N'"):
        load_model_set(path)
    with pytest.raises(ValueError, match="strictly increasing"):
        ModelSet(np.array([2.0, 1.0]), {"accel_m_s2": ms})
    with pytest.raises(ValueError, match="no 'position_m' models"):
        mset.model_at(1.5, "position_m")


def test_model_set_index_entries_must_match_the_models_they_name(tmp_path, capsys):
    """Audit modelset_grip_swapped / modelset_output_mismatch / model_neg_grip: a list out of grip order, a
    position model under accel_m_s2 and a negative grip were loaded silently (validate then printed NRMSE
    1.000 and model_at(0 N) returned the 10 N model)."""
    dev = SimDevice.from_spec("lti")
    mset = ModelSet(np.array([1.0, 2.0, 5.0]), {"accel_m_s2": [dev.linear_model(g) for g in (1.0, 2.0, 5.0)],
                                              "position_m": [dev.linear_model(g, "position_m") for g in (1.0, 2.0, 5.0)]})
    path = mset.save(tmp_path)
    assert load_model_set(path).model_at(1.0).grip_N == 1.0
    good = json.loads(path.read_text())
    swapped = json.loads(path.read_text())
    accel = swapped["models"]["accel_m_s2"]
    accel[0], accel[2] = accel[2], accel[0]
    path.write_text(json.dumps(swapped))
    with pytest.raises(ValueError, match=r"models\.accel_m_s2\[0\] = .* identified at grip 5 N, not at the index's "
                                         r"level 1 N"):
        load_model_set(path)
    crossed = json.loads(json.dumps(good))
    crossed["models"]["accel_m_s2"][1] = good["models"]["position_m"][1]
    path.write_text(json.dumps(crossed))
    with pytest.raises(ValueError, match=r"models\.accel_m_s2\[1\] = .* is a model of 'position_m', not 'accel_m_s2'"):
        load_model_set(path)
    # the CLI says so in one line (it printed "NRMSE 1.000" for the crossed set)
    assert devices_main(["validate", str(tmp_path), "--grip", "2"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]
    assert len(err) == 1 and "is a model of 'position_m'" in err[0], err
    # identification records the mean measured grip: near its level is accepted
    m = json.loads((tmp_path / good["models"]["accel_m_s2"][1]).read_text())
    m["grip_N"] = 2.3
    (tmp_path / good["models"]["accel_m_s2"][1]).write_text(json.dumps(m))
    path.write_text(json.dumps(good))
    assert load_model_set(path).model_at(2.0).grip_N == pytest.approx(2.3)
    m["grip_N"] = -5.0
    (tmp_path / good["models"]["accel_m_s2"][1]).write_text(json.dumps(m))
    with pytest.raises(ValueError, match=r"grip_N: must be >= 0 N, got -5"):
        load_model_set(path)
    with pytest.raises(ValueError, match=">= 0 N"):
        ModelSet(np.array([-1.0, 2.0]), {"accel_m_s2": [dev.linear_model(g) for g in (1.0, 2.0)]})


def test_time_domain_validation_on_lti_sim():
    dev = SimDevice.from_spec("lti", seed=2)
    with dev:
        u, a, _, windows = record_transients(dev, 1.0, grip_N=2.0)
        good = dev.linear_model(2.0)
    v = validate_model(good, u, a, dev.info.servo_rate_hz, windows)
    assert v["nrmse"] < 0.1 and len(v["nrmse_per_transient"]) == 4
    wrong = type(good)(good.zeros_rad_s, good.poles_rad_s, good.gain * 0.5, good.delay_s)
    assert validate_model(wrong, u, a, dev.info.servo_rate_hz)["nrmse"] > 0.4
    assert nrmse([1.0, -1.0], [1.0, -1.0]) == 0.0


def test_cli_identify_then_fit(tmp_path, capsys):
    out = tmp_path / "id"
    rc = devices_main(["identify", "--device", "sim:lti", "--grip", "2", "--trials", "2", "--duration", "1",
                       "--no-validate", "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "accel" in printed and "model_set.json" in printed
    model = load_model(out / "accel_g2N.json")
    assert model.grip_N == pytest.approx(2.0, abs=0.05) and model.output == "accel_m_s2"
    assert {"rms_db", "rms_phase_deg", "worst_band_db", "order_table"} <= set(model.fit)
    recs = sorted(str(p) for p in (out / "recordings").glob("*.csv"))
    target = tmp_path / "fit.json"
    rc = devices_main(["fit", *recs, "--band", "20", "800", "--weight", "low", "--out", str(target),
                       "--plot", str(tmp_path / "fit.png")])
    assert rc == 0 and target.exists() and (tmp_path / "fit.png").exists()
    m = load_model(target)
    assert m.band_hz[0] == pytest.approx(20.0, abs=1) and m.fit["weight"] == "low"
    f = np.arange(30.0, 700.0)
    ratio = m.frequency_response(f) / model.frequency_response(f)
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) < 1.0
    # a fit that cannot reach the requested error writes nothing and exits 2
    bad = tmp_path / "bad.json"
    rc = devices_main(["fit", *recs, "--order", "1", "--max-rms-db", "0.1", "--out", str(bad)])
    assert rc == 2 and not bad.exists()
    assert "did not reach the requested error" in capsys.readouterr().err
    # --plot writes fit.png, fit.svg and fit.plot.csv; a plot whose data file alone exists is refused
    # before fitting, naming it (figstyle.check_outputs), and the user's file is kept
    assert (tmp_path / "fit.plot.csv").exists() and not (tmp_path / "fit.csv").exists()
    mine = tmp_path / "mine.plot.csv"
    mine.write_text("my data\n")
    rc = devices_main(["fit", *recs, "--out", str(tmp_path / "fit2.json"), "--plot", str(tmp_path / "mine.png")])
    err = capsys.readouterr().err
    assert rc == 2 and f"{mine} exists" in err and "--force" in err
    assert mine.read_text() == "my data\n" and not (tmp_path / "fit2.json").exists()


def test_cli_fit_refuses_bad_recording(tmp_path, capsys):
    from devices.identify.synthetic import synthetic_recording
    from devices.identify.recording import write_recording

    dev = SimDevice.from_spec("lti")
    rec = synthetic_recording(dev.linear_model(2.0), None, SweepConfig(duration_s=0.5, fs_hz=10_000.0))
    path = write_recording(tmp_path / "r.csv", rec)
    lines = path.read_text().splitlines()
    lines[10] = lines[10].replace(lines[10].split(",")[2], "nan", 1)
    path.write_text("\n".join(lines) + "\n")
    assert devices_main(["fit", str(path), "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "r.csv: line 11" in err and not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("grip", ["x", True, [2.0], 10 ** 400])
def test_cli_fit_refuses_a_sidecar_grip_that_is_not_a_number(tmp_path, capsys, grip):
    """Audit fit_sidecar_grip_str.txt: grip_mean_N "x" in a recording's sidecar was a raw TypeError out of the
    curve grouping; now exit 2 naming the sidecar and the key."""
    import json

    from devices.identify.recording import sidecar_path, write_recording
    from devices.identify.synthetic import synthetic_recording

    dev = SimDevice.from_spec("lti")
    rec = synthetic_recording(dev.linear_model(2.0), None, SweepConfig(duration_s=0.5, fs_hz=10_000.0))
    path = write_recording(tmp_path / "g2N_t0.csv", rec)
    side = sidecar_path(path)
    meta = json.loads(side.read_text())
    meta["grip_mean_N"] = grip
    side.write_text(json.dumps(meta))
    capsys.readouterr()
    assert devices_main(["fit", str(path), "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {side}: key 'grip_mean_N' must be a finite number"), err
    assert not (tmp_path / "m.json").exists()


class _GripStub:
    """Wraps the sim as if it were hardware (no set_user, grip read from the sensor) with a scripted grip."""

    def __init__(self, grip_of_t):
        self.sim = SimDevice.from_spec("lti")
        self.sim.open()
        self.info = self.sim.info
        self.simulated = False
        self.grip_of_t = grip_of_t
        self.t0 = 0.0

    def read(self):
        st = self.sim.read()
        st.grip_N = self.grip_of_t(st.t_s)
        return st

    def command(self, i):
        self.sim.command(i)

    def zero(self):
        self.sim.zero()


def test_hardware_path_discards_trials_whose_grip_varies():
    """On hardware a trial whose grip varies by more than +-0.5 N is discarded and repeated (sec. 3.4.6)."""
    from devices.identify.record import record_condition

    # grip 2 N, but a squeeze of +1.5 N during 1.0-1.3 s of simulated time (inside the first trial's sweep)
    dev = _GripStub(lambda t: 2.0 + (1.5 if 1.0 < t < 1.3 else 0.0))
    sweep = SweepConfig(duration_s=0.5, fs_hz=dev.info.servo_rate_hz)
    logs = []
    recs = record_condition(dev, sweep, 2.0, trials=2, log=logs.append)
    assert len(recs) == 2 and all(r.grip_variation_N() <= 0.5 for r in recs)
    assert any("discarded" in m and "grip varied" in m for m in logs)
    assert any("hold the handle" in m for m in logs)


def test_identify_reports_an_output_that_cannot_be_fitted(tmp_path):
    """A device whose position never changes: accel models are written, position is reported as failed."""
    dev = _GripStub(lambda t: 2.0)
    orig_read = dev.read

    def read():
        st = orig_read()
        st.position_m = 0.0
        return st

    dev.read = read
    cfg = IdentifyConfig(grips_N=(2.0,), trials=1, sweep=_sweep(dev, 0.5), validate=False)
    logs = []
    report = identify_device(dev, cfg, tmp_path, log=logs.append, device_spec="stub")
    row = report["grips"][0]
    assert "error" in row["position"] and "rms_db" in row["accel"]
    assert any("position: FIT FAILED" in m for m in logs)
    mset = load_model_set(tmp_path)
    assert mset.model_at(2.0).output == "accel_m_s2" and "position_m" not in mset.models


def test_transient_recording_round_trip_and_cli_validate(tmp_path, capsys):
    from devices.identify.validate import read_transient_recording, write_transient_recording

    dev = SimDevice.from_spec("lti", seed=5)
    with dev:
        u, a, x, _ = record_transients(dev, 1.0, grip_N=2.0)
        model = dev.linear_model(2.0)
    fs = dev.info.servo_rate_hz
    path = write_transient_recording(tmp_path / "tr.csv", fs, u, a, x, 2.0)
    fs2, u2, a2 = read_transient_recording(path)
    assert fs2 == pytest.approx(fs) and np.allclose(u2, u) and np.allclose(a2, a)
    assert validate_model(model, u2, a2, fs2)["nrmse"] < 0.1
    lines = path.read_text().splitlines()
    lines[30] = lines[30].replace(lines[30].split(",")[1], "nan", 1)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="line 31, column 'current_A'"):
        read_transient_recording(bad)
    # the fit command validates its model on the transients
    out = tmp_path / "id"
    assert devices_main(["identify", "--device", "sim:lti", "--grip", "2", "--trials", "1", "--duration", "1",
                         "--out", str(out)]) == 0
    capsys.readouterr()
    recs = [str(p) for p in (out / "recordings").glob("g2N_t*.csv")]
    assert devices_main(["fit", *recs, "--out", str(tmp_path / "m.json"), "--validate", str(path)]) == 0
    text = capsys.readouterr().out
    nrmse_printed = float(text.split("NRMSE ")[1].split()[0])
    assert nrmse_printed < 0.1


def test_identification_shows_progress_per_grip(tmp_path, capsys):
    """Issue 14: grip n of N with elapsed and time left, as plain lines when stderr is not a terminal."""
    dev = SimDevice.from_spec("lti", seed=3)
    with dev:
        cfg = IdentifyConfig(grips_N=(1.0, 3.0), trials=1, sweep=_sweep(dev, 0.5), validate=False, workers=1)
        identify_device(dev, cfg, tmp_path, log=lambda *_: None, device_spec="sim:lti")
    err = capsys.readouterr().err.splitlines()
    lines = [ln for ln in err if ln.startswith("identifying sim:lti: ")]
    assert [ln.split(": ", 1)[1].split(" (")[0] for ln in lines] == ["1 of 2 grips done", "2 of 2 grips done"], err
    assert "(grip 1 N)" in lines[0] and "(grip 3 N)" in lines[1]
    assert "about" in lines[0] and "left" in lines[0] and "elapsed" in lines[1]


def test_identify_only_the_acceleration_output_without_figures(tmp_path):
    """What the HFAM pipeline asks for (stimuli.hfam.pipeline.identify_grips): H_ha only, no Bode figures."""
    dev = SimDevice.from_spec("lti", seed=4)
    with dev:
        cfg = IdentifyConfig(grips_N=(1.0, 3.0), trials=1, sweep=_sweep(dev, 0.5), validate=False, workers=1,
                             outputs=("accel_m_s2",), figures=False)
        report = identify_device(dev, cfg, tmp_path, log=lambda *_: None, device_spec="sim:lti", progress=False)
    assert all("accel" in row and "position" not in row for row in report["grips"])
    assert not list(tmp_path.glob("bode_*.png")) and not (tmp_path / "etfe_position.npz").exists()
    data = np.load(tmp_path / "etfe_accel.npz")
    assert data["H"].shape == (2, data["f_hz"].size) and list(data["grip_N"]) == pytest.approx([1.0, 3.0], abs=0.3)
    mset = load_model_set(tmp_path)
    assert set(mset.models) == {"accel_m_s2"} and list(mset.grip_N) == [1.0, 3.0]
    with pytest.raises(ValueError, match="outputs must be some of"):
        IdentifyConfig(outputs=("force",))
