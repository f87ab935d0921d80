"""Forced-choice and staircase data: reading them (a study folder or a plain CSV) and fitting them per group.

Two inputs (docs/analysis.md, "Psychometric fits"):

* a study folder of psychophysics sessions: ``DATA/<subject>/session.json`` with an ``experiment``
  entry (kind, alternatives, method, intensity scale, reference) and ``trials.csv`` with at least the
  columns ``intensity`` and ``correct`` (and ``condition``, ``staircase``, ``trial``, ``is_catch``);
  ``DATA`` may also be one subject's folder;
* a plain CSV from any software: columns ``intensity`` and ``correct`` (0/1), optional ``subject``,
  ``condition``, ``is_catch``, ``trial``, ``staircase``.

Catch trials (``is_catch = 1``) are kept for the staircase figure and left out of every fit; a catch
trial of a log10 session has no intensity (an empty cell). Each bad cell is one ``ValueError`` naming the
file and line. Sessions are pooled only when they are the same measurement (:data:`MEASUREMENT_FIELDS`):
:func:`measurements` groups them, :func:`check_poolable` refuses a mixture, naming the sessions and the
field.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from plumbing.studyfiles import FIT_COLUMNS, FIT_OPTIONAL_COLUMNS, SESSION_JSON, read_session_json
from plumbing.textsafe import read_cell
from psychophysics.bayes import fit_bayes
from psychophysics.fitting import Fit, fit, fit_multiple, compare_models
from psychophysics.psychometric import base_quantile, from_axis
from psychophysics.sdt import dprime

#: the columns a fit reads (plumbing.studyfiles: the forced-choice trials.csv holds them all)
REQUIRED, OPTIONAL = FIT_COLUMNS, FIT_OPTIONAL_COLUMNS
POOLED = "(pooled)"
ALL = "(all)"
#: what must be equal for sessions to be one measurement: the experiment's keys, then its config's
MEASUREMENT_FIELDS = ("kind", "alternatives", "guess_rate", "intensity_scale", "intensity_unit", "reference")
MEASUREMENT_CONFIG_FIELDS = ("vary", "sample", "real_sample", "renderings")


@dataclass(frozen=True)
class Trials:
    """Trial-by-trial forced-choice data, one entry per trial (arrays of equal length T).

    ``experiment`` is the ``experiment`` entry of the sessions' ``session.json`` (the first subject's;
    empty for a plain CSV); ``sources`` names the files read; ``session`` is each trial's session (the
    index into ``sessions``, whose entries are ``(session.json path, experiment)``; one empty entry for a
    plain CSV).
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
    session: np.ndarray | None = None
    sessions: tuple = ()

    def __len__(self) -> int:
        return len(self.intensity)

    def subset(self, mask) -> "Trials":
        """The trials where ``mask`` holds (the first chosen session's experiment becomes ``experiment``)."""
        mask = np.asarray(mask, dtype=bool)
        sess = self.session[mask] if self.session is not None else None
        exp = self.experiment
        if sess is not None and len(sess) and self.sessions:
            exp = self.sessions[int(sess[0])][1]
        return Trials(subject=self.subject[mask], condition=self.condition[mask], staircase=self.staircase[mask],
                      trial=self.trial[mask], intensity=self.intensity[mask], correct=self.correct[mask],
                      is_catch=self.is_catch[mask], experiment=exp, sources=self.sources, session=sess,
                      sessions=self.sessions)


def _zero_one(text: str, path: Path, line: int, column: str) -> int:
    if text.strip() in ("0", "1"):
        return int(text)
    raise ValueError(f"{path}:{line}: {column} must be 0 or 1, got {text!r}")


