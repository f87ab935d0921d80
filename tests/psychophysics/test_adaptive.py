"""The adaptive methods' common part (psychophysics.adaptive): the reversal rule, one rule for a running method
and for a recorded track."""

import numpy as np

from psychophysics.adaptive import reversals, turn
from psychophysics.observer import ObserverParams, SimulatedObserver
from psychophysics.staircase import UpDown


def test_reversals_are_the_turning_points_of_a_track():
    track = [10, 8, 6, 6, 8, 6, 4, 4, 4, 6, 8, 10, 8]
    assert reversals(track).tolist() == [3, 4, 8, 11]   # the last trial before each change of direction
    assert reversals([1, 1, 1]).tolist() == []


def test_turn_is_one_step_of_the_rule():
    assert turn(0, 5.0, 4.0) == (False, -1)        # the first move sets the direction
    assert turn(-1, 4.0, 4.0) == (False, -1)       # no move: no reversal, the direction kept
    assert turn(-1, 4.0, 5.0) == (True, 1)         # against the last move: a reversal at this trial
    assert turn(1, 5.0, 6.0) == (False, 1)


def test_a_methods_reversals_are_those_of_its_recorded_track():
    """A staircase counts its reversals as it runs; the analysis finds them in the recorded intensities (the
    staircase figure): the same trials, except that the method also sees its last proposal."""
    method = UpDown(start=4.0, step_down=[0.2, 0.1], max_trials=60)
    observer = SimulatedObserver(ObserverParams(threshold=1.0, slope=3.5), seed=5)
    while not method.finished:
        x = method.next_intensity()
        method.update(x, observer.respond(x))
    track = method.intensities + [method.next_intensity()]
    found = reversals(track)
    assert len(method.reversal_trials) >= 8
    np.testing.assert_array_equal(found + 1, method.reversal_trials)
    np.testing.assert_array_equal(np.asarray(track)[found], method.reversal_intensities)
    recorded = reversals(method.intensities)
    assert list(recorded + 1) == [t for t in method.reversal_trials if t < method.trials]
