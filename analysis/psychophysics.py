"""Forced-choice and staircase data: reading them (a study folder or a plain CSV) and fitting them per group.

Two inputs (docs/analysis.md, "Psychometric fits"):

* a study folder of psychophysics sessions: ``DATA/<subject>/session.json`` with an ``experiment``
  entry (kind, alternatives, method, intensity scale, reference) and ``trials.csv`` with at least the
  columns ``intensity`` and ``correct`` (and ``condition``, ``staircase``, ``trial``, ``is_catch``);
  ``DATA`` may also be one subject's folder;
* a plain CSV from any software: columns ``intensity`` and ``correct`` (0/1), optional ``subject``,
  ``condition``, ``is_catch``, ``trial``, ``staircase``.

Catch trials (``is_catch = 1``) are kept for the staircase figure and left out of every fit. Each
bad cell is one ``ValueError`` naming the file and line.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from plumbing.studyfiles import FIT_COLUMNS, FIT_OPTIONAL_COLUMNS, SESSION_JSON, read_session_json
from psychophysics.fitting import Fit, fit

#: the columns a fit reads (plumbing.studyfiles: the forced-choice trials.csv holds them all)
REQUIRED, OPTIONAL = FIT_COLUMNS, FIT_OPTIONAL_COLUMNS
POOLED = "(pooled)"
ALL = "(all)"


@dataclass(frozen=True)
class Trials:
    """Trial-by-trial forced-choice data, one entry per trial (arrays of equal length T).

    ``experiment`` is the ``experiment`` entry of the sessions' ``session.json`` (the first subject's;
    empty for a plain CSV); ``sources`` names the files read.
    """

    subject: np.ndarray
    condition: np.ndarray
    staircase: np.ndarray
    trial: np.ndarray
    intensity: np.ndarray
    correct: np.ndarray
    is_catch: np.ndarray
    experiment: dict
    sources: tuple

    def __len__(self) -> int:
        return len(self.intensity)


def _zero_one(text: str, path: Path, line: int, column: str) -> int:
    if text.strip() in ("0", "1"):
        return int(text)
    raise ValueError(f"{path}:{line}: {column} must be 0 or 1, got {text!r}")


def _read_csv(path: Path, subject_default: str) -> dict:
    """Columns of one trials CSV, validated cell by cell (streamed: the file is never held twice)."""
    cols = {name: [] for name in REQUIRED + OPTIONAL}
    try:
        fh = path.open(newline="", encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path} does not exist") from None
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise ValueError(f"{path}: empty file (expected a header with columns intensity, correct)") from None
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: not UTF-8 text ({exc.reason})") from None
        header = [h.strip() for h in header]
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            raise ValueError(f"{path}:1: missing column(s) {', '.join(missing)} (a psychometric fit needs "
                             "intensity and correct, 0/1)")
        where = {name: header.index(name) for name in REQUIRED + OPTIONAL if name in header}
        try:
            for line, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise ValueError(f"{path}:{line}: {len(row)} fields, the header has {len(header)}")
                text = row[where["intensity"]]
                try:
                    x = float(text)
                except ValueError:
                    raise ValueError(f"{path}:{line}: intensity must be a number, got {text!r}") from None
                if not math.isfinite(x):
                    raise ValueError(f"{path}:{line}: intensity must be finite, got {text!r}")
                cols["intensity"].append(x)
                cols["correct"].append(_zero_one(row[where["correct"]], path, line, "correct"))
                cols["is_catch"].append(_zero_one(row[where["is_catch"]], path, line, "is_catch")
                                        if "is_catch" in where else 0)
                cols["subject"].append(row[where["subject"]] if "subject" in where else subject_default)
                cols["condition"].append(row[where["condition"]] if "condition" in where else "")
                cols["staircase"].append(row[where["staircase"]] if "staircase" in where else "")
                if "trial" in where:
                    try:
                        cols["trial"].append(int(row[where["trial"]]))
                    except ValueError:
                        raise ValueError(f"{path}:{line}: trial must be a whole number, got "
                                         f"{row[where['trial']]!r}") from None
                else:
                    cols["trial"].append(line - 1)
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: not UTF-8 text ({exc.reason})") from None
        except csv.Error as exc:
            raise ValueError(f"{path}:{reader.line_num}: {exc}") from None
    return cols


def load_trials(path) -> Trials:
    """Read forced-choice trials from a study folder, one subject's folder or a plain CSV.

    Parameters
    ----------
    path : str or Path
        ``DATA`` (subject folders with ``session.json`` naming an ``experiment``), one subject folder,
        or a CSV file.

    Returns
    -------
    Trials
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    chunks, sources, experiment = [], [], {}
    if path.is_file():
        chunks.append(_read_csv(path, ""))
        sources.append(str(path))
    else:
        folders = [path] if (path / "session.json").is_file() else sorted(
            p for p in path.iterdir() if p.is_dir() and (p / "session.json").is_file())
        skipped = []
        for folder in folders:
            session = read_session_json(folder / SESSION_JSON)
            exp = session.get("experiment")
            if not isinstance(exp, dict):
                skipped.append(folder.name)
                continue
            if not experiment:
                experiment = exp
            elif exp.get("kind") != experiment.get("kind"):
                raise ValueError(f"{folder / 'session.json'}: experiment kind {exp.get('kind')!r} differs from "
                                 f"{experiment.get('kind')!r} of the first subject; fit one kind at a time")
            trials = folder / "trials.csv"
            if not trials.is_file():
                continue   # a session that never ran a trial
            chunks.append(_read_csv(trials, str(session.get("subject") or folder.name)))
            sources.append(str(trials))
        if not chunks:
            extra = (f" ({len(skipped)} rating session(s) without an 'experiment' entry: analyse those with "
                     "'analysis report')") if skipped else ""
            raise ValueError(f"{path}: no psychophysics session with trials found{extra}")
    cols = {k: [v for c in chunks for v in c[k]] for k in REQUIRED + OPTIONAL}
    if not cols["intensity"]:
        raise ValueError(f"{', '.join(sources)}: no trials")
    return Trials(subject=np.array(cols["subject"], dtype=object), condition=np.array(cols["condition"], dtype=object),
                  staircase=np.array(cols["staircase"], dtype=object), trial=np.array(cols["trial"], dtype=np.int64),
                  intensity=np.array(cols["intensity"], dtype=float), correct=np.array(cols["correct"], dtype=np.int8),
                  is_catch=np.array(cols["is_catch"], dtype=bool), experiment=experiment, sources=tuple(sources))


