"""Issue 21 item 5 (identify the six default grips in < 5 s): the faster paths give the same results as the
plain ones: the parallel identification (a recording process, fitting processes, figures in two processes),
the CSV and figure writers, and the vector-fitting steps (bit for bit)."""

from __future__ import annotations


import numpy as np
import pandas as pd
import pytest
import scipy.linalg

from devices.base import DeviceError
from devices.identify import pipeline, vfit
from devices.identify.etfe import Etfe
from devices.identify.figures import bode_lines, bode_plot
from devices.identify.fit import FitOptions
from devices.identify.pipeline import IdentifyConfig, draw_bode_plots, identify_device
from devices.identify.recording import write_csv_columns
from devices.identify.sweep import SweepConfig
from devices.model import ZpkModel
from devices.registry import make_device


def _cfg(**kw):
    sweep = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=0.5, fs_hz=1e4)
    opts = FitOptions(max_order=7)
    return IdentifyConfig(grips_N=(0.0, 2.0, 5.0), trials=2, sweep=sweep, accel_options=opts,
                          position_options=opts, **kw)


def test_parallel_identification_equals_each_grip_on_a_fresh_device(tmp_path):
    """The recording process records sweeps and transients back to back; the result must equal identifying
    each grip on its own fresh device (seed + 1000 k), fits and transients included."""
    cfg = _cfg(workers=2)
    dev = make_device("sim:lti", seed=3)
    with dev:
        report = identify_device(dev, cfg, tmp_path / "par", log=lambda *_: None, device_spec="sim:lti", seed=3,
                                 progress=False)
    ref = tmp_path / "ref"
    rows = []
    for k, g in enumerate(cfg.grips_N):
        d = make_device("sim:lti", seed=3 + 1000 * k)
        with d:
            rows.append(pipeline._identify_grip(d, k, g, cfg, "sim:lti", ref)[0])
    assert report["grips"] == rows
    par = sorted(p.relative_to(tmp_path / "par") for p in (tmp_path / "par" / "recordings").iterdir())
    assert par == sorted(p.relative_to(ref) for p in (ref / "recordings").iterdir())
    assert any(p.name.startswith("transients_") for p in par)
    for p in par:
        assert (tmp_path / "par" / p).read_bytes() == (ref / p).read_bytes(), p


def test_recording_error_in_parallel_identification_is_raised(tmp_path, monkeypatch):
    real = pipeline._record_worker

    def failing(job):
        if job[3] == 2.0:
            raise DeviceError("handle slipped")
        return real(job)

    monkeypatch.setattr(pipeline, "_record_worker", failing)  # the recording process is forked: it sees this
    dev = make_device("sim:lti")
    with dev, pytest.raises(DeviceError, match="handle slipped"):
        identify_device(dev, _cfg(workers=2, validate=False, figures=False), tmp_path, log=lambda *_: None,
                        device_spec="sim:lti", progress=False)


def _curves_and_models():
    f = np.arange(5.0, 1000.0, 2.5)
    curves, models = [], []
    for i, (fn, label) in enumerate([(80.0, "grip 0 N"), (95.0, "grip 2 N, 0.75 A"), (120.0, "")]):
        wn = 2 * np.pi * fn
        p = -0.08 * wn + 1j * wn
        m = ZpkModel(np.array([0.0, 0.0]), np.array([p, np.conj(p)]), 30.0, delay_s=1e-4, band_hz=(10.0, 900.0),
                     grip_N=float(i))
        H = m.frequency_response(f) * (1 + 0.05 * np.sin(f / 7.0))
        coh = np.where((f > 300 + 50 * i) & (f < 400 + 50 * i), 0.3, 0.97)
        curves.append(Etfe(f, H, H, coh, "accel_m_s2", 4, float(i), label, resolvable_hi_hz=950.0))
        models.append(m)
    return curves, models


def test_bode_plots_in_parallel_write_the_same_files(tmp_path):
    curves, models = _curves_and_models()
    jobs = [(curves, models, tmp_path / "a" / "bode_one.png", "one"),
            (curves[:2], [models[0]], tmp_path / "a" / "bode_two.png", "two")]
    par = draw_bode_plots(jobs, parallel=True)
    ser = draw_bode_plots([(c, m, tmp_path / "b" / p.name, t) for c, m, p, t in jobs], parallel=False)
    assert [p.name for p in par] == [p.name for p in ser] == ["bode_one.png", "bode_two.png"]
    for name in ("bode_one", "bode_two"):
        for ext in ("png", "svg", "plot.csv"):
            assert (tmp_path / "a" / f"{name}.{ext}").read_bytes() == (tmp_path / "b" / f"{name}.{ext}").read_bytes()


