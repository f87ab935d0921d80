"""Method of adjustment and magnitude estimation on the sim device: PSE and Stevens exponent recovered per
simulated participant and pooled, the coverage of their 95 % intervals, and the trials a participant needs.

Each simulated participant runs two sessions through ``python -m study run`` (in a worker process, sim device,
0.6 s windows):

* **method of adjustment**: the comparison's stiffness matched to a 700 N/m reference (half the trials starting
  20-60 % above, half below); the participant over-adjusts by ``BIAS`` (its true PSE is 700 * (1 + BIAS) N/m)
  and perceives stiffness with the default force and compliance JNDs (a Weber fraction W of 16.8 %);
* **magnitude estimation**: six stiffnesses 250-2500 N/m, free modulus; the participant's exponent is
  ``EXPONENT``, its numbers carry its Weber noise and a response noise of 10 % (log-SD).

**Trials per participant.** A participant's PSE is the geometric mean of n settings whose log-SD is s, so its
error is normal on the log scale with SD s / sqrt(n): the fraction of participants within +-5 % is
``Phi(ln(1.05) sqrt(n) / s) - Phi(ln(0.95) sqrt(n) / s)`` (:func:`fraction_within`), and
:func:`trials_needed` is the smallest n that puts 95 % of them there. The settings' SD is taken from the Weber
fraction, the SD of a match being about W times the PSE (s = W on the log scale), which gives 44 trials at W =
0.168 (8 trials: 60 %). The exponent is an OLS slope: its SD is ``r / sqrt(R * sum (ln phi - mean ln phi)^2)``
with r the residual log-SD of the numbers (the percept's noise times the exponent, ``beta ln(1 + W) /
(0.6745 sqrt 2)``, and the response noise in quadrature) and R repetitions of the levels
(:func:`repetitions_needed`: 12, i.e. 72 trials, for 95 % within 0.05). The sessions run with those counts
(``--adjust-trials`` and ``--repetitions`` set others); printed beside: what the spread measured in the
sessions predicts.

``python -m analysis adjustment`` / ``magnitude``'s functions estimate each participant's PSE and exponent
with their 95 % t intervals. Printed: the pooled estimates against the truth, the participants' errors and the
fraction within 5 % (0.05), and the fraction of intervals covering the truth with its exact (Clopper-Pearson)
95 % interval. Runs as ``python -m benchmarks scaling [--participants N] [--workers W]``
(``SCALING_PARTICIPANTS`` in the environment also sets N; default 100, 2 workers); it takes about 20 minutes on
two cores (measured: 1000 s for the adjustment sessions, 110 s for magnitude), so ``make bench`` runs it only
when named.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

from analysis import adjustment, magnitude
from analysis.scaling_design import (TOLERANCE_EXPONENT, TOLERANCE_PSE, WITHIN, exponent_fraction_within,
                                     fraction_within, magnitude_residual_sd, repetitions_needed, trials_needed)
from study.__main__ import main as study_main
from study.forcedchoice.perception import stiffness_weber_fraction
from study.session.participants import SimParticipantConfig

RUN_BY_DEFAULT = False

BIAS, EXPONENT, REFERENCE = 0.10, 0.8, 700.0
LEVELS = (250.0, 400.0, 630.0, 1000.0, 1600.0, 2500.0)
QUICK = """tap_window_s = 0.6
homing_after_s = 0.3
homing_before_max_s = 0.1
"""
PARTICIPANT = f"adjust_bias_frac = {BIAS}\nstevens_exponent = {EXPONENT}\n"


def participant_design() -> dict:
    """The simulated participant's Weber fraction and the trial counts the module docstring derives."""
    cfg = SimParticipantConfig()
    w = stiffness_weber_fraction(cfg.jnd_force_frac, cfg.jnd_compliance_frac)
    residual = magnitude_residual_sd(w, EXPONENT, cfg.magnitude_noise_frac)
    return {"weber": w, "adjust_trials": trials_needed(w), "residual_sd": residual,
            "repetitions": repetitions_needed(residual, LEVELS)}


