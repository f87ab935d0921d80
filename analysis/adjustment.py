"""The method of adjustment's analysis: point of subjective equality, spread (a JND estimate) and constant error,
per subject and condition and pooled over subjects.

Per subject and condition, over the matched trials (settings ``s_i``, reference ``r``):

* **PSE** -- the geometric mean of the settings, ``exp(mean ln s_i)``, with its t interval
  ``exp(mean ln s +- t(n-1) sd(ln s) / sqrt(n))``. Stiffness and vibration amplitudes are judged on a ratio
  scale (Weber's law: the settings' spread grows with the reference), so their logarithms are averaged; the
  arithmetic mean and SD are reported beside (``pse_arith``, ``sd``).
* **Spread** -- ``sd_log``, the SD of ``ln s_i``, and the JND estimate from it: the 75 % point of a normal
  spread of settings is 0.6745 SD from the PSE (the classical semi-interquartile range, Guilford 1954;
  Jones & Tan 2013), so ``weber = exp(0.6745 sd_log) - 1`` and ``jnd = pse * weber`` (physical units).
* **Constant error** -- ``ce = pse - r`` (physical units) and ``ce_rel = pse / r - 1``; and the error of the
  starting side, ``direction_effect = mean ln s (started above) - mean ln s (started below)`` (a positive
  value: the settings stop short of the reference on the side they start from, the expected bias).

Pooled per condition over subjects: the mean of the subjects' ``ln(pse / r)`` with its t interval across
subjects (subjects as the random factor), reported as ``pse_rel`` (``exp`` of it) and ``pse = r * pse_rel``;
the mean Weber fraction and constant error. Unmatched trials (``max_comparisons`` reached) are counted and left
out.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from plumbing.studyfiles import ADJUSTMENT

from .scaling_load import load_kind, order_effects

#: z of the 75 % point: a setting 0.6745 SD from the PSE is judged different 75 % of the time
Z75 = 0.6744897501960817


def load(data) -> tuple[pd.DataFrame, dict]:
    """The adjustment sessions' rows under ``data`` (:func:`analysis.scaling_load.load_kind`), with ``ln_ratio``
    = ln(final / reference)."""
    df, info = load_kind(data, ADJUSTMENT, "adjustment")
    df["ln_ratio"] = np.log(df["final_value"] / df["reference_value"])
    return df, info


def t_interval(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its t interval ``(mean, low, high)`` (NaN bounds for fewer than 2 values)."""
    v = np.asarray(values, dtype=float)
    m = float(v.mean()) if len(v) else math.nan
    if len(v) < 2:
        return m, math.nan, math.nan
    h = float(stats.t.ppf(0.5 + level / 2, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return m, m - h, m + h


def per_subject(df: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """One row per subject and condition (module docstring): ``n``, ``unmatched``, ``reference``, ``pse``,
    ``pse_low``, ``pse_high``, ``pse_arith``, ``sd``, ``sd_log``, ``weber``, ``jnd``, ``ce``, ``ce_rel``,
    ``direction_effect``, ``position``, ``sequence``."""
    out = []
    for (subject, condition), g in df.groupby(["subject", "condition"], sort=True):
        m = g[g["matched"] == 1]
        s, r = m["final_value"].to_numpy(float), float(g["reference_value"].iloc[0])
        mean, lo, hi = t_interval(np.log(s), level) if len(s) else (math.nan,) * 3
        sd_log = float(np.std(np.log(s), ddof=1)) if len(s) > 1 else math.nan
        pse = math.exp(mean) if len(s) else math.nan
        weber = math.expm1(Z75 * sd_log)
        above, below = np.log(m.loc[m["start_side"] == "above", "final_value"]), np.log(
            m.loc[m["start_side"] == "below", "final_value"])
        out.append({"subject": subject, "condition": condition, "n": len(s), "unmatched": int((g["matched"] == 0).sum()),
                    "reference": r, "pse": pse, "pse_low": math.exp(lo), "pse_high": math.exp(hi),
                    "pse_arith": float(s.mean()) if len(s) else math.nan,
                    "sd": float(s.std(ddof=1)) if len(s) > 1 else math.nan, "sd_log": sd_log, "weber": weber,
                    "jnd": pse * weber, "ce": pse - r, "ce_rel": pse / r - 1.0,
                    "direction_effect": float(above.mean() - below.mean()) if len(above) and len(below) else math.nan,
                    "position": int(g["position"].iloc[0]), "sequence": int(g["sequence"].iloc[0])})
    return pd.DataFrame(out)


def pooled(subjects: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """One row per condition over subjects (module docstring): ``subjects``, ``reference``, ``pse_rel`` with
    ``pse_rel_low``/``high``, ``pse`` with ``pse_low``/``high``, ``weber`` (mean) with its interval, ``ce``,
    ``ce_rel``."""
    out = []
    for condition, g in subjects.groupby("condition", sort=True):
        g = g[np.isfinite(g["pse"])]
        r = float(g["reference"].iloc[0])
        m, lo, hi = t_interval(np.log(g["pse"] / g["reference"]), level)
        w, wlo, whi = t_interval(g["weber"].dropna(), level)
        out.append({"condition": condition, "subjects": len(g), "reference": r, "pse_rel": math.exp(m),
                    "pse_rel_low": math.exp(lo), "pse_rel_high": math.exp(hi), "pse": r * math.exp(m),
                    "pse_low": r * math.exp(lo), "pse_high": r * math.exp(hi), "weber": w, "weber_low": wlo,
                    "weber_high": whi, "ce": r * math.expm1(m), "ce_rel": math.expm1(m)})
    return pd.DataFrame(out)


def analyse(data, level: float = 0.95) -> dict:
    """Everything the ``adjustment`` command writes: ``trials``, ``subjects``, ``pooled``, ``order`` (the
    position ANOVA of ``ln_ratio``, or None), ``experiments``, ``skipped``."""
    df, info = load(data)
    subjects = per_subject(df, level)
    return {"trials": df, "subjects": subjects, "pooled": pooled(subjects, level),
            "order": order_effects(df[df["matched"] == 1], "ln_ratio"), **info}
