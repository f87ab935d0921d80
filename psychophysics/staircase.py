"""Staircases: transformed up-down (Levitt 1971) and weighted up-down (Kaernbach 1991).

Both move the intensity by fixed steps after runs of responses; the interface, the state/replay and the
reversal convention are those of :class:`psychophysics.adaptive.AdaptiveMethod`.

Steps are in the staircase's ``step_scale``: ``"linear"`` adds and subtracts them, ``"log10"`` multiplies
and divides the intensity by ``10**step`` (a step of 0.1 is a factor 1.26, about 1 dB of amplitude
x 2). A step may be a list: the step after ``k`` reversals is ``steps[min(k, len - 1)]`` (PsychoPy's
``stepSizes``; the move that makes the k-th reversal already takes ``steps[k]``, as in PsychoPy), e.g.
large steps to find the threshold region, then small ones to track it.

``initial_rule = True`` moves after every response until the first reversal (1-up-1-down), then follows
the staircase's own rule: PsychoPy's ``StairHandler(applyInitialRule=True)``, which saves the first trials
of a start far from threshold. A staircase stopped by reversals only (no ``max_trials``) also stops after
``max_trials_at_bound`` trials in a row at ``min_intensity`` or ``max_intensity`` (default 20): an observer
who cannot do the task at the easiest intensity never makes a reversal there, and the session would run
for ever.
"""

from __future__ import annotations

import math

from plumbing.validation import require_int, require_number

from .adaptive import AdaptiveMethod, mean_sd

#: the step scales
STEP_SCALES = ("linear", "log10")
#: a staircase stopped by reversals only stops after this many trials in a row at an intensity bound
DEFAULT_TRIALS_AT_BOUND = 20


def _steps(name: str, value, prefix: str) -> list[float]:
    """A step or list of steps, each a positive finite number; returns the list."""
    values = value if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise ValueError(f"{prefix}{name} must be a positive number or a non-empty list of them, got []")
    for v in values:
        require_number(name, v, minimum=0.0, strict=True, prefix=prefix)
    return [float(v) for v in values]


