"""Planning the next study's size (command :mod:`analysis.cli_plan`).

Every number comes from statsmodels' power of the one-sample t-test (``TTestPower``, the paired
t-test on the per-subject differences: noncentral t with df = n - 1, noncentrality d_z sqrt(n)):

* **difference test** of a pair (two-sided paired t-test): the smallest n whose power reaches the
  target at level ``alpha / m``; ``m`` = the planned comparisons. Holm's procedure tests its first
  (smallest) p-value at alpha/m and the later ones at larger levels, so planning at alpha/m gives
  every comparison at least the target power under Holm (the plan is conservative for the others);
* **equivalence (TOST)** at a margin of +-``margin`` rating points, sample minus reference: the two
  one-sided tests at level ``alpha / m_eq`` each, with power ``P(lower rejects) + P(upper rejects) - 1``
  (each from ``TTestPower``, one-sided), the standard approximation (Chow, Shao & Wang 2008, eq.
  3.1.9; TOSTER's ``powerTOSTpaired``), a lower bound of the exact TOST power;
* from a pilot, each pair's observed d_z with its 95 % CI (noncentral-t inversion, Steiger & Fouladi
  1997) and, for equivalence, its observed mean difference and SD of the differences.

Every row of a plan fails alone: a pilot pair whose d_z or interval cannot be computed (every subject
gave the same difference, a noncentral t that scipy cannot evaluate) gets no sample size and a plain
``note`` saying why; the other rows, the table and the figure are still written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize
from scipy import stats as sps
from statsmodels.stats.power import TTestPower

from analysis.failures import reason
from plumbing.validation import require_number

PLAN_COLUMNS = ("test", "sample_a", "sample_b", "source", "n_pilot", "dz", "dz_ci_low", "dz_ci_high",
                "mean_diff", "sd_diff", "margin", "comparisons", "alpha_each", "power_target", "n_required",
                "power_at_n", "note")
N_MAX = 100_000      # above this many subjects a plan is reported as not reachable
#: an SD of the differences below this share of their magnitude is rounding (per-subject means of whole-number
#: ratings that differ by the same amount give an SD of ~1e-16, not 0, and a d_z of ~1e16)
ZERO_SD_RELATIVE = 1e-9


@dataclass(frozen=True)
class PlanSettings:
    """Planning choices, checked at the boundary.

    Attributes
    ----------
    power : float
        Target power of every comparison, in (0, 1) (default 0.8).
    alpha : float
        Family-wise level, in (0, 1); Holm over the planned comparisons of each kind.
    comparisons : int
        Planned difference tests (Holm family size), >= 1.
    equivalence_comparisons : int
        Planned equivalence tests (Holm family size), >= 1.
    margin : float
        Equivalence margin, rating points (> 0).
    """

    power: float = 0.8
    alpha: float = 0.05
    comparisons: int = 66
    equivalence_comparisons: int = 11
    margin: float = 0.5

    def __post_init__(self):
        require_number("--power", self.power, minimum=0.0, strict=True)
        require_number("--alpha", self.alpha, minimum=0.0, strict=True)
        if not (self.power < 1 and self.alpha < 1):
            raise ValueError(f"--power and --alpha must be below 1, got {self.power} and {self.alpha}")
        for name, value in (("--comparisons", self.comparisons),
                            ("--equivalence-comparisons", self.equivalence_comparisons)):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be a whole number >= 1, got {value}")
        require_number("--margin", self.margin, minimum=0.0, strict=True)


_POWER = TTestPower()


def power_difference(dz: float, n: int, alpha_each: float) -> float:
    """Power of the two-sided paired t-test with effect ``dz`` (1), ``n`` subjects, level ``alpha_each``.

    statsmodels' two-sided power adds the noncentral t's far tail on the other side, which scipy (1.17)
    returns as NaN once it is below ~1e-16 (e.g. d_z = 0.5, n = 104, alpha = 0.05/66); the power is
    then statsmodels' one-sided power at alpha/2 plus that tail where it is finite (else 0); and 1 where
    scipy's near side is NaN too, 8+ standard errors past the critical value.
    """
    p = float(_POWER.power(effect_size=abs(dz), nobs=n, alpha=alpha_each, alternative="two-sided"))
    if np.isnan(p):
        near = float(_POWER.power(effect_size=abs(dz), nobs=n, alpha=alpha_each / 2, alternative="larger"))
        far = float(_POWER.power(effect_size=abs(dz), nobs=n, alpha=alpha_each / 2, alternative="smaller"))
        p = near + (far if np.isfinite(far) else 0.0)
    if np.isnan(p) and abs(dz) * math.sqrt(n) - sps.t.isf(alpha_each / 2, n - 1) > 8.0:
        p = 1.0     # the noncentrality 8+ SDs past the critical value: scipy's NaN stands for 1 - (< 1e-15)
    return p


def power_tost(delta_dz: float, margin_dz: float, n: int, alpha_each: float) -> float:
    """Approximate power of the paired TOST (Chow, Shao & Wang 2008, eq. 3.1.9), clipped to [0, 1].

    Parameters
    ----------
    delta_dz : float
        True mean difference in SDs of the differences (1).
    margin_dz : float
        Equivalence margin in SDs of the differences (1), > 0.
    n : int
        Subjects.
    alpha_each : float
        Level of each one-sided test.
    """
    lower = _POWER.power(effect_size=delta_dz + margin_dz, nobs=n, alpha=alpha_each, alternative="larger")
    upper = _POWER.power(effect_size=delta_dz - margin_dz, nobs=n, alpha=alpha_each, alternative="smaller")
    return float(min(1.0, max(0.0, lower + upper - 1.0)))


def _power_difference_at(dz: float, ns: np.ndarray, alpha_each: float) -> np.ndarray:
    """:func:`power_difference` at every n of ``ns`` (ints), equal to it value for value.

    statsmodels' power takes the array of n at once (the same scipy functions, element by element: several
    times faster than one call per n), and so do :func:`power_difference`'s fallbacks at the n where it is NaN.
    """
    ns = np.asarray(ns)
    p = np.array(_POWER.power(effect_size=abs(dz), nobs=ns, alpha=alpha_each, alternative="two-sided"),
                 dtype=float, ndmin=1)
    nan = np.flatnonzero(np.isnan(p))
    if len(nan):
        n = ns[nan]
        near = np.asarray(_POWER.power(effect_size=abs(dz), nobs=n, alpha=alpha_each / 2, alternative="larger"),
                          dtype=float)
        far = np.asarray(_POWER.power(effect_size=abs(dz), nobs=n, alpha=alpha_each / 2, alternative="smaller"),
                         dtype=float)
        q = near + np.where(np.isfinite(far), far, 0.0)
        past = abs(dz) * np.sqrt(n) - sps.t.isf(alpha_each / 2, n - 1) > 8.0
        p[nan] = np.where(np.isnan(q) & past, 1.0, q)
    return p


def _power_tost_at(delta_dz: float, margin_dz: float, ns: np.ndarray, alpha_each: float) -> np.ndarray:
    """:func:`power_tost` at every n of ``ns`` (ints), equal to it value for value (one statsmodels call per side
    for all n; the clipping as ``min(1, max(0, x))`` does it, NaN to 0)."""
    lower = np.asarray(_POWER.power(effect_size=delta_dz + margin_dz, nobs=ns, alpha=alpha_each,
                                    alternative="larger"), dtype=float)
    upper = np.asarray(_POWER.power(effect_size=delta_dz - margin_dz, nobs=ns, alpha=alpha_each,
                                    alternative="smaller"), dtype=float)
    x = lower + upper - 1.0
    x = np.where(x > 0.0, x, 0.0)
    return np.where(x < 1.0, x, 1.0)


def smallest_n(power_of, target: float, n_max: int = N_MAX) -> int | None:
    """Smallest n >= 2 with ``power_of(n) >= target`` (power rising with n), or None above ``n_max``."""
    raw = power_of

    def checked(n):
        p = raw(n)
        if not np.isfinite(p):
            raise ValueError(f"the power at n = {n} is not a number (statsmodels' noncentral t returned {p})")
        return p

    power_of = checked
    if power_of(n_max) < target:
        return None
    lo, hi = 2, 2
    while power_of(hi) < target:
        lo, hi = hi, min(hi * 2, n_max)
    while lo < hi:                       # power_of(hi) >= target; find the first such n in [lo, hi]
        mid = (lo + hi) // 2
        if power_of(mid) >= target:
            hi = mid
        else:
            lo = mid + 1
    return hi


def dz_ci(dz: float, n: int, level: float = 0.95) -> tuple[float, float]:
    """CI of Cohen's d_z from ``n`` pairs: the noncentral t inverted (Steiger & Fouladi 1997).

    The bounds are the noncentralities lambda whose noncentral t (df = n - 1) puts the observed
    t = d_z sqrt(n) at its upper and lower (1 - level)/2 tails, divided by sqrt(n).
    """
    if n < 2 or not np.isfinite(dz):
        return float("nan"), float("nan")
    df, t = n - 1, dz * math.sqrt(n)
    tail = (1 - level) / 2

    def at(q):
        def f(ncp):      # rises with ncp
            v = float(sps.nct.sf(t, df, ncp)) - q
            if not np.isfinite(v):
                raise ValueError(f"the noncentral t (df {df}, t = {t:.4g}) cannot be evaluated at noncentrality "
                                 f"{ncp:.4g}")
            return v
        # the interval of a small pilot is wide (with 3 subjects its upper end can be several times t): widen
        # the bracket until it holds the root
        width = 10.0 + abs(t)
        for _ in range(40):
            if f(t - width) < 0 < f(t + width):
                return optimize.brentq(f, t - width, t + width, xtol=1e-10)
            width *= 2.0
        raise ValueError(f"no noncentrality within ±{width:.3g} of t = {t:.4g} puts it at the {q:g} tail")

    with np.errstate(all="ignore"):
        return at(tail) / math.sqrt(n), at(1 - tail) / math.sqrt(n)


def difference_row(sample_a: str, sample_b: str, dz: float, settings: PlanSettings, source: str,
                   n_pilot: int | None = None, ci=(np.nan, np.nan)) -> dict:
    """One ``plan.csv`` row of a two-sided paired difference test with effect ``dz``."""
    a = settings.alpha / settings.comparisons
    row = {"test": "difference", "sample_a": sample_a, "sample_b": sample_b, "source": source,
           "n_pilot": n_pilot, "dz": dz, "dz_ci_low": ci[0], "dz_ci_high": ci[1], "mean_diff": np.nan,
           "sd_diff": np.nan, "margin": np.nan, "comparisons": settings.comparisons, "alpha_each": a,
           "power_target": settings.power, "note": ""}
    n = smallest_n(lambda k: power_difference(dz, k, a), settings.power) if np.isfinite(dz) and dz != 0 else None
    if n is None:
        row.update(n_required=np.nan, power_at_n=np.nan,
                   note="no effect to detect (d_z = 0)" if dz == 0 else
                   "d_z not available" if not np.isfinite(dz) else f"more than {N_MAX} subjects")
    else:
        row.update(n_required=n, power_at_n=power_difference(dz, n, a))
    return row


def equivalence_row(sample: str, reference: str, mean_diff: float, sd_diff: float, settings: PlanSettings,
                    source: str, n_pilot: int | None = None) -> dict:
    """One ``plan.csv`` row of a paired TOST of ``sample`` - ``reference`` at +-margin.

    ``mean_diff``: assumed true difference (rating points); ``sd_diff``: SD of the differences.
    """
    a = settings.alpha / settings.equivalence_comparisons
    delta, margin = mean_diff / sd_diff, settings.margin / sd_diff
    row = {"test": "equivalence", "sample_a": sample, "sample_b": reference, "source": source,
           "n_pilot": n_pilot, "dz": delta, "dz_ci_low": np.nan, "dz_ci_high": np.nan, "mean_diff": mean_diff,
           "sd_diff": sd_diff, "margin": settings.margin, "comparisons": settings.equivalence_comparisons,
           "alpha_each": a, "power_target": settings.power, "note": ""}
    n = smallest_n(lambda k: power_tost(delta, margin, k, a), settings.power) \
        if np.isfinite(delta) and abs(mean_diff) < settings.margin else None
    if n is None:
        why = ("the difference is not inside the margin: equivalence cannot be shown"
               if np.isfinite(delta) and abs(mean_diff) >= settings.margin else
               "no SD of the differences" if not np.isfinite(delta) else f"more than {N_MAX} subjects")
        row.update(n_required=np.nan, power_at_n=np.nan, note=why)
    else:
        row.update(n_required=n, power_at_n=power_tost(delta, margin, n, a))
    return row


def assumed_plan(dz: float, sd_diff: float, settings: PlanSettings) -> pd.DataFrame:
    """Plan from an assumed effect: one difference test (d_z = ``dz``) and one TOST (true difference 0)."""
    rows = [difference_row("(assumed)", "", dz, settings, "assumed"),
            equivalence_row("(assumed)", "", 0.0, sd_diff, settings, "assumed")]
    return pd.DataFrame(rows, columns=list(PLAN_COLUMNS))


def pilot_plan(matrix, reference: str, settings: PlanSettings) -> pd.DataFrame:
    """Plan from a pilot's per-subject means (:class:`analysis.stats.RatingMatrix`, all subjects).

    Every pair: the observed d_z (with its 95 % CI) as the effect to detect. Every sample against
    ``reference``: a TOST whose true difference and SD are the pilot's observed ones.
    """
    m, samples = matrix.means, matrix.samples
    rows = []
    for i in range(len(samples)):
        for j in range(i + 1, len(samples)):
            d = m[:, i] - m[:, j]
            d = d[np.isfinite(d)]
            sd, why = _pilot_sd(d)
            dz = float(np.mean(d) / sd) if np.isfinite(sd) else np.nan
            rows.append(_one_row([
                ("95 % CI of d_z", lambda: difference_row(samples[i], samples[j], dz, settings, "pilot", d.size, dz_ci(dz, d.size))),
                ("sample size", lambda: difference_row(samples[i], samples[j], dz, settings, "pilot", d.size)),
                ("", lambda: _failed_row("difference", samples[i], samples[j], settings, d.size))], why))
    if reference in samples:
        r = samples.index(reference)
        for j, s in enumerate(samples):
            if j == r:
                continue
            d = m[:, j] - m[:, r]
            d = d[np.isfinite(d)]
            sd, why = _pilot_sd(d)
            mean = float(np.mean(d)) if d.size else np.nan
            rows.append(_one_row([
                ("sample size", lambda: equivalence_row(s, reference, mean, sd, settings, "pilot", int(d.size))),
                ("", lambda: _failed_row("equivalence", s, reference, settings, int(d.size)))], why))
    return pd.DataFrame(rows, columns=list(PLAN_COLUMNS))


def _pilot_sd(d: np.ndarray) -> tuple[float, str]:
    """SD of a pilot pair's per-subject differences (NaN where it is not a spread) and, then, why in words."""
    if d.size < 2:
        return np.nan, f"{d.size} subject(s) rated both samples: a pilot pair needs 2 or more for an SD"
    sd = float(np.std(d, ddof=1))
    if not sd > ZERO_SD_RELATIVE * max(float(np.max(np.abs(d))), 1.0):
        return np.nan, (f"every one of the {d.size} subjects gave the same difference ({float(np.mean(d)):+.3g} "
                        "rating points, SD 0): d_z is not defined; plan this pair with --dz")
    return sd, ""