def _pandas_csv(curves, models) -> str:
    """The figure's CSV as it was written before (rows of dicts through pandas)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lines = bode_lines(curves, models)
    rows, marks = [], []
    for e in lines["etfe"]:
        rows += [{"curve": e["label"], "kind": "etfe", "f_hz": f, "magnitude_db": m, "phase_deg": p,
                  "coherence": h, "trusted": bool(t)}
                 for f, m, p, h, t in zip(e["f_hz"], e["magnitude_db"], e["phase_deg"], e["coherence"],
                                          e["trusted"])]
    for d in lines["models"]:
        rows += [{"curve": d["label"], "kind": "model", "f_hz": f, "magnitude_db": m, "phase_deg": p}
                 for f, m, p in zip(d["f_hz"], d["magnitude_db"], d["phase_deg"])]
        for kind in ("resonance", "minus_3db"):
            if d[kind] is not None:
                marks.append({"curve": d["label"], "kind": kind, "f_hz": d[kind][0], "magnitude_db": d[kind][1]})
    data = pd.DataFrame(rows)
    if marks:
        data = pd.concat([data, pd.DataFrame(marks)], ignore_index=True)
    return data.to_csv(index=False, float_format="%.9g", lineterminator="\n")


@pytest.mark.parametrize("case", ["own models", "shared model", "a missing model"])
def test_bode_csv_is_what_pandas_wrote(tmp_path, case):
    curves, models = _curves_and_models()
    models = {"own models": models, "shared model": [models[1]], "a missing model": [models[0], None, models[2]]}[case]
    bode_plot(curves, models, tmp_path / "bode.png")
    assert (tmp_path / "bode.plot.csv").read_text() == _pandas_csv(curves, models)


def test_csv_columns_are_the_text_of_savetxt(tmp_path):
    rng = np.random.default_rng(1)
    t = np.arange(5000) / 1e4
    cur = 0.75 * np.sin(2 * np.pi * 37.0 * t)
    odd = np.array([0.0, -0.0, np.inf, -np.inf, 1e-300, 5e-324, 1 / 3, -2.5] * 625)
    cols = ["t_s", "current_A", "accel_m_s2", "odd", "grip_N"]
    for trial in range(6):  # the same time and current columns again (cached text), others new
        arrays = [t, cur if trial % 2 else -cur, np.round(rng.normal(size=t.size), 2), odd, np.full(t.size, 2)]
        path = write_csv_columns(tmp_path / f"r{trial}.csv", cols, arrays)
        np.savetxt(tmp_path / "ref.csv", np.column_stack(arrays), fmt="%.10g", delimiter=",",
                   header=",".join(cols), comments="")
        assert path.read_text() == (tmp_path / "ref.csv").read_text()
    write_csv_columns(tmp_path / "empty.csv", ["a", "b"], [np.zeros(0), np.zeros(0)])
    assert (tmp_path / "empty.csv").read_text() == "a,b\n"
    with pytest.raises(ValueError):
        write_csv_columns(tmp_path / "bad.csv", ["a", "b"], [np.zeros(3), np.zeros(4)])


# -- vector fitting: the plain formulation the fast steps must reproduce bit for bit ---------------------------
def _ref_lstsq_scaled(M, rhs):
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0] = 1.0
    Ms = M / norms
    G = Ms.T @ Ms
    G[np.diag_indices_from(G)] += 1e-13
    try:
        c, low = scipy.linalg.cho_factor(G, check_finite=False)
        x = scipy.linalg.cho_solve((c, low), Ms.T @ rhs, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        x, *_ = np.linalg.lstsq(Ms, rhs, rcond=None)
    return x / norms


def _ref_join(reals, upper):
    pairs = np.column_stack([upper, np.conj(upper)]).ravel() if upper.size else np.zeros(0, complex)
    return np.concatenate([reals.astype(complex), pairs])


def _ref_realization(reals, upper, coef):
    n = reals.size + 2 * upper.size
    A, b, c = np.zeros((n, n)), np.zeros(n), np.asarray(coef, dtype=float).copy()
    for i, a in enumerate(reals):
        A[i, i] = a
        b[i] = 1.0
    for j, p in enumerate(upper):
        i = reals.size + 2 * j
        A[i : i + 2, i : i + 2] = [[p.real, p.imag], [-p.imag, p.real]]
        b[i] = 2.0
    return A, b, c


def _ref_relocate(s, H, w, poles, direct):
    reals, upper = vfit.split_poles(poles)
    Phi = vfit._basis(s, reals, upper)
    m, n = Phi.shape
    wH = w * H
    blocks = [w[:, None] * Phi]
    if direct:
        blocks.append(w[:, None].astype(complex))
    blocks += [-wH[:, None] * Phi, -wH[:, None]]
    M = np.hstack(blocks)
    rows = np.vstack([M.real, M.imag])
    scale = np.linalg.norm(wH) / m
    extra = np.zeros(M.shape[1])
    extra[-(n + 1) : -1] = np.sum(Phi.real, axis=0)
    extra[-1] = m
    x = _ref_lstsq_scaled(np.vstack([rows, scale * extra]), np.concatenate([np.zeros(2 * m), [scale * m]]))
    ct, dt = x[-(n + 1) : -1], x[-1]
    if abs(dt) < 1e-8:
        dt = 1.0
        M2 = np.hstack(blocks[:-1])
        ct = _ref_lstsq_scaled(np.vstack([M2.real, M2.imag]), np.concatenate([wH.real, wH.imag]))[-n:]
    A, b, c = _ref_realization(reals, upper, ct)
    r2, u2 = vfit.split_poles(vfit._stabilize(np.linalg.eigvals(A - np.outer(b, c) / dt)))
    return _ref_join(r2, u2)


def _ref_fit_residues(s, H, w, poles, direct):
    reals, upper = vfit.split_poles(poles)
    Phi = vfit._basis(s, reals, upper)
    M = w[:, None] * Phi
    if direct:
        M = np.hstack([M, w[:, None].astype(complex)])
    wH = w * H
    x = _ref_lstsq_scaled(np.vstack([M.real, M.imag]), np.concatenate([wH.real, wH.imag]))
    coef = x[: Phi.shape[1]]
    res = np.concatenate([coef[: reals.size].astype(complex),
                          np.column_stack([coef[reals.size :: 2] + 1j * coef[reals.size + 1 :: 2],
                                           coef[reals.size :: 2] - 1j * coef[reals.size + 1 :: 2]]).ravel()])
    return vfit.PoleResidue(_ref_join(reals, upper), res, float(x[-1]) if direct else 0.0)


def _ref_vector_fit(s, H, w, order, n_iter, direct, poles0, tol):
    w_abs = np.abs(s.imag)
    poles = vfit.initial_poles(order, w_abs.min(), w_abs.max()) if poles0 is None else np.asarray(poles0, complex)
    for _ in range(n_iter):
        new = _ref_relocate(s, H, w, poles, direct)
        moved = np.max(np.abs(np.sort_complex(new) - np.sort_complex(poles)) / np.maximum(np.abs(new), 1.0))
        poles = new
        if moved < tol:
            break
    return _ref_fit_residues(s, H, w, poles, direct)


def _same(a: vfit.PoleResidue, b: vfit.PoleResidue) -> bool:
    return (a.poles.tobytes() == b.poles.tobytes() and a.residues.tobytes() == b.residues.tobytes()
            and a.d == b.d)


@pytest.mark.parametrize("order", [1, 2, 5, 8, 11])
def test_vector_fitting_is_bit_for_bit_the_plain_formulation(order):
    rng = np.random.default_rng(order)
    f = np.geomspace(10.0, 1000.0, 300)
    s = 2j * np.pi * f
    truth = ZpkModel(np.array([-2 * np.pi * 30.0]), 2 * np.pi * np.array([-20 + 130j, -20 - 130j, -60 + 420j,
                                                                          -60 - 420j, -300]), 4e5)
    H = truth.frequency_response(f) * np.exp(0.05 * rng.normal(size=f.size) + 0.05j * rng.normal(size=f.size))
    w = rng.uniform(0.5, 1.0, f.size) / np.abs(H)
    for direct in (False, True):
        assert _same(vfit.vector_fit(s, H, w, order, n_iter=12, direct=direct, tol=1e-7),
                     _ref_vector_fit(s, H, w, order, 12, direct, None, 1e-7))
    poles0 = _ref_vector_fit(s, H, w, order, 3, False, None, 0.0).poles
    assert vfit.relocate_poles(s, H, w, poles0, False).tobytes() == _ref_relocate(s, H, w, poles0, False).tobytes()
    pr, prd = vfit.vector_fit_both(s, H, w, order, n_iter=8, poles0=poles0, tol=1e-7)
    ref = _ref_vector_fit(s, H, w, order, 8, False, poles0, 1e-7)
    assert _same(pr, ref) and _same(prd, _ref_fit_residues(s, H, w, ref.poles, True))
    assert _same(vfit.fit_residues(s, H, w, poles0, True), _ref_fit_residues(s, H, w, poles0, True))
