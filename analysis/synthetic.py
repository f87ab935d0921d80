"""Synthetic study folders in exactly the study's format (for tests, benchmarks and demos).

Ratings are drawn from a fixed per-sample realism profile loosely shaped like
Figure 4.17 plus a per-subject bias and per-attempt noise (novices noisier).
This exercises the analysis pipeline; it is not a model of human perception.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import norm

import figstyle
from analysis.load import TRIAL_COLUMNS


@dataclass(frozen=True)
class SyntheticSample:
    """One catalog entry of the generator: true mean rating (1-7) and mean penetration (m)."""

    name: str
    kind: str
    mean_rating: float
    penetration_m: float
    ring_hz: float        # dominant contact-transient frequency in the synthetic traces
    ring_gain: float      # transient acceleration per unit incoming velocity, (m/s^2)/(m/s)


DEFAULT_SAMPLES = (
    SyntheticSample("wood", "real", 6.1, 0.10e-3, 300.0, 900.0),
    SyntheticSample("wood_on_foam", "real", 4.9, 0.22e-3, 120.0, 500.0),
    SyntheticSample("foam", "real", 2.3, 2.2e-3, 15.0, 40.0),
    SyntheticSample("very_firm", "virtual", 2.6, 0.6e-3, 25.0, 60.0),
    SyntheticSample("firm", "virtual", 2.4, 0.9e-3, 20.0, 50.0),
    SyntheticSample("soft", "virtual", 2.2, 2.1e-3, 14.0, 40.0),
    SyntheticSample("pulse_firm", "virtual", 4.3, 0.5e-3, 50.0, 300.0),
    SyntheticSample("pulse_soft", "virtual", 4.2, 1.0e-3, 50.0, 300.0),
    SyntheticSample("sinusoid_firm", "virtual", 4.7, 0.45e-3, 55.0, 420.0),
    SyntheticSample("sinusoid_soft", "virtual", 4.6, 0.9e-3, 55.0, 420.0),
    SyntheticSample("hfam_firm", "virtual", 4.9, 0.45e-3, 110.0, 480.0),
    SyntheticSample("hfam_soft", "virtual", 4.8, 0.9e-3, 110.0, 480.0),
)


def _fmt(x: float) -> str:
    return repr(float(x))


def _taps(rng: np.random.Generator, sample: SyntheticSample, grip: float) -> tuple[np.ndarray, np.ndarray]:
    n = int(rng.integers(3, 9))
    v = np.clip(rng.normal(0.10, 0.04, n), 0.02, None)
    pen = sample.penetration_m * (v / 0.10) * grip * np.exp(rng.normal(0.0, 0.15, n))
    return v, pen


def synthetic_trace(sample: SyntheticSample, v_in_m_s: float, fs_hz: float = 10000.0, duration_s: float = 0.16,
                    rng: np.random.Generator | None = None) -> dict:
    """A single-tap trace: approach at ``v_in``, impact at 0.05 s, decaying contact ringing.

    Returns the arrays of a study trace file: ``t_s, position_m, force_prop_N, accel_m_s2`` (n,),
    ``event_t_s, event_incoming_velocity_m_s`` (1,), ``fs_hz`` and ``sample``.
    """
    rng = rng or np.random.default_rng(0)
    t = np.arange(int(duration_s * fs_hz)) / fs_hz
    t_imp = 0.05
    tau = t - t_imp
    after = tau >= 0
    pos = np.where(after, -sample.penetration_m * (v_in_m_s / 0.1) * (1 - np.exp(-tau.clip(0) * 60.0)),
                   -v_in_m_s * tau)
    decay = 2.5 / max(sample.ring_hz, 1.0) + 0.004  # s: a few cycles, like real contact ringing
    acc = np.where(after, sample.ring_gain * v_in_m_s * np.exp(-tau.clip(0) / decay)
                   * np.sin(2 * np.pi * sample.ring_hz * tau.clip(0)), 0.0)
    acc = acc + rng.normal(0.0, 0.2, t.size)
    force = np.where(after, -pos * 300.0, 0.0)
    # keys and dtypes as the study runner writes them (docs/study.md)
    return {"t_s": t, "position_m": pos.astype(np.float32), "force_prop_N": force.astype(np.float32),
            "accel_m_s2": acc.astype(np.float32), "event_t_s": np.array([t_imp]),
            "event_incoming_velocity_m_s": np.array([v_in_m_s]), "fs_hz": np.float64(fs_hz),
            "sample": np.array(sample.name)}


#: the generator's subject bias SD and per-attempt noise SDs (novices noisier), rating points
SUBJECT_BIAS_SD = 0.4
NOISE_SD = {"none": 1.2, "few": 0.5, "regular": 0.5}
EXPERIENCE_CYCLE = ("none",) * 7 + ("few",) * 7 + ("regular",) * 2


def expected_ratings(n_subjects: int, samples=DEFAULT_SAMPLES, effect_scale: float = 1.0, experience=None) -> dict:
    """The generator's true mean rating per sample, on the 1-7 scale it writes (the models' target).

    A rating is ``clip(rint(mu + b + e), 1, 7)`` with ``b ~ N(0, 0.4^2)`` per subject and
    ``e ~ N(0, s^2)`` per attempt (s by experience), so its expectation is not ``mu``: with
    ``x ~ N(mu, 0.4^2 + s^2)``, ``E = 1 + sum_(c=1.5..6.5) P(x > c)`` (exact; rint's ties have
    probability 0). Averaged over the subjects' experience as :func:`write_synthetic_study` assigns it
    (with ``velocity_effect`` 0).

    Returns
    -------
    dict
        ``{sample: expected rating}``.
    """
    means = np.array([s.mean_rating for s in samples])
    means = means.mean() + effect_scale * (means - means.mean())
    exp = [experience[k] if experience is not None else EXPERIENCE_CYCLE[k % len(EXPERIENCE_CYCLE)]
           for k in range(n_subjects)]
    cuts = np.arange(1.5, 7.0, 1.0)
    total = np.zeros(means.size)
    for e in exp:
        sd = np.hypot(SUBJECT_BIAS_SD, NOISE_SD[e])
        total += 1.0 + norm.sf((cuts[None, :] - means[:, None]) / sd).sum(axis=1)
    return {s.name: float(v) for s, v in zip(samples, total / len(exp))}


def write_synthetic_study(out_dir, n_subjects: int = 16, *, samples=DEFAULT_SAMPLES, repetitions: int = 3,
                          seed: int = 0, experience=None, p_invalid: float = 0.1, missing=None,
                          unfinished=(), traces: bool | int = False, fs_hz: float = 10000.0,
                          effect_scale: float = 1.0, velocity_effect: float = 0.0) -> list[Path]:
    """Write ``n_subjects`` subject folders (``session.json`` + ``trials.csv``) into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Created if missing; subject folders ``S001``, ``S002``, ... are written inside.
    n_subjects : int
    samples : sequence of SyntheticSample
        Catalog in order.
    repetitions : int
        Valid testing attempts per sample (redraws for invalid attempts are added on top).
    seed : int
    experience : sequence of str or None
        Experience code per subject (``none|few|regular``); default cycles 7:7:2 as in section 4.5.4.
    p_invalid : float
        Probability that an attempt is saturated, rejected or overpowered (and redrawn).
    missing : dict or None
        ``{subject_id: [sample, ...]}``: those samples get no testing attempt for that subject.
    unfinished : sequence of str
        Subject ids written with ``finished_at`` null.
    traces : bool or int
        Also write ``traces/<phase>_t<trial:03d>_a<attempt:02d>.npz`` for testing attempts (an int:
        only for that many first subjects).
    effect_scale : float
        Multiplies the deviation of each sample's true mean from the grand mean (0: no effect).
    velocity_effect : float
        Rating points per m/s of the attempt's mean incoming velocity above 0.10 m/s, added before
        rounding (0: ratings do not depend on velocity; draws no random numbers, so the default keeps
        every earlier data set identical).

    Returns
    -------
    list of Path
        The subject folders.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    missing = missing or {}
    means = np.array([s.mean_rating for s in samples])
    means = means.mean() + effect_scale * (means - means.mean())
    cycle = EXPERIENCE_CYCLE
    folders = []
    for k in range(n_subjects):
        subject = f"S{k + 1:03d}"
        exp = experience[k] if experience is not None else cycle[k % len(cycle)]
        bias = rng.normal(0.0, SUBJECT_BIAS_SD)
        noise = NOISE_SD.get(exp, 0.5)
        grip = float(rng.uniform(0.7, 1.3))
        folder = out / subject
        (folder / "traces").mkdir(parents=True, exist_ok=True)
        session = {
            "subject": subject, "age": int(rng.integers(19, 34)), "gender": ["female", "male"][k % 2],
            "handedness": "right", "experience": exp, "seed": int(seed * 100003 + k),
            # the project palette's labels, as the study's catalog gives its samples (the report draws these)
            "catalog": [{"name": s.name, "label": figstyle.sample_style(s.name)["label"], "kind": s.kind}
                        for s in samples], "repetitions": repetitions,
            "device": "synthetic", "software_version": "synthetic", "started_at": "2026-01-01T00:00:00Z",
            "finished_at": None if subject in unfinished else "2026-01-01T00:10:00Z",
        }
        (folder / "session.json").write_text(json.dumps(session, indent=2) + "\n")
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(TRIAL_COLUMNS)

        def row(phase, trial, attempt, j, rating, rejected, saturated, overpowered, v, pen):
            valid = not (rejected or saturated or overpowered)
            w.writerow([subject, phase, trial, attempt, samples[j].name, samples[j].kind,
                        "" if rating is None else str(rating), *("true" if b else "false" for b in
                                                                 (rejected, saturated, overpowered, valid)),
                        len(v), _fmt(v.mean()) if len(v) else "", _fmt(pen.mean()) if len(pen) else "",
                        ";".join(_fmt(x) for x in v), ";".join(_fmt(x) for x in pen),
                        "2026-01-01T00:00:00Z", "5.0"])

        wood = next((j for j, s in enumerate(samples) if s.name == "wood"), 0)
        v, pen = _taps(rng, samples[wood], grip)
        row("familiarization", 1, 1, wood, None, False, False, False, v, pen)
        for phase, reps in (("demonstration", 1), ("testing", repetitions)):
            order = rng.permutation(np.repeat(np.arange(len(samples)), reps))
            if phase == "testing":
                skip = set(missing.get(subject, ()))
                order = [j for j in order if samples[j].name not in skip]
            for trial, j in enumerate(order, start=1):
                attempt = 1
                while True:
                    v, pen = _taps(rng, samples[j], grip)
                    invalid = rng.random() < p_invalid
                    kind = int(rng.integers(3)) if invalid else -1
                    rejected, saturated, overpowered = kind == 0, kind == 1, kind == 2
                    rating = None if rejected else int(np.clip(np.rint(
                        means[j] + bias + velocity_effect * (v.mean() - 0.10) + rng.normal(0.0, noise)), 1, 7))
                    row(phase, trial, attempt, j, rating, rejected, saturated, overpowered, v, pen)
                    if phase == "testing" and (traces is True or (traces is not False and k < int(traces))):
                        tr = synthetic_trace(samples[j], float(v[0]), fs_hz=fs_hz, rng=rng)
                        np.savez(folder / "traces" / f"{phase}_t{trial:03d}_a{attempt:02d}.npz", **tr)
                    if not invalid:
                        break
                    attempt += 1
        (folder / "trials.csv").write_text(buf.getvalue())
        folders.append(folder)
    return folders