def _failed_row(test: str, sample_a: str, sample_b: str, settings: PlanSettings, n_pilot: int) -> dict:
    """A row without numbers (its note is set by the caller)."""
    m = settings.comparisons if test == "difference" else settings.equivalence_comparisons
    return {"test": test, "sample_a": sample_a, "sample_b": sample_b, "source": "pilot", "n_pilot": n_pilot,
            "dz": np.nan, "dz_ci_low": np.nan, "dz_ci_high": np.nan, "mean_diff": np.nan, "sd_diff": np.nan,
            "margin": settings.margin if test == "equivalence" else np.nan, "comparisons": m,
            "alpha_each": settings.alpha / m, "power_target": settings.power, "n_required": np.nan,
            "power_at_n": np.nan, "note": ""}


def _one_row(tries, why: str) -> dict:
    """The first of ``tries`` ((what it leaves out, builder) pairs, fullest first) that builds; the parts left out
    and why in its note. ``why`` (the pilot's own reason, e.g. SD 0) replaces a generic note."""
    failed = []
    row = None
    for what, build in tries:
        try:
            row = build()
            break
        except Exception as exc:         # one row's failure is its own (analysis.failures)
            failed.append(f"{what} not computed: {reason(exc)}")
    note = row.get("note", "")
    if why and note in ("", "d_z not available", "no SD of the differences"):
        note = why
    elif why:
        note = f"{why}; {note}"
    row["note"] = "; ".join([n for n in [note] if n] + failed)
    return row