def _read_csv(path: Path, subject_default: str) -> dict:
    """Columns of one trials CSV, validated cell by cell (streamed: the file is never held twice)."""
    cols = {name: [] for name in REQUIRED + OPTIONAL}
    try:
        # utf-8-sig: a spreadsheet's "CSV UTF-8" export starts with a byte-order mark, which would otherwise
        # be part of the first column's name
        fh = path.open(newline="", encoding="utf-8-sig")
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
        except csv.Error as exc:   # e.g. a 50 MB first line: one error line, not a traceback
            raise ValueError(f"{path}:1: not CSV ({exc})") from None
        header = [h.strip() for h in header]
        twice = sorted({h for h in header if header.count(h) > 1 and h})
        if twice:
            raise ValueError(f"{path}:1: column(s) {', '.join(twice)} appear more than once in the header; keep one "
                             "of each")
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            hint = ""
            if len(header) == 1 and any(sep in header[0] for sep in ";\t"):
                sep = "';'" if ";" in header[0] else "a tab"
                hint = (f"; the header is one field holding {sep}: the file is separated by {sep}, not commas "
                        "(a spreadsheet's regional CSV export): save it as CSV with commas")
            raise ValueError(f"{path}:1: missing column(s) {', '.join(missing)} (a psychometric fit needs "
                             f"intensity and correct, 0/1){hint}")
        where = {name: header.index(name) for name in REQUIRED + OPTIONAL if name in header}
        try:
            for line, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise ValueError(f"{path}:{line}: {len(row)} fields, the header has {len(header)}")
                catch = _zero_one(row[where["is_catch"]], path, line, "is_catch") if "is_catch" in where else 0
                text = row[where["intensity"]]
                if catch and not text.strip():
                    x = math.nan        # a catch trial of a log10 session: a blank has no log10 intensity
                else:
                    try:
                        x = float(text)
                    except ValueError:
                        raise ValueError(f"{path}:{line}: intensity must be a number, got {text!r}") from None
                    if not math.isfinite(x):
                        raise ValueError(f"{path}:{line}: intensity must be finite, got {text!r}")
                cols["intensity"].append(x)
                cols["correct"].append(_zero_one(row[where["correct"]], path, line, "correct"))
                cols["is_catch"].append(catch)
                # names as written, without the quote that kept a formula-like name from running in a spreadsheet
                cols["subject"].append(read_cell(row[where["subject"]]) if "subject" in where else subject_default)
                cols["condition"].append(read_cell(row[where["condition"]]) if "condition" in where else "")
                cols["staircase"].append(read_cell(row[where["staircase"]]) if "staircase" in where else "")
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
    chunks, sources, experiment, sessions = [], [], {}, []
    if path.is_file():
        chunks.append(_read_csv(path, ""))
        sources.append(str(path))
        sessions.append(("", {}))
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
            sessions.append((str(folder / SESSION_JSON), exp))
        if not chunks:
            extra = (f" ({len(skipped)} rating session(s) without an 'experiment' entry: analyse those with "
                     "'analysis report')") if skipped else ""
            raise ValueError(f"{path}: no psychophysics session with trials found{extra}")
    cols = {k: [v for c in chunks for v in c[k]] for k in REQUIRED + OPTIONAL}
    if not cols["intensity"]:
        raise ValueError(f"{', '.join(sources)}: no trials")
    session = np.concatenate([np.full(len(c["intensity"]), i, dtype=np.int64) for i, c in enumerate(chunks)])
    return Trials(subject=np.array(cols["subject"], dtype=object), condition=np.array(cols["condition"], dtype=object),
                  staircase=np.array(cols["staircase"], dtype=object), trial=np.array(cols["trial"], dtype=np.int64),
                  intensity=np.array(cols["intensity"], dtype=float), correct=np.array(cols["correct"], dtype=np.int8),
                  is_catch=np.array(cols["is_catch"], dtype=bool), experiment=experiment, sources=tuple(sources),
                  session=session, sessions=tuple(sessions))


def _measurement_key(exp: dict) -> tuple:
    config = exp.get("config") if isinstance(exp.get("config"), dict) else {}
    return tuple(("experiment." + f, _hashable(exp.get(f))) for f in MEASUREMENT_FIELDS) + tuple(
        ("experiment.config." + f, _hashable(config.get(f))) for f in MEASUREMENT_CONFIG_FIELDS)


def _hashable(v):
    return tuple(v) if isinstance(v, list) else v


@dataclass(frozen=True)
class Measurement:
    """Sessions that are one measurement: the same task, stimulus, scale, unit and reference."""

    index: int
    sessions: tuple       # session.json paths
    experiment: dict
    mask: np.ndarray      # the trials of these sessions


