"""One part of a report fails alone: its reason in words, the rest written.

The report and the plan are made of independent parts (each table, test, model and figure). A part
that cannot be computed on the data at hand (a library's ValueError, a singular matrix, a solver's NaN)
becomes one plain line naming the part and why, in the part's own section; the other parts are still
computed and written. Errors in the user's input (a bad file, a wrong flag) are found before, by the
loader and the commands, and still stop the command with one ``error:`` line.
"""

from __future__ import annotations

#: library messages and what they mean for a study's data (matched on the start of the message)
_WORDS = (
    ("There should not be a constant in the model",
     "a column of the model is constant or a combination of the others (e.g. a covariate that never changes)"),
    ("Singular matrix", "the model's equations have no unique solution (a sample or covariate is confounded "
                        "with another)"),
    ("The function value at x=", "the numerical solver met a value it cannot evaluate (an effect too large or "
                                 "a spread of zero)"),
    ("f(a) and f(b) must have different signs", "the numerical solver found no crossing (an effect beyond the "
                                                "range it searches)"),
    ("array must not contain infs or NaNs", "a value is infinite or missing"),
    ("exog contains inf or nans", "a value is infinite or missing"),
    ("zero-size array", "no data left to compute it from"),
)


def reason(exc: BaseException) -> str:
    """``exc`` as a plain reason: what it means for the data, with the library's own words in parentheses."""
    text = (str(exc).strip().splitlines() or [""])[0].strip()
    for start, words in _WORDS:
        if text.startswith(start) or start in text:
            return f"{words} ({text})"
    if not text:
        return f"{type(exc).__name__} without a message"
    return text


def attempt(what: str, notes: list, fn, *args, default=None, failed: str = "not computed", **kwargs):
    """``fn(*args, **kwargs)``, or ``default`` with ``"<what> <failed>: <reason>"`` appended to ``notes``.

    Only :class:`Exception` is caught: Ctrl-C (``KeyboardInterrupt``) and an exit (``SystemExit``, SIGTERM's
    handler) still end the command as they should; a part too large for memory (``MemoryError``) fails alone.
    """
    try:
        return fn(*args, **kwargs)
    except Exception as exc:          # one part's failure must not lose the others (module docstring)
        notes.append(f"{what} {failed}: {reason(exc)}")
        return default
