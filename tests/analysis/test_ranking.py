"""Figure 4.17's ordering and section 4.5.4's saturation counts checked on a study's data (analysis/ranking.py)."""

import math

import numpy as np
import pandas as pd
import pytest

from analysis.ranking import figure_4_17_checks, ranking_lines

SAMPLES = ["wood", "hfam_wood", "pulse_firm", "foam", "prop_soft", "prop_firm"]
MEANS = [6.1, 5.4, 4.9, 3.0, 3.4, 2.6]


def _trials(counts):
    """Testing attempts with ``counts[subject][sample]`` saturated ones each, plus one unsaturated testing
    attempt per subject and sample, and familiarization attempts (saturated: not counted)."""
    rows = []
    for subject, by_sample in counts.items():
        for sample in SAMPLES:
            rows += [(subject, "testing", sample, True)] * by_sample.get(sample, 0)
            rows.append((subject, "testing", sample, False))
            rows.append((subject, "familiarization", sample, True))
    return pd.DataFrame(rows, columns=["subject", "phase", "sample", "saturated"]).assign(note="x" * 50)


def test_the_four_checks_and_every_subjects_count_of_saturations():
    summary = pd.DataFrame({"sample": SAMPLES, "mean_rating": MEANS})
    counts = {"S01": {"wood": 4, "hfam_wood": 3}, "S02": {}, "S03": {"pulse_firm": 5, "foam": 1},
              "S04": {"wood": 2, "prop_soft": 2}}
    out = figure_4_17_checks(summary, _trials(counts))
    assert [s for s, _ in out["order"]] == ["wood", "hfam_wood", "pulse_firm", "prop_soft", "foam", "prop_firm"]
    assert out["real_wood_first"]["met"] and out["hfam_first_virtual"]["met"]
    assert out["proportional_near_foam"]["met"]              # 3.4 and 2.6 within 1 of 3.0, below 4.9
    per = np.array([7.0, 0.0, 6.0, 4.0])                        # S02 saturated nothing: it counts, as 0
    m, sd, n = out["saturations_per_subject"]
    assert n == 4 and m == pytest.approx(per.mean()) and sd == pytest.approx(per.std(ddof=1))
    assert out["saturations_by_sample"] == {"wood": 6, "pulse_firm": 5, "hfam_wood": 3, "prop_soft": 2, "foam": 1}
    # mean 4.25 inside 6 +/- 4.25; on wood and the event-based samples 14 of 17
    assert out["saturations"]["met"] and "82%" in out["saturations"]["text"]
    lines = ranking_lines(out)
    assert lines[0].startswith("**Ranking** (mean ratings, best first): wood 6.10, hfam_wood 5.40")
    assert sum(line.startswith("**Met**") for line in lines) == 4


def test_a_study_without_saturations_and_a_proportional_wall_above_an_event():
    summary = pd.DataFrame({"sample": SAMPLES, "mean_rating": [5.0, 5.5, 3.3, 3.0, 3.6, 2.6]})
    out = figure_4_17_checks(summary, _trials({"S01": {}, "S02": {}}))
    assert not out["real_wood_first"]["met"] and out["hfam_first_virtual"]["met"]
    assert not out["proportional_near_foam"]["met"]           # prop_soft 3.6 above pulse_firm 3.3
    assert out["saturations_per_subject"] == (0.0, 0.0, 2) and out["saturations_by_sample"] == {}
    assert not out["saturations"]["met"] and "nan%" in out["saturations"]["text"]
    assert math.isnan(figure_4_17_checks(summary, _trials({"S01": {}}))["saturations_per_subject"][1])