def measurements(trials: Trials) -> list[Measurement]:
    """The sessions grouped by measurement (:data:`MEASUREMENT_FIELDS`), in the order first met."""
    if trials.session is None or len(trials.sessions) <= 1:
        return [Measurement(1, tuple(p for p, _ in trials.sessions), trials.experiment,
                            np.ones(len(trials), dtype=bool))]
    groups: dict = {}
    for i, (path, exp) in enumerate(trials.sessions):
        groups.setdefault(_measurement_key(exp), []).append(i)
    out = []
    for j, idx in enumerate(groups.values(), start=1):
        out.append(Measurement(j, tuple(trials.sessions[i][0] for i in idx), trials.sessions[idx[0]][1],
                               np.isin(trials.session, idx)))
    return out


def check_poolable(trials: Trials) -> None:
    """Refuse sessions that are not one measurement, naming two of them and the field that differs.

    Raises
    ------
    ValueError
        ``"<session.json>: experiment.<field> <value> differs from <value> in <session.json>; ..."``.
    """
    groups = measurements(trials)
    if len(groups) <= 1:
        return
    first, other = groups[0], groups[1]
    for (name, a), (_, b) in zip(_measurement_key(first.experiment), _measurement_key(other.experiment)):
        if a != b:
            raise ValueError(f"{other.sessions[0]}: {name} {b!r} differs from {a!r} in {first.sessions[0]}: these "
                             f"sessions are not the same measurement ({len(groups)} different ones among "
                             f"{len(trials.sessions)} sessions) and are not pooled; fit each on its own with "
                             "--separately")


@dataclass(frozen=True)
class GroupFit:
    """The fit of one group of trials: a subject in a condition, or all subjects pooled."""

    subject: str
    condition: str
    fit: Fit


@dataclass(frozen=True)
class FitOptions:
    """How :func:`fit_groups` fits (the command's flags)."""

    alternatives: int
    function: str = "logistic"
    lapse: float | None = None
    bootstrap: int = 1000
    ci_level: float = 0.95
    reference: float | None = None
    seed: int = 0
    lower_asymptote: str = "fixed"
    bayesian: bool = False


def _fit_one(intensity, correct, o: FitOptions):
    if o.bayesian:
        return fit_bayes(intensity, correct, alternatives=o.alternatives, function=o.function,
                         lower_asymptote=o.lower_asymptote, lapse=o.lapse, ci_level=o.ci_level, reference=o.reference)
    return fit(intensity, correct, alternatives=o.alternatives, function=o.function, lapse=o.lapse,
               bootstrap=o.bootstrap, ci_level=o.ci_level, reference=o.reference, seed=o.seed,
               lower_asymptote=o.lower_asymptote)


def fit_groups(trials: Trials, alternatives, function: str = "logistic", lapse=None, bootstrap: int = 1000,
               ci_level: float = 0.95, reference=None, seed: int = 0, equal_asymptote: bool = False,
               options: FitOptions | None = None) -> list[GroupFit]:
    """Fit every (subject, condition) group, each condition pooled over subjects, and all trials pooled.

    Parameters
    ----------
    trials : Trials
    alternatives, function, lapse, bootstrap, ci_level, reference, seed, equal_asymptote
        As for :func:`psychophysics.fitting.fit` (ignored when ``options`` is given).
    options : FitOptions, optional
        Every option at once (the lower asymptote, a Bayesian fit).

    Returns
    -------
    list of GroupFit
        Pooled over everything first (subject and condition :data:`POOLED`/:data:`ALL`), then each
        condition pooled, then each subject x condition (groups with fewer than two intensities are
        reported as errors).
    """
    o = options or FitOptions(alternatives, function, lapse, bootstrap, ci_level, reference, seed,
                              "equal" if equal_asymptote else "fixed")
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
            f = _fit_one(trials.intensity[mask], trials.correct[mask], FitOptions(**{**o.__dict__, "seed": o.seed + i}))
        except ValueError as exc:
            who = f"subject {subject!r}, condition {condition!r}"
            raise ValueError(f"{who}: {exc}") from None
        out.append(GroupFit(subject, condition, f))
    return out


