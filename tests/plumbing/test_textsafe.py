"""Names from users written to CSV and Markdown: a cell a spreadsheet would run as a formula gets a quote first
(and is read back as named), a number stays a number, Markdown markup is shown, not applied."""

import csv
import io

import pandas as pd
import pytest

from plumbing.textsafe import csv_cell, csv_header, csv_text, md_escape, read_cell, safe_frame

EVIL = ["=cmd|' /C calc'!A0", "+SUM(A1:A9)", "-2+3", "@SUM(1)", "\t=1", "\r=1", "'quoted", "''two"]


@pytest.mark.parametrize("text", EVIL)
def test_a_formula_cell_is_quoted_and_read_back_as_written(text):
    cell = csv_text(text)
    assert cell == "'" + text
    assert read_cell(cell) == text


@pytest.mark.parametrize("text", ["S01", "wood", "-0.5", "+1e3", "1.5E-3", "nan", "-inf", "", "a=b", "x-1"])
def test_plain_names_and_numbers_are_unchanged(text):
    assert csv_text(text) == text
    assert read_cell(csv_text(text)) == text


def test_cells_rows_headers_and_frames():
    assert csv_cell(-0.5) == -0.5 and csv_cell(None) is None and csv_cell("=1+1") == "'=1+1"
    assert csv_header(["=a", "b"]) == ["'=a", "b"]
    frame = pd.DataFrame({"subject": ["=HYPERLINK(1)", "S02"], "x": [-1.0, 2.0], "=col": ["@a", "b"]})
    safe = safe_frame(frame)
    assert list(safe.columns) == ["subject", "x", "'=col"]
    assert list(safe["subject"]) == ["'=HYPERLINK(1)", "S02"] and list(safe["'=col"]) == ["'@a", "b"]
    assert list(safe["x"]) == [-1.0, 2.0]
    assert list(frame["subject"]) == ["=HYPERLINK(1)", "S02"]          # the caller's frame untouched
    text = safe.to_csv(index=False)
    rows = list(csv.reader(io.StringIO(text)))
    assert all(not c or c[0] not in "=+@" for r in rows for c in r)   # no cell a spreadsheet runs
    assert rows[1][1] == "-1.0"                                        # a number stays a number


def test_markdown_markup_is_escaped():
    assert md_escape("<script>alert(1)</script>") == r"\<script\>alert(1)\</script\>"
    assert md_escape("a|b *c* [l](u) `x` #h") == r"a\|b \*c\* \[l\](u) \`x\` \#h"
    assert md_escape("two\nlines") == "two lines"
    assert md_escape("snake_case _lead") == r"snake_case \_lead"