@dataclass(frozen=True)
class GroupFit:
    """The fit of one group of trials: a subject in a condition, or all subjects pooled."""

    subject: str
    condition: str
    fit: Fit


def fit_groups(trials: Trials, alternatives: int, function: str = "logistic", lapse=None, bootstrap: int = 1000,
               ci_level: float = 0.95, reference=None, seed: int = 0, equal_asymptote: bool = False) -> list[GroupFit]:
    """Fit every (subject, condition) group, each condition pooled over subjects, and all trials pooled.

    Parameters
    ----------
    trials : Trials
    alternatives, function, lapse, bootstrap, ci_level, reference, seed, equal_asymptote
        As for :func:`psychophysics.fitting.fit`.

    Returns
    -------
    list of GroupFit
        Pooled over everything first (subject and condition :data:`POOLED`/:data:`ALL`), then each
        condition pooled, then each subject x condition (groups with fewer than two intensities are
        reported as errors).
    """
    keep = ~trials.is_catch
    subjects = sorted(set(trials.subject[keep]))
    conditions = sorted(set(trials.condition[keep]))
    groups = [(POOLED, ALL, keep)]
    if len(conditions) > 1:
        groups += [(POOLED, c, keep & (trials.condition == c)) for c in conditions]
    if len(subjects) > 1:
        groups += [(s, c, keep & (trials.subject == s) & (trials.condition == c)) for c in conditions for s in subjects]
    out = []
    for i, (subject, condition, mask) in enumerate(groups):
        if not mask.any():
            continue
        try:
            f = fit(trials.intensity[mask], trials.correct[mask], alternatives=alternatives, function=function,
                    lapse=lapse, bootstrap=bootstrap, ci_level=ci_level, reference=reference, seed=seed + i,
                    equal_asymptote=equal_asymptote)
        except ValueError as exc:
            who = f"subject {subject!r}, condition {condition!r}"
            raise ValueError(f"{who}: {exc}") from None
        out.append(GroupFit(subject, condition, f))
    return out