def protocols(adjust_trials: int, repetitions: int) -> tuple[str, str]:
    """The two sessions' protocol files."""
    adjust = QUICK + f"""
[experiment]
kind = "adjustment"
sample = "firm"
references = [{REFERENCE}]
trials_per_reference = {adjust_trials}
"""
    mag = QUICK + f"""
[experiment]
kind = "magnitude"
samples = ["firm"]
levels = {list(LEVELS)}
repetitions = {repetitions}
"""
    return adjust, mag


def run_one(job: tuple) -> tuple[str, float]:
    """One participant's session (a worker's job): ``(kind, work folder, participant number)``; returns the kind
    and the wall time (s)."""
    kind, work, k = job
    t0 = time.perf_counter()
    code = study_main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", f"P{k:03d}",
                       "--seed", str(1000 + k), "--out", str(Path(work) / kind.upper()[:3]), "--protocol",
                       str(Path(work) / f"{kind}.toml"), "--participant-config", str(Path(work) / "participant.toml")])
    if code != 0:
        raise RuntimeError(f"{kind} session P{k:03d} exited {code}")
    return kind, time.perf_counter() - t0


def run_sessions(work: Path, n: int, design: dict, workers: int) -> dict:
    """Run ``n`` participants' two sessions on ``workers`` processes; returns per kind the summed session time
    and the wall time (s)."""
    adjust, mag = protocols(design["adjust_trials"], design["repetitions"])
    (work / "adjust.toml").write_text(adjust)
    (work / "magnitude.toml").write_text(mag)
    (work / "participant.toml").write_text(PARTICIPANT)
    times = {}
    for kind in ("adjust", "magnitude"):
        t0 = time.perf_counter()
        jobs = [(kind, str(work), k) for k in range(n)]
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            session_s = sum(s for _, s in pool.imap_unordered(run_one, jobs))
        times[kind] = (session_s, time.perf_counter() - t0)
    return times


def coverage(low, high, truth) -> tuple[float, float, float]:
    """The fraction of intervals holding ``truth`` with its Clopper-Pearson 95 % interval."""
    hit = ((np.asarray(low) <= truth) & (truth <= np.asarray(high)))
    ci = stats.binomtest(int(hit.sum()), len(hit)).proportion_ci(0.95)
    return float(hit.mean()), float(ci.low), float(ci.high)


