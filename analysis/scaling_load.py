"""Reading the method-of-adjustment and magnitude-estimation study folders (``DATA/<subject>/session.json`` and
``trials.csv``, the formats of :mod:`plumbing.studyfiles`) into one table, with the block position and the
design's sequence of each trial (for order effects)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import statsmodels.formula.api as smf
from statsmodels.stats.anova import anova_lm

from plumbing.studyfiles import SESSION_JSON, TRIALS_CSV, parse_trials, read_session_json


def subject_folders(data) -> list[Path]:
    """The subject folders of ``data`` (a study folder, or one subject's folder).

    Raises
    ------
    ValueError
        ``data`` is missing, not a folder, or holds no subject folder.
    """
    data = Path(data)
    if not data.is_dir():
        raise ValueError(f"{data}: not a folder (give the study's data folder, or one subject's)")
    if (data / SESSION_JSON).is_file():
        return [data]
    folders = sorted(p for p in data.iterdir() if p.is_dir() and (p / SESSION_JSON).is_file())
    if not folders:
        raise ValueError(f"{data}: no subject folder (DATA/<subject>/{SESSION_JSON}) in it")
    return folders


def load_kind(data, fmt, kind: str) -> tuple[pd.DataFrame, dict]:
    """Every row of the sessions of ``kind`` under ``data`` (other kinds' folders are skipped and named).

    Parameters
    ----------
    data : str or Path
    fmt : plumbing.studyfiles.RowFormat
        ``ADJUSTMENT`` or ``MAGNITUDE``.
    kind : str
        ``session.json``'s ``experiment.kind``.

    Returns
    -------
    (DataFrame, dict)
        The rows (one per trial, typed; ``position`` the block's 1-based place in the session, ``sequence``
        the design's sequence or 0) and, per subject, its ``session.json["experiment"]`` plus ``skipped`` (the
        folders of another kind).

    Raises
    ------
    ValueError
        A damaged file (naming it and the line), or no session of ``kind``.
    """
    frames, experiments, skipped = [], {}, []
    for folder in subject_folders(data):
        session = read_session_json(folder / SESSION_JSON)
        exp = session.get("experiment")
        if not isinstance(exp, dict) or exp.get("kind") != kind:
            skipped.append(folder.name)
            continue
        path = folder / TRIALS_CSV
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise ValueError(f"{path}: cannot be read ({exc.strerror})") from None
        rows, _ = parse_trials(fmt, raw, path, subject=session.get("subject"))
        if rows:
            df = pd.DataFrame(rows)
            df["position"] = df["block"]
            df["sequence"] = pd.to_numeric(df["sequence"].replace("", "0")).astype(int)
            frames.append(df)
        experiments[session.get("subject", folder.name)] = exp
    if not frames:
        raise ValueError(f"{data}: no {kind} session with trials in it"
                         + (f" (other kinds: {', '.join(skipped)})" if skipped else ""))
    return pd.concat(frames, ignore_index=True), {"experiments": experiments, "skipped": skipped}


def order_effects(df: pd.DataFrame, value: str, factors: tuple = ("condition",)) -> pd.DataFrame | None:
    """Order and position as factors: a type-II ANOVA of ``value`` with subject, ``factors`` and the block's
    position by ordinary least squares (statsmodels). The design's sequence is one per subject, so its effect is
    within the subject term (a between-subject factor: compare sequences on the per-subject estimates).

    Returns
    -------
    DataFrame or None
        The ANOVA table (``sum_sq``, ``df``, ``F``, ``PR(>F)`` per term), or None when position does not vary
        (one condition).
    """
    if df["position"].nunique() < 2 or df["subject"].nunique() < 2:
        return None
    terms = ["C(subject)"] + [f"C({f})" for f in factors if df[f].nunique() > 1] + ["C(position)"]
    fit = smf.ols(f"{value} ~ " + " + ".join(terms), data=df).fit()
    table = anova_lm(fit, typ=2)
    table.index.name = "term"
    return table.reset_index()