def power_curves(plan: pd.DataFrame, n_max: int | None = None) -> pd.DataFrame:
    """Power against subjects for every row of ``plan``: ``row, test, label, n, power`` (long format).

    ``n_max``: largest n drawn (default: 1.5 x the largest finite ``n_required``, at least 20, at most 500).
    """
    finite = plan["n_required"].dropna()
    if n_max is None:
        n_max = int(min(500, max(20, 1.5 * finite.max()))) if len(finite) else 100
    ns = np.unique(np.linspace(2, n_max, min(n_max - 1, 120)).astype(int))
    out = []
    for k, r in enumerate(plan.itertuples()):
        if not np.isfinite(r.dz):
            continue
        if r.test == "difference":
            pw = _power_difference_at(r.dz, ns, r.alpha_each)
            label = f"{r.sample_a} vs {r.sample_b}" if r.sample_b else f"d_z = {r.dz:.2f}"
        else:
            if not np.isfinite(r.sd_diff):
                continue
            pw = _power_tost_at(r.dz, r.margin / r.sd_diff, ns, r.alpha_each)
            label = f"{r.sample_a} ≡ {r.sample_b}" if r.sample_b else f"TOST ±{r.margin:g}"
        out.append(pd.DataFrame({"row": k, "test": r.test, "label": label, "n": ns, "power": pw}))
    return pd.concat(out, ignore_index=True) if out else pd.DataFrame(columns=["row", "test", "label", "n", "power"])


def plan_line(r) -> str:
    """The printed line of one plan row (a ``plan.csv`` row as a namedtuple)."""
    what = (f"difference {r.sample_a} vs {r.sample_b}" if r.sample_b else "difference") if r.test == "difference" \
        else (f"equivalence {r.sample_a} vs {r.sample_b} (±{r.margin:g})" if r.sample_b
              else f"equivalence (±{r.margin:g}, SD of differences {r.sd_diff:g})")
    eff = f"d_z = {r.dz:.2f}" if np.isfinite(r.dz) else "d_z = –"
    if np.isfinite(r.dz_ci_low):
        eff += f" [95 % CI {r.dz_ci_low:.2f}, {r.dz_ci_high:.2f}]"
    if r.test == "equivalence" and np.isfinite(r.mean_diff):
        eff = f"true difference {r.mean_diff:+.2f} ({eff})"
    level = f"α = {r.alpha_each:.3g} (Holm over {r.comparisons})"
    if np.isfinite(r.n_required):
        return f"{what}: {eff} -> {int(r.n_required)} subjects for power {r.power_target:g} at {level}"
    return f"{what}: {eff} -> no sample size: {r.note}"
