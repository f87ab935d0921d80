"""Intervals of the maximum-likelihood fit: the exact profile-likelihood bounds (against an independent profile
built with scipy), their coverage over hidden observers (a small version of the table in docs/psychophysics.md,
"Intervals and their coverage"), the free lower asymptote of a yes/no task with false alarms, BCa against scipy,
the chi-square p-value withheld on sparse levels."""

import math

import numpy as np
import pytest
from scipy import optimize, stats

from psychophysics import fitting as pm
from psychophysics.psychometric import base_quantile, psi

LEVELS = np.linspace(1.0, 4.0, 7)


def _independent_profile(levels, n, k, guess, function, ci_level=0.95):
    """The threshold's profile-likelihood interval computed another way: scipy's bounded minimiser for the
    slope and lapse at each threshold, brentq for the ends, the likelihood written from psychometric.psi."""
    def nll(thr, log_slope, lapse):
        p = np.clip(psi(levels, thr, math.exp(log_slope), guess, lapse, function), 1e-12, 1 - 1e-12)
        return -np.sum(k * np.log(p) + (n - k) * np.log1p(-p))

    def best(thr, start):
        res = optimize.minimize(lambda v: nll(thr, v[0], v[1]), start, method="L-BFGS-B",
                                bounds=[(-8, 8), (0.0, pm.LAPSE_MAX)], options={"ftol": 1e-13, "gtol": 1e-9})
        return res.fun

    starts = [(math.log(s), lam) for s in (0.5, 1.5, 4.0) for lam in (0.0, 0.05)]
    full = min((optimize.minimize(lambda v: nll(v[0], v[1], v[2]), (2.5, *s), method="L-BFGS-B",
                                  bounds=[(None, None), (-8, 8), (0.0, pm.LAPSE_MAX)],
                                  options={"ftol": 1e-15, "gtol": 1e-11}) for s in starts), key=lambda r: r.fun)
    crit = stats.chi2.ppf(ci_level, 1) / 2
    thr_hat = full.x[0]

    def drop(thr):
        return best(thr, full.x[1:]) - full.fun - crit

    lo = optimize.brentq(drop, thr_hat - 1.5, thr_hat, xtol=1e-9)
    hi = optimize.brentq(drop, thr_hat, thr_hat + 1.5, xtol=1e-9)
    return thr_hat, lo, hi


@pytest.mark.parametrize("guess, function, seed", [(0.5, "logistic", 1), (0.0, "normal", 2)])
def test_profile_bounds_are_exact(guess, function, seed):
    """The bounds found by root finding equal an independently built profile's to 1e-5 of the range, and the
    log-likelihood drops by exactly chi2_1(0.95) / 2 at each."""
    rng = np.random.default_rng(seed)
    n = np.full(7, 40.0)
    k = rng.binomial(40, psi(LEVELS, 2.5, 2.0, guess, 0.03, function)).astype(float)
    f = pm.fit_counts(LEVELS, n, k, 2 if guess else 1, function, bootstrap=0)[0]
    thr, lo, hi = _independent_profile(LEVELS, n, k, guess, function)
    assert f.threshold == pytest.approx(thr, abs=1e-5)
    assert f.threshold_ci == pytest.approx((lo, hi), abs=3e-5)
    assert f.threshold_ci_cutoff == pytest.approx(3.8415, abs=1e-4)      # the lapse is identified: Wilks'
    model = pm.build_model(LEVELS, function, "fixed", guess, None)
    for end in f.threshold_ci:
        start = np.array([[end, math.log(f.slope), f.lapse]])
        _, lp = pm.solve(model, k[None], n, start, hold=(0, [end]))
        assert f.loglik - lp[0] == pytest.approx(stats.chi2.ppf(0.95, 1) / 2, abs=1e-6)


def _coverage(function, alternatives, lower, n_obs, per_level, levels, seed, false_alarms=False, widths=(0.4, 0.8)):
    rng = np.random.default_rng(seed)
    lo, hi = levels[0], levels[-1]
    thr = rng.uniform(lo + 0.35 * (hi - lo), lo + 0.65 * (hi - lo), n_obs)
    width = rng.uniform(*widths, n_obs) * (hi - lo)              # the 10-90 % width, a share of the range
    slope = {"logistic": 2 * math.log(9), "normal": 2 * 1.2816}[function] / width
    lapse = rng.uniform(0.0, 0.04, n_obs)
    guess = rng.uniform(0.05, 0.15, n_obs) if false_alarms else np.full(n_obs, pm.guess_rate(alternatives))
    p = psi(levels[None, :], thr[:, None], slope[:, None], guess[:, None], lapse[:, None], function)
    k = rng.binomial(per_level, p).astype(float)
    fits = pm.fit_counts(levels, np.full(len(levels), float(per_level)), k, alternatives, function, bootstrap=0,
                         lower_asymptote=lower)
    ci = np.array([f.threshold_ci for f in fits])
    est = np.array([f.threshold for f in fits])
    return (ci[:, 0] <= thr) & (thr <= ci[:, 1]), np.median(est / thr - 1)


