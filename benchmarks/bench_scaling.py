"""Method of adjustment and magnitude estimation on the sim device: PSE and Stevens exponent recovered over
simulated participants, with the coverage of their 95 % intervals.

Each simulated participant runs two sessions through ``python -m study run`` (in this process, sim device,
0.6 s windows):

* **method of adjustment**: the comparison's stiffness matched to a 700 N/m reference, ``TRIALS`` trials (half
  starting 20-60 % above, half below); the participant over-adjusts by ``BIAS`` (its true PSE is
  700 * (1 + BIAS) N/m) and perceives stiffness with the default force and compliance JNDs (a Weber fraction
  of 16.8 %);
* **magnitude estimation**: six stiffnesses 250-2500 N/m, five times each, free modulus; the participant's
  exponent is ``EXPONENT``.

``python -m analysis adjustment`` / ``magnitude``'s functions estimate each participant's PSE and exponent with
their 95 % t intervals; printed: the pooled estimates against the truth, each participant's error, and the
fraction of intervals covering the truth. ``SCALING_PARTICIPANTS`` (environment) sets the number (100).
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis import adjustment, magnitude
from study.__main__ import main as study_main
from study.forcedchoice.perception import stiffness_weber_fraction
from study.session.participants import SimParticipantConfig

QUICK = """tap_window_s = 0.6
homing_after_s = 0.3
homing_before_max_s = 0.1
"""
TRIALS, BIAS, EXPONENT, REFERENCE = 8, 0.10, 0.8, 700.0
ADJUST = QUICK + f"""
[experiment]
kind = "adjustment"
sample = "firm"
references = [{REFERENCE}]
trials_per_reference = {TRIALS}
"""
MAGNITUDE = QUICK + """
[experiment]
kind = "magnitude"
samples = ["firm"]
levels = [250.0, 400.0, 630.0, 1000.0, 1600.0, 2500.0]
repetitions = 5
"""
PARTICIPANT = f"adjust_bias_frac = {BIAS}\nstevens_exponent = {EXPONENT}\n"


def run_sessions(work: Path, n: int) -> tuple[float, float]:
    """Run ``n`` participants' two sessions; returns the wall times (s)."""
    (work / "adjust.toml").write_text(ADJUST)
    (work / "magnitude.toml").write_text(MAGNITUDE)
    (work / "participant.toml").write_text(PARTICIPANT)
    times = []
    for kind, data in (("adjust", "ADJ"), ("magnitude", "MAG")):
        t0 = time.perf_counter()
        for k in range(n):
            code = study_main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject",
                               f"P{k:03d}", "--seed", str(1000 + k), "--out", str(work / data), "--protocol",
                               str(work / f"{kind}.toml"), "--participant-config", str(work / "participant.toml")])
            if code != 0:
                raise RuntimeError(f"{kind} session P{k:03d} exited {code}")
        times.append(time.perf_counter() - t0)
    return times[0], times[1]


def main() -> None:
    n = int(os.environ.get("SCALING_PARTICIPANTS", "100"))
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        t_adj, t_mag = run_sessions(work, n)
        adj = adjustment.analyse(work / "ADJ")
        mag = magnitude.analyse(work / "MAG")
    truth_pse = REFERENCE * (1 + BIAS)
    s = adj["subjects"]
    err = s["pse"] / truth_pse - 1
    cover = ((s["pse_low"] <= truth_pse) & (truth_pse <= s["pse_high"])).mean()
    p = adj["pooled"].iloc[0]
    w = stiffness_weber_fraction(SimParticipantConfig().jnd_force_frac, SimParticipantConfig().jnd_compliance_frac)
    print(f"   method of adjustment, {n} participants x {TRIALS} trials ({t_adj / n:.1f} s of wall time each): true "
          f"PSE {truth_pse:.1f} N/m")
    print(f"     pooled PSE {p['pse']:.1f} N/m [{p['pse_low']:.1f}, {p['pse_high']:.1f}] ({100 * (p['pse'] / truth_pse - 1):+.2f} %); "
          f"per participant |error| median {100 * err.abs().median():.1f} %, 90th percentile "
          f"{100 * err.abs().quantile(0.9):.1f} %, within 5 %: {100 * (err.abs() < 0.05).mean():.0f} %")
    print(f"     95 % intervals covering the true PSE: {100 * cover:.0f} % of participants; Weber fraction from the "
          f"spread {s['weber'].mean():.3f} (median {s['weber'].median():.3f}) against the participant's 2AFC {w:.3f}; "
          f"unmatched trials {int(s['unmatched'].sum())}")
    m = mag["subjects"]
    e = m["exponent"] - EXPONENT
    cov = ((m["exponent_low"] <= EXPONENT) & (EXPONENT <= m["exponent_high"])).mean()
    q = mag["pooled"].iloc[0]
    print(f"   magnitude estimation, {n} participants x 30 trials ({t_mag / n:.1f} s each): true exponent {EXPONENT}")
    print(f"     pooled exponent {q['exponent']:.4f} [{q['exponent_low']:.4f}, {q['exponent_high']:.4f}], group "
          f"curve {q['curve_exponent']:.4f}; per participant |error| median {e.abs().median():.3f}, 90th "
          f"percentile {e.abs().quantile(0.9):.3f}, within 0.05: {100 * (e.abs() < 0.05).mean():.0f} %")
    print(f"     95 % intervals covering the true exponent: {100 * cov:.0f} % of participants")
