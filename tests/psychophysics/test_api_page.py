"""docs/psychophysics_api.md: its example runs as printed, and it names every public name of the package."""

import contextlib
import io
import re
from pathlib import Path

import psychophysics

PAGE = Path(__file__).resolve().parents[2] / "docs" / "psychophysics_api.md"


def test_the_example_runs_and_recovers_the_observers_threshold():
    text = PAGE.read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, str(PAGE), "exec"), {})
    quest, fitted = (float(v) for v in out.getvalue().split())
    assert 0.7 < quest < 1.4 and 0.7 < fitted < 1.4      # the observer's threshold is 1.0


def test_every_public_name_is_on_the_page():
    text = PAGE.read_text()
    missing = [name for name in psychophysics.__all__ if f"`{name}" not in text]
    assert not missing, missing
    for name in psychophysics.__all__:
        assert getattr(psychophysics, name) is not None