def compare_conditions(trials: Trials, o: FitOptions, subject: str = POOLED) -> dict | None:
    """Conditions fitted together with a shared slope and lapse rate (Palamedes' ``PAL_PFML_FitMultiple``) and
    two likelihood-ratio tests (``PAL_PFLR_ModelComparison``): do the thresholds differ (one threshold for all
    against one per condition), and does sharing the slope fit (one slope against one per condition)?

    Returns
    -------
    dict or None
        ``shared`` (the fit), ``thresholds_differ`` and ``slopes_differ`` (the tests); None with fewer than two
        conditions.
    """
    keep = ~trials.is_catch
    if subject != POOLED:
        keep &= trials.subject == subject
    conditions = sorted(set(trials.condition[keep]))
    if len(conditions) < 2:
        return None
    data = []
    for c in conditions:
        mask = keep & (trials.condition == c)
        data.append(_counts(trials.intensity[mask], trials.correct[mask]))
    common = dict(alternatives=o.alternatives, function=o.function, lapse=o.lapse, lower_asymptote=o.lower_asymptote,
                  names=conditions)
    shared = fit_multiple(data, ci_level=o.ci_level, **common)
    boot = min(o.bootstrap, 1000)
    thresholds = compare_models(data, {"thresholds": "constrained"}, {"thresholds": "unconstrained"},
                                bootstrap=boot, seed=o.seed, **common)
    slopes = compare_models(data, {"thresholds": "unconstrained"},
                            {"thresholds": "unconstrained", "slopes": "unconstrained"},
                            bootstrap=boot, seed=o.seed + 1, **common)
    return {"subject": subject, "shared": shared, "thresholds_differ": thresholds, "slopes_differ": slopes}


def _counts(intensity, correct):
    levels, inverse = np.unique(intensity, return_inverse=True)
    n = np.bincount(inverse, minlength=len(levels)).astype(float)
    k = np.bincount(inverse, weights=correct, minlength=len(levels))
    return levels, n, k


def dprime_table(trials: Trials) -> list[dict]:
    """d' and criterion per subject, condition and level of a yes/no task with catch trials (blanks): each
    level's "yes" rate against the catch trials' of the same subject and condition (:func:`psychophysics.sdt.dprime`,
    log-linear correction); empty without catch trials."""
    out = []
    for subject in sorted(set(trials.subject)):
        for condition in sorted(set(trials.condition)):
            sel = (trials.subject == subject) & (trials.condition == condition)
            noise = sel & trials.is_catch
            signal = sel & ~trials.is_catch
            if not noise.any() or not signal.any():
                continue
            f, nn = float(trials.correct[noise].sum()), float(noise.sum())
            levels, n, k = _counts(trials.intensity[signal], trials.correct[signal])
            r = dprime(k, n, f, nn)
            for i, level in enumerate(levels):
                out.append({"subject": subject, "condition": condition, "intensity": float(level),
                            "n_signal": int(n[i]), "hits": int(k[i]), "n_catch": int(nn), "false_alarms": int(f),
                            "hit_rate": float(r["hit_rate"][i]), "false_alarm_rate": float(r["false_alarm_rate"]),
                            "dprime": float(r["dprime"][i]), "criterion": float(r["criterion"][i])})
    return out


def physical_summary(f, reference=None) -> dict:
    """Threshold, PSE, JND and Weber fraction in physical units, with intervals, of a fit on a log10 axis.

    Parameters
    ----------
    f : Fit or BayesFit
        Fitted on ``log10`` of the physical stimulus (a session with ``intensity_scale = "log10"``).
    reference : float, optional
        The reference stimulus in physical units.

    Returns
    -------
    dict
        ``threshold_physical`` (= 10**threshold) and ``threshold_ci_physical`` (the threshold's interval, mapped:
        exact); ``pse_physical`` (yes/no) with its interval; ``jnd_physical``: ``10**x(F=0.75) - 10**x(F=0.5)``
        for a yes/no task (interval from the bootstrap or the posterior), ``10**threshold - reference`` for an
        n-AFC task (interval mapped from the threshold's); ``weber_physical`` = ``jnd_physical / reference``
        with its interval; None where undefined.
    """
    thr = 10.0 ** f.threshold
    lo, hi = f.threshold_ci
    tci = [10.0 ** lo if not math.isnan(lo) else None, 10.0 ** hi if not math.isnan(hi) else None]
    has_ref = reference is not None and math.isfinite(reference) and reference > 0
    q75 = float(base_quantile(0.75, f.function))
    if f.alternatives == 1:
        jnd = 10.0 ** (f.threshold + q75 / f.slope) - thr

        def jnd_of(t, beta, lam, gam):
            u = from_axis(t, f.function)
            return 10.0 ** from_axis(t + q75 / beta, f.function) - 10.0 ** u

        jci = list(f.interval_of(jnd_of))
    elif has_ref:
        jnd = thr - reference
        jci = [None if v is None else v - reference for v in tci]
    else:
        jnd, jci = None, [None, None]
    jci = [None if v is None or not math.isfinite(v) else float(v) for v in jci]
    weber = wci = None
    if has_ref and jnd is not None:
        weber = jnd / reference
        wci = [None if v is None else v / reference for v in jci]
    yes_no = f.alternatives == 1
    return {"threshold_physical": thr, "threshold_ci_physical": tci,
            "pse_physical": thr if yes_no else None, "pse_ci_physical": tci if yes_no else [None, None],
            "jnd_physical": jnd, "jnd_ci_physical": jci, "weber_physical": weber,
            "weber_ci_physical": wci if wci is not None else [None, None], "reference_physical": reference}


