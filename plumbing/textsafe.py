"""Text from the data made safe in the files a command writes: CSV cells a spreadsheet cannot run, Markdown
that adds no markup.

Names come from users and their files (subject ids, catalog samples, conditions, staircase labels, the columns
of a CSV from other software) and end up in the CSV tables and Markdown reports the project writes.

* **CSV** (OWASP, "CSV Injection"): a spreadsheet runs a cell that begins with ``=``, ``+``, ``-`` or ``@``
  (and, in some programs, a tab or a carriage return) as a formula. :func:`csv_cell` writes such a *text* cell
  with a single quote before it (``=cmd|' /C calc'!A0`` -> ``'=cmd|' /C calc'!A0``), which spreadsheets show
  as text. Numbers are left alone: ``-0.5`` or ``+1e3`` written as numbers, or as text that is a plain decimal
  number, are numbers to every reader, not formulas. A text cell that itself begins with a quote gets one
  more, so that :func:`read_cell` (drop one leading quote) gives back exactly what was written: every writer
  escapes with :func:`csv_cell` and every reader of those files unescapes with :func:`read_cell`.
* **Markdown**: :func:`md_escape` puts a backslash before every character Markdown could read as markup
  (emphasis, code, links, raw HTML, table cells, headings), so a sample called ``<script>`` or ``a|b`` is
  shown as it is named.

Light on purpose (the standard library only): the figure style and every writer import it.
"""

from __future__ import annotations

import re

#: the first characters a spreadsheet reads as the start of a formula (OWASP): ``= + - @`` and tab, CR
FORMULA_LEADS = frozenset("=+-@\t\r")
#: what :func:`csv_cell` puts before a dangerous text cell (and before a text cell beginning with it)
QUOTE = "'"
#: a plain decimal number (what a spreadsheet reads as a number, not a formula), or inf/nan
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\Z|[+-]?(?:inf|infinity|nan)\Z", re.IGNORECASE)
_MD_SPECIAL = re.compile(r"([\\`*\[\]<>|#!~])")


def is_number_text(text: str) -> bool:
    """True when ``text`` is a plain decimal number (``-0.5``, ``+1e3``, ``nan``): a number, not a formula."""
    return bool(_NUMBER.match(text))


def csv_text(text: str) -> str:
    """``text`` as a CSV cell a spreadsheet shows and never runs (module doc); the inverse is :func:`read_cell`.

    Parameters
    ----------
    text : str

    Returns
    -------
    str
        ``text`` with a single quote before it when it begins with ``= + - @``, a tab or a CR (and is not a
        plain number) or with a quote; otherwise ``text`` unchanged.
    """
    if not text:
        return text
    lead = text[0]
    if lead == QUOTE or (lead in FORMULA_LEADS and not is_number_text(text)):
        return QUOTE + text
    return text


def csv_cell(value):
    """One value for a CSV writer: text through :func:`csv_text`, anything else (numbers, None) unchanged."""
    return csv_text(value) if isinstance(value, str) else value


def csv_row(values) -> list:
    """A row of values for ``csv.writer``, each through :func:`csv_cell`."""
    return [csv_cell(v) for v in values]


def csv_dict(row: dict) -> dict:
    """A row for ``csv.DictWriter``: each value through :func:`csv_cell` (the keys, the header, too through
    :func:`csv_header`)."""
    return {k: csv_cell(v) for k, v in row.items()}


def csv_header(names) -> list:
    """Column names for a header row, each through :func:`csv_text`."""
    return [csv_text(str(n)) for n in names]


def read_cell(text: str) -> str:
    """The text :func:`csv_text` was given: one leading single quote dropped (module doc)."""
    return text[1:] if text.startswith(QUOTE) else text


def safe_frame(frame):
    """A copy of a pandas DataFrame whose text cells (object and string columns) went through :func:`csv_cell`
    and whose column names through :func:`csv_text`; numeric columns are untouched (``to_csv`` writes them as
    numbers). Duck-typed: no pandas import here."""
    out = frame.copy()
    for name in out.columns:
        col = out[name]
        if str(col.dtype) in ("object", "string", "str", "category"):
            out[name] = col.astype(object).map(csv_cell)
    out.columns = [csv_text(str(c)) if isinstance(c, str) else c for c in out.columns]
    return out


def md_escape(text) -> str:
    """``text`` as literal Markdown: line breaks to spaces, a backslash before every character Markdown could
    read as markup (emphasis, code, links, HTML, table cells, headings), ``_`` too except inside a word."""
    text = " ".join(str(text).splitlines())
    text = _MD_SPECIAL.sub(r"\\\1", text)
    return re.sub(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])", r"\\_", text)

