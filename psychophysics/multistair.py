"""Several adaptive methods interleaved in one session, with catch trials (PsychoPy's MultiStairHandler).

Trials go round the unfinished staircases: in each round every unfinished staircase gets one trial, in the
order given (``order="fixed"``) or shuffled per round (``order="random"``, the default: the observer cannot
follow one track). With ``catch_rate`` > 0, before each trial a catch trial is drawn with that probability:
it is presented at ``catch_intensity`` (e.g. 0: a blank, or a sure-to-be-felt level), its response is
recorded but given to no staircase (catch trials are excluded from fits, contract column ``is_catch``).

Typical loop (the study runner writes each trial and :meth:`Interleaved.state` before the next trial)::

    handler = Interleaved({"up": UpDown(...), "down": UpDown(...)}, seed=7)
    while not handler.finished:
        trial = handler.next_trial()         # Trial(number, label, intensity, is_catch)
        handler.update(trial, observer.respond(trial.intensity))

The handler's state is its configuration plus every trial (label, intensity, catch flag, response);
:meth:`Interleaved.from_state` replays them through a fresh handler and fresh methods, checking each
replayed trial against the record, so a resumed session continues with the same random draws and the same
intensities as an uninterrupted one. The first trial of every staircase is recorded like any other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from plumbing.validation import is_finite_number, require_int, require_number

from .adaptive import AdaptiveMethod
from .methods import method_from_state, method_from_table

#: interleaving orders
ORDERS = ("random", "fixed")


class Trial(NamedTuple):
    """One scheduled trial: its 1-based number in the session, the staircase's label (a catch trial carries
    the label of the staircase whose trial follows it), the intensity and the catch flag."""

    number: int
    label: str
    intensity: float
    is_catch: bool


class Interleaved:
    """Interleaved adaptive methods with optional catch trials (module docstring).

    Parameters
    ----------
    methods : dict of str -> AdaptiveMethod
        The staircases by label (insertion order is the fixed order).
    order : {"random", "fixed"}
    seed : int
        Seeds the order shuffles and the catch-trial draws.
    catch_rate : float
        Probability in [0, 1) that a catch trial comes before a staircase trial.
    catch_intensity : float or None
        Intensity of catch trials (required when ``catch_rate`` > 0).
    """

    def __init__(self, methods: dict, order: str = "random", seed: int = 0, catch_rate: float = 0.0,
                 catch_intensity: float | None = None, prefix: str = ""):
        if not isinstance(methods, dict) or not methods:
            raise ValueError(f"{prefix}staircases: give at least one labelled adaptive method")
        for label, m in methods.items():
            if not isinstance(label, str) or not label:
                raise ValueError(f"{prefix}staircase labels must be non-empty strings, got {label!r}")
            if not isinstance(m, AdaptiveMethod):
                raise ValueError(f"{prefix}staircase {label!r} is not an adaptive method")
        if order not in ORDERS:
            raise ValueError(f"{prefix}order must be one of {', '.join(ORDERS)}, got {order!r}")
        require_int("seed", seed, minimum=0, prefix=prefix)
        require_number("catch_rate", catch_rate, minimum=0.0, prefix=prefix)
        if not catch_rate < 1.0:
            raise ValueError(f"{prefix}catch_rate must be in [0, 1), got {catch_rate!r}")
        if catch_rate > 0 and not is_finite_number(catch_intensity):
            raise ValueError(f"{prefix}catch_intensity must be a finite number when catch_rate > 0, "
                             f"got {catch_intensity!r}")
        self.methods = dict(methods)
        self.order, self.seed = order, seed
        self.catch_rate, self.catch_intensity = float(catch_rate), catch_intensity
        self._initial = {label: m.state() for label, m in self.methods.items()}
        self._rng = np.random.default_rng(seed)
        self._round: list[str] = []
        self._pending: Trial | None = None
        #: every trial so far: ``[label, intensity, is_catch, correct]``
        self.history: list[list] = []
        #: the staircases stopped by :meth:`drop` (their intensity could not be presented)
        self.stopped: set = set()

    @classmethod
    def from_table(cls, table: dict, prefix: str = "") -> "Interleaved":
        """Build from a protocol table: ``{"order", "seed", "catch_rate", "catch_intensity",
        "staircases": {label: <method table>, ...}}`` (:func:`psychophysics.methods.method_from_table`)."""
        if not isinstance(table, dict):
            raise ValueError(f"{prefix or 'the staircases '}must be a table, got {type(table).__name__}")
        unknown = sorted(set(table) - {"order", "seed", "catch_rate", "catch_intensity", "staircases"})
        if unknown:
            raise ValueError(f"{prefix}{unknown[0]} is not a key of an interleaved-staircases table "
                             "(keys: order, seed, catch_rate, catch_intensity, staircases)")
        stairs = table.get("staircases")
        if not isinstance(stairs, dict) or not stairs:
            raise ValueError(f"{prefix}staircases must be a table of labelled method tables, got {stairs!r}")
        methods = {label: method_from_table(t, f"{prefix}staircases.{label}.") for label, t in stairs.items()}
        return cls(methods, order=table.get("order", "random"), seed=table.get("seed", 0),
                   catch_rate=table.get("catch_rate", 0.0), catch_intensity=table.get("catch_intensity"),
                   prefix=prefix)

    @property
    def finished(self) -> bool:
        """True when every staircase has finished (or was stopped by :meth:`drop`)."""
        return all(m.finished or label in self.stopped for label, m in self.methods.items())

    def drop(self, trial: Trial) -> None:
        """Give up the pending ``trial`` without a response: its intensity cannot be presented (a stimulus the
        device cannot render). A staircase trial's staircase stops there (it would ask for the same intensity
        again); a dropped catch trial stops nothing. Nothing enters :attr:`history`: a replay drops the same
        trial at the same point (the random draws are the same).

        Raises
        ------
        ValueError
            ``trial`` is not the pending trial.
        """
        if self._pending is None or tuple(trial) != tuple(self._pending):
            raise ValueError(f"trial {tuple(trial)!r} is not the pending trial {self._pending!r}")
        self._pending = None
        if not trial.is_catch:
            self.stopped.add(trial.label)

    def next_trial(self) -> Trial:
        """The next trial (the same one until :meth:`update` is called with it).

        Raises
        ------
        ValueError
            Every staircase has finished.
        """
        if self._pending is not None:
            return self._pending
        if self.finished:
            raise ValueError("all staircases have finished; no next trial")
        while True:
            if not self._round:
                self._round = [lb for lb, m in self.methods.items() if not m.finished and lb not in self.stopped]
                if self.order == "random":
                    self._round = [self._round[i] for i in self._rng.permutation(len(self._round))]
            label = self._round[0]
            if not self.methods[label].finished and label not in self.stopped:
                break
            self._round.pop(0)
        number = len(self.history) + 1
        if self.catch_rate > 0 and self._rng.random() < self.catch_rate:
            self._pending = Trial(number, label, float(self.catch_intensity), True)
        else:
            self._round.pop(0)
            self._pending = Trial(number, label, self.methods[label].next_intensity(), False)
        return self._pending

    def update(self, trial: Trial, correct: bool) -> None:
        """Record the response to ``trial`` (the one :meth:`next_trial` returned) and adapt its staircase.

        Raises
        ------
        ValueError
            ``trial`` is not the pending trial.
        """
        if self._pending is None or tuple(trial) != tuple(self._pending):
            raise ValueError(f"trial {tuple(trial)!r} is not the pending trial {self._pending!r}")
        if not (isinstance(correct, (bool, np.bool_)) or (isinstance(correct, int) and correct in (0, 1))):
            raise ValueError(f"a response must be correct (1) or not (0), got {correct!r}")
        if not trial.is_catch:
            self.methods[trial.label].update(trial.intensity, correct)
        self.history.append([trial.label, trial.intensity, trial.is_catch, bool(correct)])
        self._pending = None

    def estimates(self) -> dict:
        """Each staircase's :meth:`~psychophysics.adaptive.AdaptiveMethod.estimate`, by label."""
        return {label: m.estimate() for label, m in self.methods.items()}

    def state(self) -> dict:
        """JSON-serialisable state: configuration, the staircases' initial states, every trial, and each
        staircase's current state (for a human reader; :meth:`from_state` replays the trials)."""
        return {"handler": "interleaved", "order": self.order, "seed": self.seed, "catch_rate": self.catch_rate,
                "catch_intensity": self.catch_intensity, "initial": self._initial,
                "history": [list(h) for h in self.history],
                "staircases": {lb: m.state() for lb, m in self.methods.items()}}

    @classmethod
    def from_state(cls, state: dict) -> "Interleaved":
        """Rebuild the handler by replaying its trials (same random draws, same intensities, same bits).

        Raises
        ------
        ValueError
            Not an interleaved state, or a recorded trial differs from the replayed one.
        """
        if not isinstance(state, dict) or state.get("handler") != "interleaved":
            raise ValueError("not the state of interleaved staircases (no \"handler\": \"interleaved\")")
        initial = state.get("initial")
        if not isinstance(initial, dict):
            raise ValueError("interleaved state: 'initial' must map labels to method states")
        handler = cls({lb: method_from_state(s) for lb, s in initial.items()}, order=state.get("order"),
                      seed=state.get("seed"), catch_rate=state.get("catch_rate"),
                      catch_intensity=state.get("catch_intensity"))
        for i, rec in enumerate(state.get("history", []), 1):
            if not (isinstance(rec, list) and len(rec) == 4):
                raise ValueError(f"interleaved state: trial {i} must be [label, intensity, is_catch, correct]")
            trial = handler.next_trial()
            if [trial.label, trial.intensity, trial.is_catch] != rec[:3]:
                raise ValueError(f"interleaved state does not replay at trial {i}: recorded {rec[:3]!r}, "
                                 f"replayed {[trial.label, trial.intensity, trial.is_catch]!r}")
            handler.update(trial, rec[3])
        return handler