def test_coverage_of_the_printed_interval_on_hidden_observers():
    """The small version of the coverage table (docs/psychophysics.md, "Intervals and their coverage"): a yes/no design
    of 8 x 150 trials with steep observers (the interpolated 81-point grid's interval covered 0.83 of these 160) and
    a 2AFC 7 x 50, 160 observers each. A true coverage in 93-97 % gives a pooled rate within the binomial bounds
    below (n = 320, 0.1 % tails: about [0.90, 0.99])."""
    yn, _ = _coverage("logistic", 1, "fixed", 160, 150, np.linspace(1.0, 4.0, 8), seed=11, widths=(0.2, 0.4))
    two, _ = _coverage("normal", 2, "fixed", 160, 50, LEVELS, seed=12)
    hits = np.concatenate([yn, two])
    lo = stats.binom.ppf(0.001, len(hits), 0.93) / len(hits)
    hi = stats.binom.ppf(0.999, len(hits), 0.97) / len(hits)
    assert lo <= hits.mean() <= hi, (hits.mean(), lo, hi)


def _low_side(n_obs, seed, function="normal"):
    """2AFC observers whose levels (1-4, 7 x 50) sit low on their function: F = 0.05-0.15 at the lowest level,
    0.40-0.60 at the highest (the generator of benchmarks/bench_fit_coverage.py's "low side"), lapse 0-0.04."""
    rng = np.random.default_rng(seed)
    z_lo = base_quantile(rng.uniform(0.05, 0.15, n_obs), function)
    z_hi = base_quantile(rng.uniform(0.40, 0.60, n_obs), function)
    beta = (z_hi - z_lo) / 3.0
    thr = 1.0 - z_lo / beta
    lapse = rng.uniform(0.0, 0.04, n_obs)
    k = rng.binomial(50, psi(LEVELS[None, :], thr[:, None], beta[:, None], 0.5, lapse[:, None], function))
    return thr, k.astype(float)


def test_an_unidentified_lapse_rate_gives_the_one_sided_cutoff():
    """Levels below the threshold (2AFC, 27-40 of 50 correct): Wilks' interval runs the fitted lapse rate from its
    bound 0.1 at the low end to 0 at the high end, so the threshold is only partially identified; the printed
    interval then uses chi2_1(0.90) = 2.706 (Imbens & Manski 2004), the log-likelihood dropping by exactly half of
    it at each end, and lies inside Wilks' 3.841 interval."""
    n = np.full(7, 50.0)
    k = np.array([27, 23, 33, 26, 35, 36, 34.0])
    f = pm.fit_counts(LEVELS, n, k, 2, "normal", bootstrap=0)[0]
    assert f.lapse == pytest.approx(pm.LAPSE_MAX, abs=1e-9)
    assert f.threshold_ci_cutoff == pytest.approx(stats.chi2.ppf(0.90, 1), abs=1e-9) == pytest.approx(2.7055, abs=1e-4)
    assert f.as_dict()["threshold_ci_cutoff"] == f.threshold_ci_cutoff
    model = pm.build_model(LEVELS, "normal", "fixed", 0.5, None)
    theta = np.array([[f.threshold, math.log(f.slope), f.lapse]])
    for end in f.threshold_ci:
        lp = max(pm.solve(model, k[None], n, np.array([[end, math.log(f.slope), lam]]), hold=(0, [end]))[1][0]
                 for lam in (0.0, 0.05, 0.1))
        assert f.loglik - lp == pytest.approx(2.7055 / 2, abs=1e-4)
    wilks, cut = pm.profile_bounds(model, k[None], n, theta, np.array([f.loglik]), bound_aware=False,
                                   with_cutoff=True)
    assert cut[0] == pytest.approx(3.8415, abs=1e-4)
    lo, hi = f.threshold_ci
    assert wilks[0, 0] < lo - 0.05 and hi + 0.05 < wilks[0, 1]
    ends = [pm.solve(model, k[None], n, np.array([[e, math.log(f.slope), 0.05]]), hold=(0, [e]))[0]
            for e in wilks[0]]
    assert ends[0][0, 2] == pytest.approx(pm.LAPSE_MAX) and ends[1][0, 2] == pytest.approx(0.0, abs=1e-9)
    assert pm.lapse_unidentified(model, ends[0], ends[1])[0]


