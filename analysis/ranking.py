"""Figure 4.17's ordering and section 4.5.4's saturation counts, checked on a study's data (thesis 4.5.4, 4.5.5).

Three sentences of the thesis about the ranking and one about the saturations, each a yes/no on the study's mean
ratings (over subjects, ``sample_summary``) and its testing-phase attempts:

* "the most highly rated sample was real wood" -- ``real_wood_first``: the real ``wood`` has the highest mean;
* "the six transient-overlaid virtual surfaces, with acceleration matching rated most highly" --
  ``hfam_first_virtual``: the best-rated virtual sample is an HFAM one;
* "The ratings given to the three proportional controllers were comparable to those assigned to foam,
  significantly lower than those given to the event-based samples" -- ``proportional_near_foam``: every
  proportional wall within :data:`NEAR_FOAM_POINTS` rating points of the foam and below every event-based sample;
* "Users exceeded the system's force capability an average of six times during the testing phase, with a standard
  deviation of 8.5. Saturations occurred most frequently for the real wood and the event-based virtual samples"
  -- ``saturations``: the mean count per subject within the 95 % interval of the thesis's mean (6 +/- 2 x 8.5 /
  sqrt(16)), and more than half of the saturations on the real wood and the event-based samples.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: "comparable": within one rating point (of the 1-7 scale) of the foam
NEAR_FOAM_POINTS = 1.0
#: section 4.5.4: saturations per subject, mean and standard deviation over the sixteen subjects
THESIS_SATURATIONS = (6.0, 8.5, 16)
#: the catalog's names of the samples the sentences name
WOOD, FOAM = "wood", "foam"


def _kind(name: str) -> str:
    """``hfam``, ``event`` (pulse, sinusoid), ``proportional`` or ``real`` by the catalog's names."""
    if name in (WOOD, FOAM, "wood_on_foam"):
        return "real"
    if name.startswith("hfam"):
        return "hfam"
    if name.startswith(("pulse", "sinusoid")):
        return "event"
    return "proportional"


def figure_4_17_checks(summary: pd.DataFrame, trials: pd.DataFrame, name=str) -> dict:
    """The four checks of the module doc on a study's ``sample_summary`` and its trials.

    Parameters
    ----------
    summary : DataFrame
        ``sample``, ``mean_rating`` (mean over subjects' means).
    trials : DataFrame
        Every attempt: ``subject``, ``phase``, ``sample``, ``saturated``.
    name : callable
        How a sample name from the data is written into the texts (the report marks names for escaping).

    Returns
    -------
    dict
        ``order`` (samples best first, with their means), the four checks (``real_wood_first``,
        ``hfam_first_virtual``, ``proportional_near_foam``, ``saturations``: each ``{"met": bool, "text": str}``),
        and ``saturations_per_subject`` (mean, SD, n), ``saturations_by_sample``.
    """
    means = dict(zip(summary["sample"], summary["mean_rating"].astype(float)))
    order = sorted(means, key=lambda s: -means[s])
    virtual = [s for s in order if _kind(s) != "real"]
    prop = [s for s in order if _kind(s) == "proportional"]
    events = [s for s in order if _kind(s) in ("event", "hfam")]
    out = {"order": [(s, means[s]) for s in order]}
    out["real_wood_first"] = {"met": bool(order and order[0] == WOOD),
                              "text": f"highest mean: {name(order[0])} {means[order[0]]:.2f}" if order else "no ratings"}
    best_v = virtual[0] if virtual else None
    out["hfam_first_virtual"] = {"met": bool(best_v and _kind(best_v) == "hfam"),
                                 "text": f"best virtual sample: {name(best_v)} {means[best_v]:.2f}" if best_v else "none"}
    foam = means.get(FOAM, math.nan)
    near = bool(prop) and all(abs(means[s] - foam) <= NEAR_FOAM_POINTS for s in prop)
    below = bool(prop and events) and max(means[s] for s in prop) < min(means[s] for s in events)
    out["proportional_near_foam"] = {
        "met": near and below,
        "text": f"foam {foam:.2f}; proportional walls " + ", ".join(f"{name(s)} {means[s]:.2f}" for s in prop)
                + f"; lowest event-based {name(min(events, key=lambda s: means[s])) if events else '-'} "
                  f"{min((means[s] for s in events), default=math.nan):.2f}"}
    # the three columns used, not the whole table (its long text columns cost most of the copy)
    test = trials.loc[trials["phase"] == "testing", ["subject", "sample", "saturated"]]
    subjects = sorted(set(trials["subject"]))
    sat = test[test["saturated"].astype(bool)]
    # every subject's count at once (a subject without saturations counts 0): one pass, not one per subject
    per_subject = sat["subject"].value_counts().reindex(subjects, fill_value=0).to_numpy(dtype=float)
    by_sample = sat["sample"].value_counts().to_dict()
    mean_t, sd_t, n_t = THESIS_SATURATIONS
    half = 2.0 * sd_t / math.sqrt(n_t)
    share = (sum(v for s, v in by_sample.items() if s == WOOD or _kind(s) in ("event", "hfam")) / len(sat)
             if len(sat) else math.nan)
    m = float(per_subject.mean()) if per_subject.size else math.nan
    sd = float(per_subject.std(ddof=1)) if per_subject.size > 1 else math.nan
    out["saturations_per_subject"] = (m, sd, int(per_subject.size))
    out["saturations_by_sample"] = {str(k): int(v) for k, v in by_sample.items()}
    out["saturations"] = {
        "met": bool(mean_t - half <= m <= mean_t + half and share > 0.5),
        "text": f"{m:.1f} +/- {sd:.1f} per subject (n = {per_subject.size}; thesis 6 +/- 8.5, its mean's 95 % "
                f"interval {mean_t - half:.2f}-{mean_t + half:.2f}); on the real wood and event-based samples "
                f"{share:.0%}" + (" (" + ", ".join(f"{name(k)} {v}" for k, v in sorted(by_sample.items(),
                                                                                         key=lambda kv: -kv[1])) + ")"
                                   if by_sample else "")}
    return out


def ranking_lines(checks: dict, name=str) -> list[str]:
    """The report's summary lines for :func:`figure_4_17_checks` (markdown emphasis with ``**``; ``name`` marks a
    sample name from the data, as in :func:`figure_4_17_checks`)."""
    order = ", ".join(f"{name(s)} {m:.2f}" for s, m in checks["order"])
    lines = [f"**Ranking** (mean ratings, best first): {order}."]
    words = {"real_wood_first": "real wood rated highest (section 4.5.5)",
             "hfam_first_virtual": "HFAM first among the virtual samples (section 4.5.5)",
             "proportional_near_foam": f"proportional walls comparable to foam (within {NEAR_FOAM_POINTS:g} point) "
                                       "and below every event-based sample (section 4.5.5)",
             "saturations": "saturations: about six per subject, mostly real wood and event-based (section 4.5.4)"}
    for key, text in words.items():
        c = checks[key]
        lines.append(f"**{'Met' if c['met'] else 'Not met'}**: {text} -- {c['text']}.")
    return lines
