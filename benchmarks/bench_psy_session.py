"""Psychophysics sessions on the sim device: JND recovered vs the simulated participant, SIGKILL/resume.

1. **JND recovery.** Simulated subjects run a stiffness-discrimination session (method of constant stimuli,
   7 comparison stiffnesses from 400 to 1225 N/m around a 700 N/m reference, ``TRIALS_PER_LEVEL`` trials
   each) on the sim device;
   their answers come from what the device rendered (:mod:`study.forcedchoice.perception`: force and penetration of their
   own taps with the force and compliance JNDs). A cumulative normal is fitted by maximum likelihood to
   P("comparison harder") against log10 stiffness (``psychophysics.fit``, lapse fixed at 0 and free);
   its JND = x(F = 0.75) - x(F = 0.5) gives the Weber fraction, printed against the participant's
   (16.8 % from 7 % force and 15 % compliance JNDs).
2. **SIGKILL at every trial.** A warm process forks a session killed by SIGKILL at a durable step
   (:func:`study.session.store.crash_point`) and a ``--resume`` to the end; the finished trials.csv must equal an
   uninterrupted run's trial by trial (the :mod:`benchmarks.bench_study_kill` harness' forking).
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from psychophysics import fitting as psychometric
from study.__main__ import main as study_main
from study.session.participants import SimParticipantConfig
from study.forcedchoice.perception import stiffness_weber_fraction

from tests.support.kills import (QUICK, REAL_VIRTUAL, ForcedChoiceKillHarness, read_rows, session_args,
                                 state_lines)

DISCRIMINATION = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
vary = "stiffness_N_m"
reference = 700.0
levels = {levels}
trials_per_level = {n}
intensity_scale = "log10"
"""
DETECTION_CONSTANT = QUICK + """
[experiment]
kind = "detection"
sample = "pulse_firm"
levels = [0.15, 0.3, 0.6, 1.2, 2.4, 4.8, 9.6]
trials_per_level = {n}
intensity_scale = "log10"
"""
DETECTION_QUEST = QUICK + """
[experiment]
kind = "detection"
sample = "pulse_firm"
method = "quest+"
intensity_scale = "log10"

[experiment.staircases.Q]
intensities = {{min = 0.1, max = 10.0, n = 31, spacing = "log10"}}
thresholds = {{min = 0.1, max = 10.0, n = 31, spacing = "log10"}}
slopes = [1.0, 2.0, 3.5, 6.0]
lapses = [0.0, 0.02, 0.05]
guess = 0.5
function = "weibull"
max_trials = {n}
"""
LEVELS = [400.0, 500.0, 600.0, 700.0, 820.0, 980.0, 1225.0]   # to 0.57 and 1.75 x: the lapses show
TRIALS_PER_LEVEL = 60
def fit_probit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Maximum-likelihood cumulative normal ``P = Phi(beta (x - alpha))`` (guess and lapse 0), by
    ``analysis psychometric``'s fit (which equals statsmodels' probit GLM, tests/analysis/test_psychometric.py).

    Returns
    -------
    (alpha, beta)
        PSE (F = 0.5) and slope, in the units of ``x``.
    """
    f = psychometric.fit(x, y, alternatives=1, function="normal", lapse=0.0, bootstrap=0)
    return f.threshold, f.slope


def fit_probit_lapse(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """The same with the lapse rate fitted in [0, 0.1] (``analysis psychometric --lapse free``: the lapse lowers
    the upper asymptote only; the simulated participant's coin-flip lapse also lifts the lower one by lapse/2).

    Returns
    -------
    (alpha, beta, lapse)
    """
    f = psychometric.fit(x, y, alternatives=1, function="normal", bootstrap=0)
    return f.threshold, f.slope, f.lapse


def weber_from_log10_fit(alpha: float, beta: float) -> tuple[float, float]:
    """PSE (physical) and Weber fraction from a probit fit on log10 intensity (JND = x75 - x50, eq. of the
    contract; Weber fraction = JND / PSE)."""
    x50 = 10 ** alpha
    x75 = 10 ** (alpha + 0.6744897501960817 / beta)
    return x50, (x75 - x50) / x50


def jnd_recovery(work: Path, subjects: int = 4, n: int = TRIALS_PER_LEVEL) -> list[dict]:
    """Run ``subjects`` discrimination sessions and fit each; returns per subject PSE, Weber fraction, time."""
    proto = work / "discrimination.toml"
    proto.write_text(DISCRIMINATION.format(levels=LEVELS, n=n))
    out = []
    for k in range(subjects):
        subject = f"J{k + 1}"
        t0 = time.perf_counter()
        code = study_main(session_args(proto, work / "DATA", subject, 100 + k))
        wall = time.perf_counter() - t0
        if code != 0:
            raise RuntimeError(f"session {subject} exited {code}")
        rows = read_rows(work / "DATA" / subject)
        x = np.array([float(r["intensity"]) for r in rows])
        y = np.array([int(r["correct"]) for r in rows])
        alpha, beta = fit_probit(x, y)
        pse, weber = weber_from_log10_fit(alpha, beta)
        a2, b2, lapse = fit_probit_lapse(x, y)
        pse2, weber2 = weber_from_log10_fit(a2, b2)
        out.append({"subject": subject, "trials": len(rows), "pse_N_m": pse, "weber": weber, "wall_s": wall,
                    "pse_lapse_N_m": pse2, "weber_lapse": weber2, "lapse": lapse})
    return out


def fit_2afc_threshold(x: np.ndarray, y: np.ndarray) -> float:
    """Maximum likelihood of ``P = 0.5 + (0.5 - lapse) Phi(beta (x - alpha))`` (2AFC, lapse in [0, 0.1]) on
    ``x`` = log10 intensity, by ``analysis psychometric``'s fit; returns the threshold ``10**alpha`` (F = 0.5)."""
    return float(10 ** psychometric.fit(x, y, alternatives=2, function="normal", bootstrap=0).threshold)


def detection_and_real_virtual(work: Path, n_constant: int = 40, n_quest: int = 80, n_rv: int = 20) -> dict:
    """A simulated subject's transient-detection threshold by constant stimuli (7 levels) and by QUEST+
    (``n_quest`` trials), and proportion correct per rendering in a real-vs-virtual session."""
    out = {}
    for name, text, n in (("constant", DETECTION_CONSTANT, n_constant), ("quest", DETECTION_QUEST, n_quest),
                          ("rv", REAL_VIRTUAL.replace('["firm", "sinusoid_firm"]',
                                                      '["firm", "pulse_firm", "sinusoid_firm", "hfam_firm"]'), n_rv)):
        proto = work / f"{name}.toml"
        proto.write_text(text.format(n=n))
        t0 = time.perf_counter()
        if study_main(session_args(proto, work / "DATA2", name, 7)) != 0:
            raise RuntimeError(f"session {name} failed")
        out[f"{name}_s"] = time.perf_counter() - t0
        rows = read_rows(work / "DATA2" / name)
        if name == "constant":
            x = np.array([float(r["intensity"]) for r in rows])
            out["constant"] = fit_2afc_threshold(x, np.array([int(r["correct"]) for r in rows]))
        elif name == "quest":
            last = state_lines(work / "DATA2" / name)[-1]["estimate"]
            out["quest"], out["quest_ci"] = last["threshold"], last["threshold_ci"]
        else:
            out["rv"] = {c: (float(np.mean([int(r["correct"]) for r in rows if r["condition"] == c])),
                             sum(r["condition"] == c for r in rows)) for c in sorted({r["condition"] for r in rows})}
    return out


def main(subjects: int = 4) -> None:
    """Print the JND recovery per simulated subject and the kill/resume cases' outcome."""
    cfg = SimParticipantConfig()
    true_w = stiffness_weber_fraction(cfg.jnd_force_frac, cfg.jnd_compliance_frac)
    with tempfile.TemporaryDirectory() as tmp:
        res = jnd_recovery(Path(tmp), subjects)
        per_trial = np.median([r["wall_s"] / r["trials"] for r in res])
        print(f"   stiffness discrimination, 7 levels x {TRIALS_PER_LEVEL} trials, reference 700 N/m; participant: "
              f"force JND {cfg.jnd_force_frac:.0%}, compliance JND {cfg.jnd_compliance_frac:.0%}, lapse "
              f"{cfg.lapse:.0%} -> Weber fraction {true_w:.3f}")
        for r in res:
            print(f"   {r['subject']}: {r['trials']} trials; lapse 0: PSE {r['pse_N_m']:.0f} N/m, Weber fraction "
                  f"{r['weber']:.3f} ({(r['weber'] / true_w - 1):+.0%}); lapse free: PSE {r['pse_lapse_N_m']:.0f} "
                  f"N/m, Weber {r['weber_lapse']:.3f} ({(r['weber_lapse'] / true_w - 1):+.0%}), lapse "
                  f"{r['lapse']:.3f}")
        ws = np.array([r["weber"] for r in res])
        wl = np.array([r["weber_lapse"] for r in res])
        print(f"   median Weber fraction {np.median(ws):.3f} (lapse 0), {np.median(wl):.3f} (lapse free) vs "
              f"{true_w:.3f}; median {per_trial * 1e3:.0f} ms per trial (wall)")
        d = detection_and_real_virtual(Path(tmp))
        print(f"   detection of pulse_firm's pulse (N*s/m): constant stimuli 7 x 40 -> threshold "
              f"{d['constant']:.3f} ({d['constant_s']:.0f} s); QUEST+ 80 trials -> {d['quest']:.3f}, 95 % CI "
              f"[{d['quest_ci'][0]:.3f}, {d['quest_ci'][1]:.3f}] ({d['quest_s']:.0f} s); ratio "
              f"{d['quest'] / d['constant']:.2f}")
        print("   real vs virtual (wood_on_foam), proportion correct per rendering: " +
              ", ".join(f"{c} {p:.2f} (n {n})" for c, (p, n) in d["rv"].items()))
        harness = ForcedChoiceKillHarness(Path(tmp), REAL_VIRTUAL.format(n=2))
        rows = [harness.step_of(f"row written: trial {k}/1") for k in range(1, len(harness.reference) + 1)
                if any(s.endswith(f"row written: trial {k}/1") for s in harness.steps)]
        picks = sorted(set(rows + [2, len(harness.steps)] + [r - 1 for r in rows]))
        results = [harness.case(s, i) for i, s in enumerate(picks)]
        bad = [r for r in results if "error" in r]
        print(f"   real-virtual 2AFC, {len(harness.reference)} trials, {len(harness.steps)} durable steps: "
              f"{len(results)} SIGKILL/resume cases, {len(bad)} differing from the uninterrupted run")
        for r in bad[:5]:
            print(f"     step {r['step']} ({r['where']}): {r['error']}")
        if bad or not all(math.isfinite(w) for w in ws):
            raise AssertionError("psychophysics session benchmark failed")


if __name__ == "__main__":
    main()
