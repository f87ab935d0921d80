"""Psychophysics end to end (issue 34): a simulated stiffness-JND session and a real-vs-virtual 2AFC session on the
sim device, run by the study runner and read back by `analysis psychometric`, recover the simulated participant's
settings."""

import csv
import json
import math
import re
from pathlib import Path

import pytest
from statsmodels.stats.proportion import proportion_confint

from analysis.__main__ import main as analysis
from study.__main__ import main as study

ROOT = Path(__file__).resolve().parents[2]
#: the simulated participant's stiffness Weber fraction: force JND 7 % and compliance JND 15 % combined
#: (docs/study.md, "Psychophysics sessions")
WEBER_STIFFNESS = (0.07 ** 2 + 0.15 ** 2) ** 0.5


def _protocol(tmp: Path, example: str, trials_per_level: int) -> Path:
    text = (ROOT / "examples" / example).read_text()
    text = re.sub(r"^trials_per_level = \d+", f"trials_per_level = {trials_per_level}", text, flags=re.M)
    path = tmp / example
    path.write_text(text)
    return path


def _session(tmp: Path, protocol: Path, seed: int) -> Path:
    data = tmp / "DATA"
    assert study(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "S01",
                  "--seed", str(seed), "--out", str(data), "--protocol", str(protocol)]) == 0
    return data


def test_a_stiffness_jnd_session_fits_back_to_the_participants_pse_and_weber_fraction(tmp_path):
    data = _session(tmp_path, _protocol(tmp_path, "psy_discrimination.toml", 16), seed=3)
    out = tmp_path / "FITS"
    assert analysis(["psychometric", str(data), "--lapse", "0", "--bootstrap", "200", "--out", str(out)]) == 0
    fit = json.loads((out / "fit.json").read_text())
    reference = fit["experiment"]["reference"]
    assert fit["alternatives"] == 1 and fit["guess"] == 0.0       # "which was harder?": gamma = 0
    assert fit["intensity_scale"] == "log10" and fit["n_trials"] == 7 * 16
    # an unbiased participant: the PSE is the reference (within 10 %), inside its interval
    assert fit["pse_physical"] == pytest.approx(reference, rel=0.10)
    low, high = fit["threshold_ci_physical"]
    assert low < reference < high
    assert fit["weber_physical"] == pytest.approx(WEBER_STIFFNESS, rel=0.30)
    # with a free lapse, "which was harder?" lapses either way: one rate at both asymptotes (gamma = lambda)
    assert analysis(["psychometric", str(data), "--bootstrap", "0", "--no-figures", "--out", str(tmp_path / "F2")]) == 0
    free = json.loads((tmp_path / "F2" / "fit.json").read_text())
    assert free["equal_asymptote"] is True and free["guess"] == free["lapse"] and 0.0 <= free["lapse"] <= 0.1
    assert free["pse_physical"] == pytest.approx(reference, rel=0.10)


def test_a_real_virtual_session_gives_proportions_correct_against_chance(tmp_path):
    data = _session(tmp_path, _protocol(tmp_path, "psy_real_virtual.toml", 6), seed=1)
    out = tmp_path / "RV"
    assert analysis(["psychometric", str(data), "--out", str(out)]) == 0
    with (out / "proportions.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    renderings = json.loads((data / "S01" / "session.json").read_text())["experiment"]["config"]["renderings"]
    assert sorted(r["condition"] for r in rows) == sorted(renderings)
    for r in rows:
        n, k = int(r["n_trials"]), int(r["n_correct"])
        assert n == 6 and float(r["proportion_correct"]) == pytest.approx(k / n)
        low, high = proportion_confint(k, n, alpha=0.05, method="beta")     # Clopper-Pearson
        assert float(r["ci_low"]) == pytest.approx(low, abs=1e-9) and float(r["ci_high"]) == pytest.approx(high, abs=1e-9)
        # exact two-sided binomial test against 0.5 for a symmetric null: 2 x the smaller tail
        tail = sum(math.comb(n, i) for i in range(min(k, n - k) + 1)) / 2 ** n
        assert float(r["p_vs_chance"]) == pytest.approx(min(1.0, 2 * tail))
    assert (out / "fig_real_virtual.png").stat().st_size > 0
