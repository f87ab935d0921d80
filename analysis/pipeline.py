"""Whole analysis of a study folder: load, validate, tables, exclusion warnings (no figures)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from analysis import models, stats
from analysis.failures import attempt
from analysis.config import DEFAULT_MARGIN, DEFAULT_REFERENCE, AnalysisConfig  # noqa: F401 (re-export)
from analysis.load import AnalysisWarning, Study, load_study

@dataclass(frozen=True)
class Analysis:
    """Every table of the report plus the warnings (each also raised as :class:`AnalysisWarning`)."""

    study: Study
    config: AnalysisConfig
    matrix: stats.RatingMatrix
    summary: pd.DataFrame
    pairwise: pd.DataFrame
    anova: pd.DataFrame
    equivalence: pd.DataFrame
    velocity: pd.DataFrame
    attempts: pd.DataFrame
    exclusions: pd.DataFrame
    warnings: tuple
    models: models.ModelResults | None = None   # mixed and ordinal models of every attempt
    #: the parts that could not be computed: ``{table attribute: [plain reasons]}`` (their tables are empty and
    #: the report says why in their sections; analysis.failures)
    failures: dict = field(default_factory=dict)


#: the columns of each table, for the empty table of a part that could not be computed
EMPTY_COLUMNS = {
    "summary": ("sample", "kind", "n_subjects", "n_attempts", "mean_rating", "median_rating", "sem_rating",
                "ci95_low_rating", "ci95_high_rating", "sd_rating_attempts", "n_taps", "penetration_mean_m",
                "penetration_sd_m", "incoming_velocity_mean_m_s", "incoming_velocity_sd_m_s"),
    "pairwise": stats.PAIRWISE_COLUMNS, "anova": stats.ANOVA_COLUMNS, "equivalence": stats.EQUIVALENCE_COLUMNS,
    "velocity": ("sample", "n_attempts", "n_subjects", "r", "p", "r_rm", "df_rm", "p_rm"),
    "attempts": ("subject", "attempts", "valid", "saturated", "rejected", "overpowered", "invalid_other"),
}


def _empty(attr: str) -> pd.DataFrame:
    return pd.DataFrame(columns=list(EMPTY_COLUMNS[attr]))


def _exclusion_table(matrix: stats.RatingMatrix, group_names) -> pd.DataFrame:
    miss = stats.missing_samples(matrix)
    exp = dict(zip(matrix.subjects, matrix.experience))
    rows = []
    for subject, samples in miss.items():
        in_groups = [g for g in group_names if g == "all" or exp[subject] != "none"]
        rows.append({"subject": subject, "experience": exp[subject], "missing_samples": ";".join(samples),
                     "excluded_from": "rm_anova, friedman, and pairwise/equivalence tests involving "
                                      + ", ".join(samples),
                     "groups": ";".join(in_groups)})
    return pd.DataFrame(rows, columns=["subject", "experience", "missing_samples", "excluded_from", "groups"])


def analyse(data_dir, config: AnalysisConfig | None = None, sessions: tuple | None = None,
            loaded=None) -> Analysis:
    """Run every table of the report on the study in ``data_dir``.

    Parameters
    ----------
    data_dir : path
        Study folder (see :func:`analysis.load.load_study`).
    config : AnalysisConfig or None
        Default: ``AnalysisConfig()``.
    sessions : tuple or None
        Its session files being read in another process (:func:`analysis.load.submit_sessions`).
    loaded : callable or None
        Called with the :class:`analysis.load.Study` once it is loaded and the configuration checked
        against it, before the tables: the report starts Figure 4.20 there, so that it is drawn while
        the statistics run.

    Raises ValueError/FileNotFoundError on bad input (see :func:`analysis.load.load_study`).
    """
    config = config or AnalysisConfig()
    study = load_study(Path(data_dir), sessions)
    messages = list(study.warnings)

    def warn(text):
        messages.append(text)
        warnings.warn(text, AnalysisWarning, stacklevel=2)

    if config.reference not in study.catalog:
        raise ValueError(f"--reference {config.reference!r} is not a sample of the catalog "
                         f"({', '.join(study.catalog)})")
    if loaded is not None:
        loaded(study)
    matrix = stats.rating_matrix(study)
    no_data = [s for s, c in zip(matrix.subjects, matrix.counts.sum(axis=1)) if c == 0]
    if no_data:
        warn(f"{len(no_data)} subject(s) have no valid testing attempt and are left out of every test: "
             + ", ".join(map(str, no_data)))
    selected = stats.groups(matrix, config.group)
    exclusions = _exclusion_table(matrix, list(selected))
    if len(exclusions):
        detail = "; ".join(f"{r.subject} ({r.missing_samples.replace(';', ', ')})" for r in exclusions.itertuples())
        warn(f"{len(exclusions)} subject(s) miss sample(s) and are excluded from the tests needing them "
             f"(RM-ANOVA/Friedman need every sample; pairwise and equivalence tests need both samples): {detail}")
    # every table is its own part: one that cannot be computed on these data is said (failures), the others are
    # still computed (analysis.failures)
    failures: dict = {}

    def part(attr, what, fn, *args):
        notes = []
        got = attempt(what, notes, fn, *args)
        if notes:
            failures.setdefault(attr, []).extend(notes)
            return _empty(attr) if attr in EMPTY_COLUMNS else None
        return got

    pair_tables, anova_tables, eq_tables = [], [], []
    for name, m in selected.items():
        if len(m.subjects) < 2:
            warn(f"group {name!r} has {len(m.subjects)} subject(s): its tests give no result (need 2 or more)")
        pair_tables.append(part("pairwise", f"paired t-tests ({name} subjects)", stats.pairwise_ttests, m, name))
        anova_tables.append(part("anova", f"RM-ANOVA and Friedman test ({name} subjects)", stats.omnibus, m, name))
        eq_tables.append(part("equivalence", f"equivalence tests ({name} subjects)", stats.equivalence, m, name,
                              config.reference, config.margin, config.alpha))
    pairwise = pd.concat(pair_tables, ignore_index=True) if any(len(t) for t in pair_tables) else _empty("pairwise")
    # the models use every subject (as the group 'all'); their directions are compared with its t-tests
    if config.models:
        all_pairs = pairwise[pairwise["group"] == "all"] if "all" in selected else \
            part("pairwise", "paired t-tests (all subjects, for the models)", stats.pairwise_ttests, matrix, "all")
        model_notes = []
        fitted = attempt("models", model_notes, models.fit_models, study, config.reference, all_pairs, config.alpha)
        if fitted is None:
            fitted = models.skipped(model_notes[0])
    else:
        fitted = models.skipped("models not requested (--no-models)")

    def joined(tables, attr):
        kept = [t for t in tables if len(t)]
        return pd.concat(kept, ignore_index=True) if kept else _empty(attr)

    return Analysis(
        study=study, config=config, matrix=matrix,
        summary=part("summary", "sample summary", stats.sample_summary, study, matrix),
        pairwise=pairwise, anova=joined(anova_tables, "anova"), equivalence=joined(eq_tables, "equivalence"),
        velocity=part("velocity", "velocity-rating correlations", stats.velocity_rating, study),
        attempts=part("attempts", "attempt counts", stats.attempt_counts, study), exclusions=exclusions,
        warnings=tuple(messages), models=fitted, failures=failures)


TABLE_FILES = {
    "sample_summary.csv": "summary", "pairwise_ttests.csv": "pairwise", "anova.csv": "anova",
    "equivalence.csv": "equivalence", "velocity_rating.csv": "velocity", "attempts.csv": "attempts",
    "exclusions.csv": "exclusions",
}


#: the models' tables: attribute of :class:`analysis.models.ModelResults` per file
MODEL_TABLE_FILES = {
    "models_fixed_effects.csv": "fixed", "models_emm.csv": "emm", "models_contrasts.csv": "contrasts",
    "models_ordinal_probabilities.csv": "probabilities",
}


def write_tables(result: Analysis, out_dir) -> list[Path]:
    """Write every table as CSV into ``out_dir`` (created); returns the paths.

    The models' tables are written (with their header only when a model was not fitted, so that a
    stale table of an earlier report never stands beside a new report).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for filename, attr in TABLE_FILES.items():
        path = out / filename
        getattr(result, attr).to_csv(path, index=False, float_format="%.6g")
        paths.append(path)
    fitted = result.models or models.skipped("models not run")
    for filename, attr in MODEL_TABLE_FILES.items():
        path = out / filename
        getattr(fitted, attr).to_csv(path, index=False, float_format="%.6g")
        paths.append(path)
    return paths
