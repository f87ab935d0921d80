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
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.psychometric import Fit, fit

REQUIRED = ("intensity", "correct")
OPTIONAL = ("subject", "condition", "staircase", "trial", "is_catch")
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


def _session(folder: Path) -> dict:
    path = folder / "session.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return data


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
            session = _session(folder)
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
               ci_level: float = 0.95, reference=None, seed: int = 0) -> list[GroupFit]:
    """Fit every (subject, condition) group, each condition pooled over subjects, and all trials pooled.

    Parameters
    ----------
    trials : Trials
    alternatives, function, lapse, bootstrap, ci_level, reference, seed
        As for :func:`analysis.psychometric.fit`.

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
                    lapse=lapse, bootstrap=bootstrap, ci_level=ci_level, reference=reference, seed=seed + i)
        except ValueError as exc:
            who = f"subject {subject!r}, condition {condition!r}"
            raise ValueError(f"{who}: {exc}") from None
        out.append(GroupFit(subject, condition, f))
    return out


def fits_table(fits: list[GroupFit]) -> tuple[list[str], list[list]]:
    """``fits.csv``'s header and rows: one row per group, intervals as ``*_ci_low``/``*_ci_high``."""
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
    return header, rows