def report(adj: dict, mag: dict, design: dict, n: int, times: dict, workers: int) -> list[str]:
    """The printed lines (module docstring)."""
    w, trials, reps = design["weber"], design["adjust_trials"], design["repetitions"]
    truth_pse = REFERENCE * (1 + BIAS)
    s = adj["subjects"]
    err = s["pse"] / truth_pse - 1
    within = float((err.abs() < TOLERANCE_PSE).mean())
    cov, clo, chi = coverage(s["pse_low"], s["pse_high"], truth_pse)
    p = adj["pooled"].iloc[0]
    t = adj["trials"]
    sd_log = float(np.sqrt(t[t["matched"] == 1].groupby("subject")["ln_ratio"].var(ddof=1).mean()))
    (adj_s, adj_wall), (mag_s, mag_wall) = times["adjust"], times["magnitude"]
    eight = f", 8 give {100 * fraction_within(w, 8):.0f} %" if trials != 8 else ""
    five = (f", 5 give {100 * exponent_fraction_within(design['residual_sd'], LEVELS, 5):.0f} %" if reps != 5
            else "")
    lines = [
        f"   method of adjustment, {n} participants x {trials} trials ({trials_needed(w)} for {100 * WITHIN:.0f} % "
        f"within {100 * TOLERANCE_PSE:.0f} % at a match SD of W = {w:.3f}, {trials} give "
        f"{100 * fraction_within(w, trials):.0f} %{eight}): true PSE "
        f"{truth_pse:.1f} N/m",
        f"     pooled PSE {p['pse']:.1f} N/m [{p['pse_low']:.1f}, {p['pse_high']:.1f}] "
        f"({100 * (p['pse'] / truth_pse - 1):+.2f} %)",
        f"     per participant: |error| median {100 * err.abs().median():.1f} %, 90th percentile "
        f"{100 * err.abs().quantile(0.9):.1f} %, within {100 * TOLERANCE_PSE:.0f} %: {100 * within:.0f} % (target "
        f">= 90 %); 95 % intervals covering the true PSE: {100 * cov:.0f} % [{100 * clo:.0f}, {100 * chi:.0f}] "
        f"(target 90-99 %)",
        f"     settings' log-SD {sd_log:.3f} (the participant's W {w:.3f}): it predicts "
        f"{100 * fraction_within(sd_log, trials):.0f} % within {100 * TOLERANCE_PSE:.0f} % with {trials} trials "
        f"and needs {trials_needed(sd_log)} for {100 * WITHIN:.0f} %; Weber fraction from the spread "
        f"{s['weber'].mean():.3f}; unmatched trials {int(s['unmatched'].sum())}",
    ]
    m = mag["subjects"]
    e = m["exponent"] - EXPONENT
    mwithin = float((e.abs() < TOLERANCE_EXPONENT).mean())
    mcov, mlo, mhi = coverage(m["exponent_low"], m["exponent_high"], EXPONENT)
    q = mag["pooled"].iloc[0]
    tr = mag["trials"]
    resid = []
    for _, g in tr.groupby("subject"):
        fit = stats.linregress(g["ln_level"], g["ln_number"])
        resid.append(np.var(g["ln_number"] - fit.intercept - fit.slope * g["ln_level"], ddof=2))
    rsd = float(np.sqrt(np.nanmean(resid)))
    lines += [
        f"   magnitude estimation, {n} participants x {len(LEVELS)} levels x {reps} ({len(LEVELS) * reps} trials; "
        f"{repetitions_needed(design['residual_sd'], LEVELS)} repetitions for {100 * WITHIN:.0f} % within "
        f"{TOLERANCE_EXPONENT} at a residual log-SD of {design['residual_sd']:.3f}, {reps} give "
        f"{100 * exponent_fraction_within(design['residual_sd'], LEVELS, reps):.0f} %{five}): true exponent "
        f"{EXPONENT}",
        f"     pooled exponent {q['exponent']:.4f} [{q['exponent_low']:.4f}, {q['exponent_high']:.4f}], group "
        f"curve {q['curve_exponent']:.4f}",
        f"     per participant: |error| median {e.abs().median():.3f}, 90th percentile {e.abs().quantile(0.9):.3f}, "
        f"within {TOLERANCE_EXPONENT}: {100 * mwithin:.0f} % (target >= 90 %); 95 % intervals covering the true "
        f"exponent: {100 * mcov:.0f} % [{100 * mlo:.0f}, {100 * mhi:.0f}] (target 90-99 %)",
        f"     residual log-SD of the numbers {rsd:.3f}: it predicts "
        f"{100 * exponent_fraction_within(rsd, LEVELS, reps):.0f} % within {TOLERANCE_EXPONENT} with {reps} "
        f"repetitions and needs {repetitions_needed(rsd, LEVELS)}",
        f"   wall time: adjustment {adj_wall:.0f} s ({adj_s / n:.1f} s per session, {adj_s / n / trials:.2f} s per "
        f"trial), magnitude {mag_wall:.0f} s ({mag_s / n:.1f} s per session), {workers} workers, load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores",
    ]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks scaling", description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=int(os.environ.get("SCALING_PARTICIPANTS", "100")),
                    help="simulated participants (default 100, or SCALING_PARTICIPANTS)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2: the machine is shared)")
    ap.add_argument("--adjust-trials", type=int, default=None,
                    help="adjustment trials per participant (default: trials_needed at the participant's W)")
    ap.add_argument("--repetitions", type=int, default=None,
                    help="magnitude repetitions of each level (default: repetitions_needed)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="a new folder to keep the sessions in (ADJ, MAG; default: a temporary one)")
    a = ap.parse_args([] if argv is None else argv)
    design = participant_design()
    design["adjust_trials"] = a.adjust_trials or design["adjust_trials"]
    design["repetitions"] = a.repetitions or design["repetitions"]
    if a.keep is not None and a.keep.exists():
        ap.error(f"--keep {a.keep} exists: give a new folder")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) if a.keep is None else a.keep
        work.mkdir(parents=True, exist_ok=True)
        times = run_sessions(work, a.participants, design, a.workers)
        adj = adjustment.analyse(work / "ADJ")
        mag = magnitude.analyse(work / "MAG")
    for line in report(adj, mag, design, a.participants, times, a.workers):
        print(line)
    return 0
