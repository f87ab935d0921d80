"""plumbing.progress: plain progress lines when not on a terminal, with elapsed time and an estimate of what is left."""

import io
import types

import pytest

from plumbing import progress as progress_mod
from plumbing.progress import Progress, format_s


@pytest.fixture
def clock(monkeypatch):
    """The progress module's clock, advanced by the test (a loaded machine cannot stretch a sleep into it)."""
    now = [1000.0]
    monkeypatch.setattr(progress_mod, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    return now


def test_plain_lines_with_elapsed_and_time_left(clock):
    out = io.StringIO()                                  # not a terminal: plain lines, no bar
    p = Progress(4, "study S01", unit="trial", stream=out, min_interval_s=0.0)
    assert p.bar is None and p.eta_s() is None
    clock[0] += 0.05
    p.update(status="demonstration")
    assert p.eta_s() == pytest.approx(0.15)              # 3 left at 0.05 s each
    p.update(3, status="testing", total=5)               # a redrawn trial adds one
    p.update(5, status="done")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("study S01: 1 of 4 trials done (demonstration); elapsed 0 s, about 0 s left")
    assert lines[1].startswith("study S01: 3 of 5 trials done (testing)")
    assert lines[-1].startswith("study S01: 5 of 5 trials done (done)")


def test_rate_limited_but_the_last_step_always_printed():
    out = io.StringIO()
    p = Progress(100, "build", stream=out, min_interval_s=60.0)
    for k in range(1, 101):
        p.update(k)
    assert len(out.getvalue().splitlines()) == 2        # the first and the last


def test_resumed_progress_estimates_from_new_steps_only(clock):
    p = Progress(10, "study", stream=io.StringIO(), initial=6)
    assert p.eta_s() is None
    clock[0] += 0.02
    p.update(7)
    assert p.eta_s() == pytest.approx(0.06)              # 3 left at 0.02 s, not 6 steps' worth of history


def test_format_s():
    assert format_s(42.4) == "42 s" and format_s(185) == "3 min 05 s"
