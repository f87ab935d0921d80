"""The common part of every adaptive method: trial history, reversals, stopping rules, state and replay.

Every method (:mod:`psychophysics.staircase`: transformed and weighted up-down; :mod:`psychophysics.quest`: QUEST+ and Psi)
has the same interface::

    x = method.next_intensity()          # the intensity of the next trial (the first one too)
    method.update(x, correct)            # the response at the intensity actually presented
    method.finished                      # a stopping rule is met (trials or reversals)
    method.estimate()                    # {"threshold": ..., ...}
    d = method.state()                   # JSON-serialisable: method name, configuration, history
    same = method_from_state(d)          # the same method after the same trials, bit for bit

A state is the method's configuration plus the list of ``[intensity, correct]`` of every trial, the first
included; :func:`from_state` rebuilds the method and replays the history through the same arithmetic, so a
session killed at any trial resumes exactly where it was (floating-point operations in the same order give
the same bits). The state also carries a summary (trials, reversals, next intensity) for a human reading the
file; on load the replayed next intensity must equal the stored one, so a state written by a different
version of the method is refused rather than silently continued differently.

Reversals are counted the same way for every method: a reversal is a trial after which the track changes
direction (the next intensity moves opposite to the last move); its intensity is that trial's
(PsychoPy's ``StairHandler.reversalIntensities`` convention). The rule is :func:`turn`, the one
:func:`reversals` also applies to a recorded track.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from plumbing.validation import is_finite_number, require_int


class AdaptiveMethod:
    """Base class of the adaptive methods (module docstring); subclasses set :attr:`name` and implement
    :meth:`config`, :meth:`_apply`, :meth:`_proposal` and :meth:`estimate`.

    Parameters
    ----------
    max_trials : int or None
        Stop after this many trials.
    max_reversals : int or None
        Stop after this many reversals. At least one of the two is required; the method stops at whichever
        comes first.
    """

    #: the method's name in protocol files, states and ``--method``
    name = ""

    def __init__(self, max_trials: int | None = None, max_reversals: int | None = None, prefix: str = ""):
        if max_trials is None and max_reversals is None:
            raise ValueError(f"{prefix}max_trials or {prefix}max_reversals is required (the stopping rule)")
        if max_trials is not None:
            require_int("max_trials", max_trials, minimum=1, prefix=prefix)
        if max_reversals is not None:
            require_int("max_reversals", max_reversals, minimum=1, prefix=prefix)
        self.max_trials = max_trials
        self.max_reversals = max_reversals
        #: ``[intensity, correct]`` of every trial, in order (the first trial included)
        self.history: list[list] = []
        #: intensities at the reversals, and their 1-based trial numbers
        self.reversal_intensities: list[float] = []
        self.reversal_trials: list[int] = []
        self._direction = 0

    # -- the interface ------------------------------------------------------------------------------------

    def next_intensity(self) -> float:
        """The intensity of the next trial (the method's unit; unchanged until :meth:`update`)."""
        return float(self._proposal())

    def update(self, intensity: float, correct: bool) -> None:
        """Record one trial's response at ``intensity`` (the intensity presented) and adapt.

        Parameters
        ----------
        intensity : float
            The trial's intensity (finite).
        correct : bool
            True for a correct response (``1``/``0`` are accepted).

        Raises
        ------
        ValueError
            ``intensity`` not finite, ``correct`` not a boolean or 0/1, or the method already finished.
        """
        if not is_finite_number(intensity):
            raise ValueError(f"{self.name}: trial intensity must be a finite number, got {intensity!r}")
        if not (isinstance(correct, (bool, np.bool_)) or (isinstance(correct, int) and correct in (0, 1))):
            raise ValueError(f"{self.name}: a response must be correct (1) or not (0), got {correct!r}")
        if self.finished:
            raise ValueError(f"{self.name}: the method finished after {len(self.history)} trials; no more updates")
        intensity, correct = float(intensity), bool(correct)
        self._apply(intensity, correct)          # first: a response it refuses leaves no trace
        self.history.append([intensity, correct])
        self._track_reversal(intensity, float(self._proposal()))

    @property
    def finished(self) -> bool:
        """True once ``max_trials`` trials or ``max_reversals`` reversals are reached."""
        return ((self.max_trials is not None and len(self.history) >= self.max_trials)
                or (self.max_reversals is not None and len(self.reversal_intensities) >= self.max_reversals))

    @property
    def last_trial_reversal(self) -> bool:
        """True when the last trial so far was a reversal (for a trials.csv ``reversal`` column)."""
        return bool(self.reversal_trials) and self.reversal_trials[-1] == len(self.history)

    @property
    def trials(self) -> int:
        """Number of trials so far."""
        return len(self.history)

    @property
    def intensities(self) -> list[float]:
        """The intensity of every trial so far, the first included."""
        return [x for x, _ in self.history]

    def state(self) -> dict:
        """The method as a JSON-serialisable dict: ``method``, ``config``, ``history`` and a summary.

        Returns
        -------
        dict
            ``{"method": name, "config": {...}, "history": [[intensity, correct], ...], "trials": int,
            "reversals": int, "finished": bool, "next_intensity": float}``; :func:`from_state` rebuilds it.
        """
        return {"method": self.name, "config": self.config(), "history": [[x, bool(c)] for x, c in self.history],
                "trials": len(self.history), "reversals": len(self.reversal_intensities),
                "finished": self.finished, "next_intensity": self.next_intensity()}

    @classmethod
    def from_state(cls, state: dict):
        """Rebuild a method from :meth:`state` by replaying its history (exact: the same bits).

        Raises
        ------
        ValueError
            The state is not a dict of this method, a trial is malformed, or the replay does not end at the
            stored next intensity (a state from a different version of the method).
        """
        if not isinstance(state, dict) or not isinstance(state.get("config"), dict):
            raise ValueError(f"an adaptive method's state must be a dict with 'method', 'config' and 'history', "
                             f"got {type(state).__name__}")
        if state.get("method") != cls.name:
            raise ValueError(f"state is of method {state.get('method')!r}, not {cls.name!r}")
        method = build(cls, state["config"], f"{cls.name} state config.")
        history = state.get("history", [])
        if not isinstance(history, list):
            raise ValueError(f"{cls.name} state: 'history' must be a list of [intensity, correct]")
        for i, trial in enumerate(history, 1):
            if not (isinstance(trial, (list, tuple)) and len(trial) == 2):
                raise ValueError(f"{cls.name} state: history trial {i} must be [intensity, correct], got {trial!r}")
            method.update(trial[0], trial[1])
        stored = state.get("next_intensity")
        if stored is not None and stored != method.next_intensity():
            raise ValueError(f"{cls.name} state does not replay: it stores next intensity {stored!r} but the "
                             f"replayed method proposes {method.next_intensity()!r} (written by another version?)")
        return method

    # -- for subclasses -----------------------------------------------------------------------------------

    def config(self) -> dict:
        """The constructor's keyword arguments (JSON-serialisable)."""
        raise NotImplementedError

    def estimate(self) -> dict:
        """The method's threshold estimate: ``{"threshold": float, ...}``."""
        raise NotImplementedError

    def _apply(self, intensity: float, correct: bool) -> None:
        """Adapt to one response (before it joins the history; raise ValueError to refuse it)."""
        raise NotImplementedError

    def _proposal(self) -> float:
        """The next trial's intensity (pure: no state change)."""
        raise NotImplementedError

    def _stop_config(self) -> dict:
        """The stopping rule's part of :meth:`config`."""
        return {"max_trials": self.max_trials, "max_reversals": self.max_reversals}

    def _track_reversal(self, intensity: float, following: float) -> None:
        """Count a reversal when the move ``intensity -> following`` is opposite to the last move (:func:`turn`)."""
        reversal, self._direction = turn(self._direction, intensity, following)
        if reversal:
            self.reversal_intensities.append(intensity)
            self.reversal_trials.append(len(self.history))


def turn(direction: int, intensity: float, following: float) -> tuple[bool, int]:
    """The reversal rule, one step: is the trial at ``intensity`` a reversal, and the track's direction after it.

    Parameters
    ----------
    direction : int
        The direction of the track's last move: +1 up, -1 down, 0 before any move.
    intensity : float
        The trial's intensity.
    following : float
        The next trial's intensity (a method's proposal, or the next recorded trial).

    Returns
    -------
    (bool, int)
        True when the move ``intensity -> following`` goes against ``direction`` (a turning point: the
        trial's intensity is a local extreme of the track); the direction after the move (unchanged by a
        move of zero).
    """
    move = 0 if following == intensity else (1 if following > intensity else -1)
    if move == 0:
        return False, direction
    return direction != 0 and move != direction, move


def reversals(intensity) -> np.ndarray:
    """Indices of the trials at which a recorded staircase track reversed (its turning points, :func:`turn`).

    Parameters
    ----------
    intensity : array_like, shape (T,)
        The track's intensities in trial order.

    Returns
    -------
    ndarray of int
        Index of each trial whose intensity is a local extreme of the track: the last trial before the
        direction of change flips (runs of equal intensity are skipped). A method counts the same trials
        (:attr:`AdaptiveMethod.reversal_trials`, 1-based) and, before the track has a next trial, also
        the last one when its proposal turns.
    """
    x = np.asarray(intensity, dtype=float)
    out, direction = [], 0
    for i in range(len(x) - 1):
        reversal, direction = turn(direction, float(x[i]), float(x[i + 1]))
        if reversal:
            out.append(i)
    return np.array(out, dtype=int)


def build(cls, kwargs: dict, prefix: str = "") -> AdaptiveMethod:
    """``cls(**kwargs)`` after checking the keys against its constructor: an unknown or missing key is one
    ``ValueError`` naming it with ``prefix`` (a protocol table's place, or a state's), never a ``TypeError``."""
    params = inspect.signature(cls.__init__).parameters
    allowed = [p for p in params if p not in ("self", "prefix")]
    unknown = sorted(set(kwargs) - set(allowed))
    if unknown:
        raise ValueError(f"{prefix}{unknown[0]} is not a parameter of method {cls.name!r} "
                         f"(its parameters: {', '.join(allowed)})")
    missing = [p for p in allowed if params[p].default is inspect.Parameter.empty and p not in kwargs]
    if missing:
        raise ValueError(f"{prefix}{missing[0]} is missing (method {cls.name!r} requires it)")
    return cls(**kwargs, prefix=prefix)


def mean_sd(values, log10: bool) -> tuple[float, float]:
    """Mean and sample SD of ``values``; with ``log10`` the geometric mean and the SD of log10(values).

    Returns ``(nan, nan)`` for no values and SD ``0.0`` for one.
    """
    vals = [math.log10(v) for v in values] if log10 else list(values)
    if not vals:
        return math.nan, math.nan
    m = sum(vals) / len(vals)
    sd = math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
    return (10.0 ** m if log10 else m), sd