class UpDown(AdaptiveMethod):
    """Transformed up-down staircase (Levitt 1971, *J. Acoust. Soc. Am.* 49(2B):467-477), with unequal
    steps (Garcia-Perez 1998, *Vision Res.* 38:1861-1881).

    The intensity goes down by ``step_down`` after ``n_down`` consecutive correct responses and up by
    ``step_up`` after ``n_up`` consecutive errors. With ``n_up = 1`` the track converges where
    ``p**n_down = step_up / (step_up + step_down)``: for equal steps 1-up-2-down tracks
    ``p = 0.5**(1/2) = 0.707``, 1-up-3-down ``0.794`` (:meth:`target_probability`).

    Parameters
    ----------
    start : float
        Intensity of the first trial (the method's unit; > 0 with ``step_scale="log10"``).
    step_down : float or list of float
        Step down (in ``step_scale`` units); a list changes it with the reversal count (module docstring).
    step_up : float, list of float or None
        Step up; None: the same as ``step_down``.
    n_down, n_up : int
        Consecutive correct responses for a step down, errors for a step up (default 1-up-2-down).
    step_scale : {"linear", "log10"}
    min_intensity, max_intensity : float or None
        The intensity is clipped to these bounds.
    max_trials, max_reversals : int or None
        Stopping rule (:class:`psychophysics.adaptive.AdaptiveMethod`).
    discard_reversals : int
        The estimate ignores this many first reversals (default 2: they mostly reflect the start).
    initial_rule : bool
        1-up-1-down until the first reversal (PsychoPy's ``applyInitialRule``); default False.
    max_trials_at_bound : int or None
        Stop after this many trials in a row at ``min_intensity`` or ``max_intensity``; None: 20 when the
        staircase has no ``max_trials`` (stopped by reversals only), else no such stop.
    """

    name = "updown"

    def __init__(self, start: float, step_down, step_up=None, n_down: int = 2, n_up: int = 1,
                 step_scale: str = "log10", min_intensity: float | None = None,
                 max_intensity: float | None = None, max_trials: int | None = None,
                 max_reversals: int | None = None, discard_reversals: int = 2, initial_rule: bool = False,
                 max_trials_at_bound: int | None = None, prefix: str = ""):
        super().__init__(max_trials, max_reversals, prefix)
        if not isinstance(initial_rule, bool):
            raise ValueError(f"{prefix}initial_rule must be true or false, got {initial_rule!r}")
        if max_trials_at_bound is not None:
            require_int("max_trials_at_bound", max_trials_at_bound, minimum=1, prefix=prefix)
        self.initial_rule = initial_rule
        self._bound_cap_given = max_trials_at_bound
        self.max_trials_at_bound = (max_trials_at_bound if max_trials_at_bound is not None
                                    else (DEFAULT_TRIALS_AT_BOUND if max_trials is None else None))
        if step_scale not in STEP_SCALES:
            raise ValueError(f"{prefix}step_scale must be one of {', '.join(STEP_SCALES)}, got {step_scale!r}")
        log = step_scale == "log10"
        require_number("start", start, minimum=0.0 if log else None, strict=True, prefix=prefix)
        require_number("min_intensity", min_intensity, minimum=0.0 if log else None, strict=True,
                       optional=True, prefix=prefix)
        require_number("max_intensity", max_intensity, optional=True, prefix=prefix)
        if min_intensity is not None and max_intensity is not None and max_intensity < min_intensity:
            raise ValueError(f"{prefix}max_intensity ({max_intensity}) must be >= min_intensity ({min_intensity})")
        self.steps_down = _steps("step_down", step_down, prefix)
        self.steps_up = self.steps_down if step_up is None else _steps("step_up", step_up, prefix)
        self.n_down = require_int("n_down", n_down, minimum=1, prefix=prefix)
        self.n_up = require_int("n_up", n_up, minimum=1, prefix=prefix)
        self.discard_reversals = require_int("discard_reversals", discard_reversals, minimum=0, prefix=prefix)
        self.step_scale = step_scale
        self.start = float(start)
        self.min_intensity = min_intensity
        self.max_intensity = max_intensity
        self._step_up_given = step_up
        self._next = self._clip(self.start)
        self._run_correct = 0
        self._run_wrong = 0

    def config(self) -> dict:
        """The constructor's keyword arguments (JSON-serialisable)."""
        return {"start": self.start, "step_down": list(self.steps_down),
                "step_up": None if self._step_up_given is None else list(self.steps_up),
                "n_down": self.n_down, "n_up": self.n_up, "step_scale": self.step_scale,
                "min_intensity": self.min_intensity, "max_intensity": self.max_intensity,
                "discard_reversals": self.discard_reversals, **self._stop_config(), **self._new_keys()}

    def _new_keys(self) -> dict:
        """The options a state holds only when set (states written without them replay unchanged)."""
        out = {}
        if self.initial_rule:
            out["initial_rule"] = True
        if self._bound_cap_given is not None:
            out["max_trials_at_bound"] = self._bound_cap_given
        return out

    @property
    def finished(self) -> bool:
        """True once ``max_trials`` or ``max_reversals`` is reached, or after ``max_trials_at_bound`` trials in a
        row at an intensity bound."""
        return super().finished or self.stopped_at_bound is not None

    @property
    def stopped_at_bound(self) -> str | None:
        """``"min_intensity"`` or ``"max_intensity"`` when the track has sat there for ``max_trials_at_bound``
        trials in a row (and the next trial would be there too), else None."""
        cap = self.max_trials_at_bound
        if cap is None or len(self.history) < cap:
            return None
        for name, bound in (("min_intensity", self.min_intensity), ("max_intensity", self.max_intensity)):
            if bound is not None and self._next == bound and all(x == bound for x, _ in self.history[-cap:]):
                return name
        return None

    def target_probability(self) -> float | None:
        """The probability correct the track converges to, for the current (last) steps.

        ``n_up = 1``: ``(s_up / (s_up + s_down)) ** (1 / n_down)``; ``n_down = 1``:
        ``1 - (s_down / (s_up + s_down)) ** (1 / n_up)`` (Levitt 1971; Garcia-Perez 1998; Kaernbach 1991).
        None for other rules (no closed form).
        """
        up, down = self.steps_up[-1], self.steps_down[-1]
        if self.n_up == 1:
            return (up / (up + down)) ** (1.0 / self.n_down)
        if self.n_down == 1:
            return 1.0 - (down / (up + down)) ** (1.0 / self.n_up)
        return None

    def estimate(self) -> dict:
        """Threshold = mean of the reversal intensities after the first ``discard_reversals``.

        Geometric mean with ``step_scale="log10"``. Before there is a reversal to use, the mean of the second
        half of the trials' intensities (``"basis": "trials"``).

        Returns
        -------
        dict
            ``threshold``, ``threshold_sd`` (of the values averaged, log10 units with log steps),
            ``basis`` (``"reversals"`` or ``"trials"``), ``n_used``, ``trials``, ``reversals``,
            ``target_p`` (:meth:`target_probability`).
        """
        log = self.step_scale == "log10"
        used = self.reversal_intensities[self.discard_reversals:]
        basis = "reversals"
        if not used:
            basis = "trials"
            xs = self.intensities or [self._next]
            used = xs[len(xs) // 2:]
        threshold, sd = mean_sd(used, log)
        out = {"threshold": threshold, "threshold_sd": sd, "basis": basis, "n_used": len(used),
               "trials": self.trials, "reversals": len(self.reversal_intensities),
               "target_p": self.target_probability()}
        if self.stopped_at_bound is not None:
            out["stopped_at_bound"] = self.stopped_at_bound
        return out

    def _clip(self, x: float) -> float:
        if self.min_intensity is not None:
            x = max(x, self.min_intensity)
        if self.max_intensity is not None:
            x = min(x, self.max_intensity)
        return x

    def _step(self, x: float, steps: list[float], sign: int) -> float:
        # a move that turns the track already takes the next step size (PsychoPy's StairHandler does the same)
        k = len(self.reversal_intensities) + (1 if self._direction not in (0, sign) else 0)
        s = steps[min(k, len(steps) - 1)]
        return x * 10.0 ** (sign * s) if self.step_scale == "log10" else x + sign * s

    def _apply(self, intensity: float, correct: bool) -> None:
        # counts of the current runs, committed only when the step is accepted (a refused update changes nothing)
        nxt = intensity
        if self.initial_rule and not self.reversal_intensities:
            # 1-up-1-down until the first reversal (the move making it included), as PsychoPy's initial rule
            nxt = self._clip(self._step(intensity, self.steps_down if correct else self.steps_up,
                                        -1 if correct else 1))
            if not math.isfinite(nxt):
                raise ValueError(f"{self.name}: the next intensity is {nxt!r} (the track ran off the number "
                                 "range); set max_intensity (and min_intensity) to the stimulus range")
            self._run_correct, self._run_wrong, self._next = 0, 0, nxt
            return
        if correct:
            run_correct, run_wrong = self._run_correct + 1, 0
            if run_correct >= self.n_down:
                run_correct = 0
                nxt = self._step(intensity, self.steps_down, -1)
        else:
            run_correct, run_wrong = 0, self._run_wrong + 1
            if run_wrong >= self.n_up:
                run_wrong = 0
                nxt = self._step(intensity, self.steps_up, +1)
        nxt = self._clip(nxt)
        if not math.isfinite(nxt):
            # only without max_intensity: e.g. hundreds of wrong answers in a row on a log scale
            raise ValueError(f"{self.name}: the next intensity is {nxt!r} (the track ran off the number range); "
                             "set max_intensity (and min_intensity) to the stimulus range")
        self._run_correct, self._run_wrong = run_correct, run_wrong
        self._next = nxt

    def _proposal(self) -> float:
        return self._next


class WeightedUpDown(UpDown):
    """Weighted up-down staircase (Kaernbach 1991, *Percept. Psychophys.* 49(3):227-229).

    One step after every response: down by ``step_down`` after a correct one, up by
    ``step_up = step_down * target / (1 - target)`` after an error, so the track converges where
    ``p * step_down = (1 - p) * step_up``, i.e. ``p = target`` (e.g. 0.75: up steps three times the down
    steps).

    Parameters
    ----------
    start : float
        First intensity.
    step_down : float or list of float
        Step down (``step_scale`` units); the up steps follow from ``target``.
    target : float
        Probability correct to track, in (0, 1) (default 0.75, midway in a 2AFC).
    step_scale, min_intensity, max_intensity, max_trials, max_reversals, discard_reversals, max_trials_at_bound
        As :class:`UpDown` (the weighted rule steps after every response: it has no initial rule).
    """

    name = "weighted"

    def __init__(self, start: float, step_down, target: float = 0.75, step_scale: str = "log10",
                 min_intensity: float | None = None, max_intensity: float | None = None,
                 max_trials: int | None = None, max_reversals: int | None = None, discard_reversals: int = 2,
                 max_trials_at_bound: int | None = None, prefix: str = ""):
        require_number("target", target, minimum=0.0, strict=True, prefix=prefix)
        if not target < 1.0:
            raise ValueError(f"{prefix}target must be in (0, 1), got {target!r}")
        downs = _steps("step_down", step_down, prefix)
        super().__init__(start, downs, [s * target / (1.0 - target) for s in downs], n_down=1, n_up=1,
                         step_scale=step_scale, min_intensity=min_intensity, max_intensity=max_intensity,
                         max_trials=max_trials, max_reversals=max_reversals,
                         discard_reversals=discard_reversals, max_trials_at_bound=max_trials_at_bound,
                         prefix=prefix)
        self.target = float(target)

    def config(self) -> dict:
        """The constructor's keyword arguments (JSON-serialisable)."""
        return {"start": self.start, "step_down": list(self.steps_down), "target": self.target,
                "step_scale": self.step_scale, "min_intensity": self.min_intensity,
                "max_intensity": self.max_intensity, "discard_reversals": self.discard_reversals,
                **self._stop_config(), **self._new_keys()}