def test_coverage_where_the_levels_sit_below_the_threshold():
    """200 low-side 2AFC observers (normal): Wilks' cut-off covered 0.97-0.98 of such observers on 1000 (the
    benchmark); with the one-sided cut-off where the lapse rate is not identified the rate must lie within the
    binomial range of a true 93-97 % (0.1 % tails), and below Wilks' own on the same data."""
    thr, k = _low_side(200, seed=31)
    n = np.full(7, 50.0)
    fits = pm.fit_counts(LEVELS, n, k, 2, "normal", bootstrap=0)
    ci = np.array([f.threshold_ci for f in fits])
    covered = (ci[:, 0] <= thr) & (thr <= ci[:, 1])
    one_sided = np.array([f.threshold_ci_cutoff for f in fits]) < 3.0
    assert one_sided.mean() > 0.5                     # most such fits
    lo = stats.binom.ppf(0.001, len(thr), 0.93) / len(thr)
    hi = stats.binom.ppf(0.999, len(thr), 0.97) / len(thr)
    assert lo <= covered.mean() <= hi, (covered.mean(), lo, hi)
    wilks = pm.profile_interval(LEVELS, n, k, 2, "normal")    # bound-aware too: same intervals
    assert np.allclose(wilks, ci, equal_nan=True)


def test_a_free_lower_asymptote_removes_the_bias_of_false_alarms():
    """Yes/no observers who say "yes" to 5-15 % of blanks: gamma = 0 puts their threshold 5-11 % low, gamma =
    lambda biases it too; the fitted lower asymptote (psignifit's yes/no, Palamedes' free guess rate)
    recovers it within 2 % (median) and its interval covers the truth (>= 90 % of 160)."""
    covered, bias_free = _coverage("logistic", 1, "free", 160, 100, np.linspace(1.0, 4.0, 8), seed=21,
                                   false_alarms=True)
    _, bias_zero = _coverage("logistic", 1, "fixed", 160, 100, np.linspace(1.0, 4.0, 8), seed=21,
                             false_alarms=True)
    assert abs(bias_free) < 0.02 and bias_zero < -0.04
    assert covered.mean() >= 0.90
    f = pm.fit_counts(np.linspace(1.0, 4.0, 8), np.full(8, 100.0),
                      np.array([10, 14, 22, 41, 63, 80, 88, 95.0]), 1, "logistic", bootstrap=200,
                      lower_asymptote="free")[0]
    assert f.lower_asymptote == "free" and 0.05 < f.guess < 0.2 and f.guess_ci[0] < f.guess < f.guess_ci[1]
    with pytest.raises(ValueError, match="free lower asymptote .* is for a yes/no task"):
        pm.fit_counts(LEVELS, np.full(7, 10.0), np.arange(7.0), 2, lower_asymptote="free")


def test_bca_interval_equals_scipys():
    """The BCa formula (bias correction and jackknife acceleration) against scipy.stats.bootstrap's on a skewed
    statistic: the same interval to Monte Carlo precision (40,000 resamples each)."""
    rng = np.random.default_rng(1)
    x = rng.exponential(1.0, 40)

    def stat(a, axis=-1):
        return np.log(np.std(a, axis=axis, ddof=1))

    ref = stats.bootstrap((x,), stat, method="BCa", n_resamples=40_000, random_state=np.random.default_rng(2),
                          vectorized=True).confidence_interval
    boot = stat(x[np.random.default_rng(3).integers(0, 40, (40_000, 40))])
    jack = np.array([stat(np.delete(x, i)) for i in range(40)])
    lo, hi = pm.bca_interval(stat(x), boot, jack)
    assert lo == pytest.approx(ref.low, abs=0.01) and hi == pytest.approx(ref.high, abs=0.01)
    pct = np.quantile(boot, [0.025, 0.975])
    assert hi - pct[1] > 0.1       # this statistic is skewed: BCa and percentile differ


def test_the_chi_square_p_value_is_withheld_where_levels_hold_one_or_two_trials():
    rng = np.random.default_rng(5)
    x = np.repeat(np.linspace(1, 8, 30), 2)               # 2 trials per level: an adaptive track's kind of data
    y = (rng.random(len(x)) < psi(x, 4.0, 1.2, 0.5, 0.02)).astype(int)
    f = pm.fit(x, y, alternatives=2, bootstrap=100)
    assert math.isnan(f.deviance_p_chi2) and "fewer than 3 trials" in f.deviance_p_chi2_withheld
    assert 0.0 <= f.deviance_p_bootstrap <= 1.0
    assert f.as_dict()["deviance_p_chi2"] is None
    g = pm.fit(np.repeat(LEVELS, 10), (rng.random(70) < 0.8).astype(int), alternatives=2, bootstrap=0)
    assert 0.0 <= g.deviance_p_chi2 <= 1.0 and g.deviance_p_chi2_withheld == ""