def _ci(f, name):
    return tuple(getattr(f, name, (math.nan, math.nan)))


def fits_table(fits: list[GroupFit], reference_physical=None, physical: bool = False, threshold_pcs=(),
               measurement: int | None = None) -> tuple[list[str], list[list]]:
    """``fits.csv``'s header and rows: one row per group, intervals as ``*_ci_low``/``*_ci_high``.

    With ``physical`` (a fit on a log10 axis), the physical threshold, PSE, JND and Weber fraction with their
    intervals (:func:`physical_summary`) follow; ``threshold_pcs`` adds the threshold at each proportion
    (psignifit's ``threshold(pc)``) with its interval; ``flags`` holds the fit's flags (``;``-joined names);
    ``measurement`` (with ``--separately``) numbers the measurement the row belongs to.
    """
    header = (["measurement"] if measurement is not None else []) + [
        "subject", "condition", "function", "alternatives", "lower_asymptote", "n_trials", "n_levels", "threshold",
        "threshold_ci_low", "threshold_ci_high", "threshold_ci_bca_low", "threshold_ci_bca_high", "slope",
        "slope_ci_low", "slope_ci_high", "slope_at_threshold", "lapse", "lapse_ci_low", "lapse_ci_high", "guess",
        "guess_ci_low", "guess_ci_high", "eta", "pse", "pse_ci_low", "pse_ci_high", "jnd", "jnd_ci_low",
        "jnd_ci_high", "weber", "weber_ci_low", "weber_ci_high", "deviance", "deviance_p_bootstrap",
        "deviance_p_chi2", "flags"]
    for pc in threshold_pcs:
        header += [f"threshold_at_{pc:g}", f"threshold_at_{pc:g}_ci_low", f"threshold_at_{pc:g}_ci_high"]
    if physical:
        header += ["threshold_physical", "threshold_physical_ci_low", "threshold_physical_ci_high", "pse_physical",
                   "pse_physical_ci_low", "pse_physical_ci_high", "jnd_physical", "jnd_physical_ci_low",
                   "jnd_physical_ci_high", "weber_physical", "weber_physical_ci_low", "weber_physical_ci_high"]
    rows = []
    for g in fits:
        f = g.fit
        row = ([measurement] if measurement is not None else []) + [
            g.subject, g.condition, f.function, f.alternatives, f.lower_asymptote, f.n_trials, f.n_levels,
            f.threshold, *f.threshold_ci, *_ci(f, "threshold_ci_bca"), f.slope, *f.slope_ci, f.slope_at_threshold,
            f.lapse, *f.lapse_ci, f.guess, *f.guess_ci, getattr(f, "eta", math.nan), f.pse, *f.pse_ci, f.jnd,
            *f.jnd_ci, f.weber, *f.weber_ci, f.deviance, f.deviance_p_bootstrap, f.deviance_p_chi2,
            ";".join(flag.name for flag in f.flags)]
        for pc in threshold_pcs:
            try:
                t = f.threshold_at(pc)
                row += [t["threshold"], *t["ci"]]
            except ValueError:
                row += [math.nan, math.nan, math.nan]
        if physical:
            ph = physical_summary(f, reference_physical)
            for key in ("threshold", "pse", "jnd", "weber"):
                v = ph[f"{key}_physical"]
                row += [math.nan if v is None else v,
                        *[math.nan if c is None else c for c in ph[f"{key}_ci_physical"]]]
        rows.append(row)
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
