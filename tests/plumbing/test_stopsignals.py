"""plumbing.stopsignals.stop_in: a stop is found through the errors Python raised from it, not through errors
raised while it was handled. The signals themselves are tested in real processes (tests/renderer/test_stop_signals.py)."""

import signal

from plumbing.stopsignals import Terminated, stop_in


def _raised(make):
    try:
        make()
    except BaseException as exc:     # noqa: BLE001 -- the object under test
        return exc
    raise AssertionError("nothing raised")


def _wrap(stop):
    try:
        raise stop
    except Terminated as exc:
        raise RuntimeError("Error calling __set_name__ on 'cached_property' instance") from exc


def _during(stop):
    try:
        raise stop
    except Terminated:
        raise ValueError("the device failed while the stop was handled")


def test_a_stop_is_found_through_its_causes():
    stop = Terminated(signal.SIGTERM)
    wrapped = _raised(lambda: _wrap(stop))
    assert isinstance(wrapped, RuntimeError) and stop_in(wrapped) is stop
    twice = _raised(lambda: _rewrap(wrapped))
    assert stop_in(twice) is stop and stop_in(stop) is stop


def _rewrap(exc):
    raise TypeError("outer") from exc


def test_a_cycle_of_causes_ends_the_search():
    a, b = ValueError("a"), ValueError("b")
    a.__cause__, b.__cause__ = b, a
    assert stop_in(a) is None


def test_an_error_raised_while_a_stop_was_handled_stays_an_error():
    during = _raised(lambda: _during(Terminated(signal.SIGHUP)))
    assert isinstance(during.__context__, Terminated) and stop_in(during) is None
    assert stop_in(ValueError("plain")) is None and stop_in(None) is None
