"""What the study's store writes, the analysis reads and analyses: both sides of plumbing.studyfiles, end to end.

The test imports the study's own writer (the analysis package itself never imports study).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from analysis.pipeline import analyse
from analysis.report import write_report
from analysis.stats import valid_testing
from analysis.synthetic import DEFAULT_SAMPLES
from analysis.traces import typical_taps
import study.session.store as study_data


def _trace(v_in: float, fs_hz: float = 10000.0) -> dict:
    """Arrays shaped like study.session.apparatus.TapResult.trace: one tap at 0.2 s with ringing after it."""
    t = np.arange(int(0.5 * fs_hz)) / fs_hz
    tau = np.clip(t - 0.2, 0.0, None)
    acc = np.where(t >= 0.2, 400.0 * v_in * np.exp(-tau / 0.01) * np.sin(2 * np.pi * 120.0 * tau), 0.0)
    pos = np.where(t >= 0.2, -1e-4, 0.02 - v_in * t)
    out = {"t_s": t}
    for name, arr in (("position_m", pos), ("force_prop_N", -pos * 680), ("force_transient_N", 0 * t),
                      ("current_A", 0 * t), ("accel_m_s2", acc), ("grip_N", 0 * t + 2)):
        out[name] = np.asarray(arr, np.float32)
    out.update(clipped=np.zeros(t.size, np.uint8), event_t_s=np.array([0.2]),
               event_incoming_velocity_m_s=np.array([v_in]), event_max_penetration_m=np.array([1e-4]),
               event_clipped=np.array([False]), fs_hz=np.float64(fs_hz), window_start_s=np.float64(0.1),
               max_contact_force_N=np.float64(1.0), sample=np.array("x"))
    return out


def test_files_written_by_the_study_store_are_analysed(tmp_path):
    rng = np.random.default_rng(2)
    names = [s.name for s in DEFAULT_SAMPLES]
    for k in range(4):
        subject = f"P{k}"
        store = study_data.SessionStore(tmp_path, subject)
        store.check()
        store.create({"subject": subject, "age": 30, "gender": "unspecified", "handedness": "right",
                      "experience": ["none", "few", "regular", "few"][k], "seed": k, "repetitions": 2,
                      "catalog": [{"name": s.name, "kind": s.kind} for s in DEFAULT_SAMPLES],
                      "device": {"spec": "sim"}, "software_version": {"hfam-haptics": "test"},
                      "started_at": study_data.utc_now(), "finished_at": None})
        trial = 0
        for rep in range(2):
            for j in rng.permutation(len(names)):
                trial += 1
                v = list(rng.uniform(0.06, 0.14, 3))
                pen = [1e-4 * (j + 1)] * 3
                store.write_trace("testing", trial, 1, _trace(v[0]))
                store.append_trial({
                    "subject": subject, "phase": "testing", "trial": trial, "attempt": 1, "sample": names[j],
                    "kind": DEFAULT_SAMPLES[j].kind, "rating": int(np.clip(round(DEFAULT_SAMPLES[j].mean_rating
                                                                            + rng.normal(0, 0.5)), 1, 7)),
                    "rejected": False, "saturated": False, "overpowered": False, "valid": True, "n_taps": 3,
                    "incoming_velocity_mean_m_s": float(np.mean(v)), "penetration_mean_m": float(np.mean(pen)),
                    "incoming_velocities_m_s": v, "penetration_depths_m": pen, "started_at": study_data.utc_now(),
                    "duration_s": 5.0})
        store.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = analyse(tmp_path)
    assert len(valid_testing(res.study)) == 4 * 2 * 12
    assert list(res.study.catalog) == names
    np.testing.assert_allclose(res.summary["penetration_mean_m"], 1e-4 * np.arange(1, 13), rtol=1e-9)
    assert res.warnings == ()
    dirs = dict(zip(res.study.subjects["subject"], res.study.subjects["folder"]))
    taps, v, notes = typical_taps(valid_testing(res.study), {s: Path(d) for s, d in dirs.items()}, names, 0.1)
    assert set(taps) == set(names) and notes == []
    assert all(abs(tap.v_in_m_s - 0.1) < 0.02 for tap in taps.values())
    out = write_report(res, tmp_path / "report")
    assert [p.name for p in out["figures"]][-1] == "fig_4_20_accelerations.png"
    # the models fit the study's own files; every attempt enters, velocity as the covariate
    assert res.models.mixed["fitted"] and res.models.ordinal["fitted"], res.models.notes
    assert res.models.mixed["n_attempts"] == 96 and res.models.mixed["covariates"] == ["velocity_m_s"]
    emm = res.models.emm.set_index("sample")["emm"]
    assert emm["wood"] > emm["foam"] + 2          # profile 6.1 vs 2.3, noise SD 0.5
    md = out["md"].read_text()
    assert "## Models" in md and "## Evidence for no difference" in md
