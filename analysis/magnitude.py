"""Magnitude estimation's analysis: Stevens' power law ``N = k phi^beta`` per subject and pooled.

* **Normalisation** (modulus equalisation, Lane, Catania & Stevens 1961): each subject's numbers (over all
  its conditions, so differences between conditions stay) are divided by their geometric mean and multiplied by the geometric mean of all subjects'
  numbers, so subjects who chose different number ranges (a free modulus) share one scale; with a modulus the
  factor is near 1. Exponents are unchanged by it (a factor on ``N`` is an intercept in log-log).
* **Per subject and condition**: ordinary least squares of ``ln N`` on ``ln phi`` (``phi`` the stimulus's
  physical value of the varied parameter): the exponent ``beta`` with its t interval, ``k``, R^2.
* **Pooled per condition**: the mean of the subjects' exponents with its t interval across subjects (subjects
  as the random factor), and the exponent of the pooled curve: the fit of the geometric means of the normalised
  numbers at each level (the classical group curve, Stevens 1957), with its OLS interval.

The figure is on log-log axes (the law is a line there).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from plumbing.studyfiles import MAGNITUDE

from .adjustment import t_interval
from .scaling_load import load_kind, order_effects


def load(data) -> tuple[pd.DataFrame, dict]:
    """The magnitude sessions' rows under ``data``, with ``ln_level``, ``ln_number`` and the normalised
    ``number_norm`` / ``ln_norm`` (module docstring)."""
    df, info = load_kind(data, MAGNITUDE, "magnitude")
    df["ln_level"] = np.log(df["level"])
    df["ln_number"] = np.log(df["number"])
    grand = df["ln_number"].mean()
    df["ln_norm"] = df["ln_number"] - df.groupby("subject")["ln_number"].transform("mean") + grand
    df["number_norm"] = np.exp(df["ln_norm"])
    return df, info


def power_fit(ln_x, ln_y, level: float = 0.95) -> dict:
    """OLS of ``ln_y`` on ``ln_x``: ``exponent`` with ``exponent_low``/``high`` (t interval), ``k``
    (``exp`` of the intercept), ``r2``, ``n``."""
    x, y = np.asarray(ln_x, float), np.asarray(ln_y, float)
    n = len(x)
    res = stats.linregress(x, y)
    h = float(stats.t.ppf(0.5 + level / 2, n - 2) * res.stderr) if n > 2 else math.nan
    return {"exponent": float(res.slope), "exponent_low": float(res.slope) - h, "exponent_high": float(res.slope) + h,
            "exponent_se": float(res.stderr), "k": math.exp(res.intercept), "r2": float(res.rvalue ** 2), "n": n}


def per_subject(df: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """One power-law fit per subject and condition (module docstring)."""
    out = []
    for (subject, condition), g in df.groupby(["subject", "condition"], sort=True):
        fit = power_fit(g["ln_level"], g["ln_number"], level) if g["level"].nunique() > 1 else {}
        out.append({"subject": subject, "condition": condition, **fit,
                    "modulus": float(g["modulus"].iloc[0]), "geometric_mean_number": math.exp(g["ln_number"].mean()),
                    "position": int(g["position"].iloc[0]), "sequence": int(g["sequence"].iloc[0])})
    return pd.DataFrame(out)


def pooled(df: pd.DataFrame, subjects: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """One row per condition (module docstring): the mean exponent over subjects with its interval, and the
    group curve's exponent (``curve_*``)."""
    out = []
    for condition, g in subjects.groupby("condition", sort=True):
        m, lo, hi = t_interval(g["exponent"].dropna(), level)
        d = df[df["condition"] == condition]
        gm = d.groupby("level")["ln_norm"].mean()
        curve = power_fit(np.log(gm.index.to_numpy(float)), gm.to_numpy(float), level)
        out.append({"condition": condition, "subjects": len(g), "exponent": m, "exponent_low": lo,
                    "exponent_high": hi, "exponent_sd": float(g["exponent"].std(ddof=1)) if len(g) > 1 else math.nan,
                    **{f"curve_{k}": v for k, v in curve.items()}})
    return pd.DataFrame(out)


def analyse(data, level: float = 0.95) -> dict:
    """Everything the ``magnitude`` command writes: ``trials``, ``subjects``, ``pooled``, ``order`` (the position
    ANOVA of the normalised log numbers with the level as a factor, or None), ``experiments``, ``skipped``."""
    df, info = load(data)
    subjects = per_subject(df, level)
    df["level_factor"] = df["level"].map(lambda v: format(v, "g"))
    return {"trials": df, "subjects": subjects, "pooled": pooled(df, subjects, level),
            "order": order_effects(df, "ln_norm", ("condition", "level_factor")), **info}