def physical_summary(f: Fit, reference=None) -> dict:
    """Threshold, PSE, JND and Weber fraction in physical units of a fit on a log10 intensity axis.

    Parameters
    ----------
    f : Fit
        Fitted on ``log10`` of the physical stimulus (a session with ``intensity_scale = "log10"``).
    reference : float, optional
        The reference stimulus in physical units.

    Returns
    -------
    dict
        ``threshold_physical`` (= 10**threshold) and its interval, ``jnd_physical`` = 10**x(F=0.75) -
        10**x(F=0.5), and ``weber_physical``: ``jnd_physical / reference`` for a yes/no task, ``(10**threshold
        - reference) / reference`` for an n-AFC task (None without a reference).
    """
    thr = 10.0 ** f.threshold
    x75 = 10.0 ** (f.threshold + f.jnd)
    jnd = x75 - thr
    weber = None
    if reference is not None and math.isfinite(reference) and reference > 0:
        weber = jnd / reference if f.alternatives == 1 else (thr - reference) / reference
    lo, hi = f.threshold_ci
    return {"threshold_physical": thr, "pse_physical": thr, "jnd_physical": jnd, "weber_physical": weber,
            "reference_physical": reference,
            "threshold_ci_physical": [10.0 ** lo if math.isfinite(lo) else None,
                                      10.0 ** hi if math.isfinite(hi) else None]}


def fits_table(fits: list[GroupFit], reference_physical=None) -> tuple[list[str], list[list]]:
    """``fits.csv``'s header and rows: one row per group, intervals as ``*_ci_low``/``*_ci_high``.

    With ``reference_physical`` (a fit on a log10 axis), the physical threshold, JND and Weber fraction
    (:func:`physical_summary`) follow as extra columns.
    """
    header = ["subject", "condition", "function", "alternatives", "n_trials", "n_levels", "threshold",
              "threshold_ci_low", "threshold_ci_high", "slope", "slope_ci_low", "slope_ci_high", "lapse",
              "lapse_ci_low", "lapse_ci_high", "pse", "jnd", "jnd_ci_low", "jnd_ci_high", "weber", "weber_ci_low",
              "weber_ci_high", "deviance", "deviance_p_bootstrap", "deviance_p_chi2"]
    rows = []
    for g in fits:
        f = g.fit
        rows.append([g.subject, g.condition, f.function, f.alternatives, f.n_trials, f.n_levels, f.threshold,
                     *f.threshold_ci, f.slope, *f.slope_ci, f.lapse, *f.lapse_ci, f.pse, f.jnd, *f.jnd_ci, f.weber,
                     *f.weber_ci, f.deviance, f.deviance_p_bootstrap, f.deviance_p_chi2])
        if reference_physical is not None:
            ph = physical_summary(f, reference_physical)
            rows[-1] += [ph["threshold_physical"], ph["jnd_physical"],
                         math.nan if ph["weber_physical"] is None else ph["weber_physical"]]
    if reference_physical is not None:
        header += ["threshold_physical", "jnd_physical", "weber_physical"]
    return header, rows


@dataclass(frozen=True)
class Proportion:
    """Proportion correct of one group of real-vs-virtual 2AFC trials ("which was real?"), against chance."""

    subject: str
    condition: str
    n_trials: int
    n_correct: int
    proportion: float
    ci_low: float
    ci_high: float
    p_vs_chance: float


def proportions_correct(trials: Trials, chance: float = 0.5, ci_level: float = 0.95) -> list[Proportion]:
    """Proportion correct per condition (rendering), pooled and per subject, with its interval and a test.

    The interval is Clopper-Pearson's exact binomial interval; the test is the exact two-sided binomial
    test of the proportion against ``chance`` (scipy.stats.binomtest): a rendering that people cannot tell
    from the real sample gives about 0.5; one they always tell apart, 1.0.

    Parameters
    ----------
    trials : Trials
        Real-vs-virtual 2AFC trials (catch trials left out).
    chance : float
        The proportion correct of guessing (0.5 for two intervals).
    ci_level : float

    Returns
    -------
    list of Proportion
        Each condition pooled over subjects first, then each subject x condition (with more than one subject).
    """
    keep = ~trials.is_catch
    subjects = sorted(set(trials.subject[keep]))
    conditions = sorted(set(trials.condition[keep]))
    groups = [(POOLED, c, keep & (trials.condition == c)) for c in conditions]
    if len(subjects) > 1:
        groups += [(s, c, keep & (trials.subject == s) & (trials.condition == c)) for c in conditions for s in subjects]
    out = []
    for subject, condition, mask in groups:
        n = int(mask.sum())
        if n == 0:
            continue
        k = int(trials.correct[mask].sum())
        test = binomtest(k, n, chance)
        ci = test.proportion_ci(confidence_level=ci_level, method="exact")
        out.append(Proportion(subject, condition, n, k, k / n, float(ci.low), float(ci.high), float(test.pvalue)))
    return out
