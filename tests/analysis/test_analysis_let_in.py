"""Issue 38, item 11 (analysis): an impossible velocity or penetration in a trials file is refused naming the file
and line (before: inf, nan and negative values flowed into sample_summary.csv), and names from the data are
escaped in report.md (before: a sample name could add markup, links, tags or table cells)."""

from __future__ import annotations

import re
import warnings

import pytest

from analysis.load import load_study
from analysis.pipeline import analyse
from analysis.report import md_escape, write_report
from analysis.synthetic import DEFAULT_SAMPLES, SyntheticSample, write_synthetic_study

COLUMNS = ("subject,phase,trial,attempt,sample,kind,rating,rejected,saturated,overpowered,valid,n_taps,"
           "incoming_velocity_mean_m_s,penetration_mean_m,incoming_velocities_m_s,penetration_depths_m,"
           "started_at,duration_s").split(",")


@pytest.fixture(scope="module")
def small_study(tmp_path_factory):
    root = tmp_path_factory.mktemp("let_in")
    write_synthetic_study(root, 3, seed=2)
    return root


def _damage(root, column: str, value: str):
    """Set ``column`` of S002's first testing row with taps to ``value``; returns (file, 1-based line)."""
    path = root / "S002" / "trials.csv"
    lines = path.read_text().splitlines(keepends=True)
    j = COLUMNS.index(column)
    for i, ln in enumerate(lines):
        cells = ln.rstrip("\n").split(",")
        if cells[1] == "testing" and cells[11] not in ("", "0"):
            cells[j] = value
            lines[i] = ",".join(cells) + "\n"
            path.write_text("".join(lines))
            return path, i + 1
    raise AssertionError("no testing row with taps")


@pytest.mark.parametrize("column, value, shown", [
    ("incoming_velocities_m_s", "inf", "inf"),
    ("incoming_velocities_m_s", "nan", "nan"),
    ("incoming_velocities_m_s", "-0.1", "-0.1"),
    ("penetration_depths_m", "-0.002", "-0.002"),
    ("penetration_depths_m", "nan", "nan"),
    ("incoming_velocity_mean_m_s", "inf", "inf"),
    ("penetration_mean_m", "-0.001", "-0.001"),
    ("duration_s", "-inf", "-inf"),
])
def test_impossible_velocities_and_penetrations_are_refused_with_file_and_line(small_study, tmp_path, column, value,
                                                                                shown):
    import shutil

    root = tmp_path / "study"
    shutil.copytree(small_study, root)
    path, line = _damage(root, column, value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError) as err:
            load_study(root)
    text = str(err.value)
    assert text.startswith(f"{path}:{line}: column {column!r}: value "), text
    assert shown in text and "finite number >= 0" in text


def test_a_plain_study_still_loads(small_study):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert len(load_study(small_study).trials) > 0


EVIL = "x|y*z*<script>alert(1)</script>[a](http://e.example)_"


def test_names_from_the_data_are_escaped_in_report_md(tmp_path):
    samples = list(DEFAULT_SAMPLES[:4])
    samples[2] = SyntheticSample(EVIL, "real", 6.0, 0.1e-3, 300.0, 900.0)  # rated like wood: in the summary
    root = tmp_path / "study"
    write_synthetic_study(root, 6, seed=4, samples=samples, p_invalid=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = analyse(root)
        written = write_report(res, tmp_path / "report", figures=False)
    md = written["md"].read_text(encoding="utf-8")
    assert EVIL not in md and "<script>" not in md
    assert not re.search(r"(?<!\\)\]\(http", md)  # no live link
    assert md_escape(EVIL) in md
    assert md_escape(EVIL) == r"x\|y\*z\*\<script\>alert(1)\</script\>\[a\](http://e.example)\_"
    # every markdown table row has as many cell separators as its header
    for block in re.findall(r"(?:^\|.*\|\n)+", md, flags=re.M):
        rows = block.splitlines()
        cells = [len(re.findall(r"(?<!\\)\|", r)) for r in rows]
        assert len(set(cells)) == 1, rows[:3]
    html = written["html"].read_text(encoding="utf-8")
    assert "<script>alert" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
