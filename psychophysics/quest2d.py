"""QUEST+ over a two-dimensional stimulus (Watson 2017): a threshold that depends on a second stimulus dimension.

The stimulus of a trial is a pair ``(x, y)``: ``x`` the dimension the psychometric function rises along (a
transient's amplitude, a comparison's stiffness), ``y`` a second one on which the threshold depends (the
transient's frequency, the comparison's transient amplitude). The model is the contract's psychometric
function (:func:`psychophysics.psychometric.psi`) along ``x`` with a threshold that is a line in ``y``, floored:

.. math::

    \\psi(x, y) = \\gamma + (1 - \\gamma - \\lambda)\\, F\\bigl(x;\\ \\alpha(y), \\beta\\bigr), \\qquad
    \\log_{10} \\alpha(y) = \\max\\bigl(t_{min},\\ t_0 + t_1\\, y\\bigr)

(``threshold_scale = "linear"``: ``alpha(y)`` itself is the floored line). This is the form of Watson's
spatio-temporal contrast sensitivity example (2017, section 6, questplus's ``csf``) with one frequency axis:
on a log10 frequency axis ``t_1`` is the threshold's slope in decades per decade, the floor ``t_min`` the
lowest threshold; a vibrotactile detection threshold falling with frequency towards its Pacinian minimum, or
the stiffness a comparison needs to feel as hard as the reference as its transient grows (a trade-off line).

The parameters ``(t_0, t_1, t_min, beta, lambda)`` are a product grid (``floors`` may be left out: no floor);
the guess rate ``gamma`` is fixed. The prior is uniform over the grid. After every response the posterior is
multiplied by the response's likelihood (Bayes' rule) and the next stimulus is the grid pair that minimises
the expected entropy of the joint posterior; with a binary response that is ``H(post) - I(s)``, two
matrix-vector products over the (stimulus x parameter) table (as :class:`psychophysics.quest.QuestPlus`).

State, replay and resume are those of the 1-D methods (:mod:`psychophysics.adaptive`): :meth:`QuestPlus2D.state`
is the configuration plus every ``[x, y, correct]``; :meth:`QuestPlus2D.from_state` replays them through the
same arithmetic (the same bits) and refuses a state whose stored next stimulus the replay does not reach.
"""

from __future__ import annotations

import numpy as np
from scipy.special import entr

from plumbing.validation import is_finite_number, require_int, require_number

from .adaptive import build
from .psychometric import check_function, psi
from .quest import SPACINGS, _binary_entropy, _jsonable, make_grid, on_grid

#: the parameters of the model, in the order of the posterior's axes
PARAMETERS = ("intercept", "gain", "floor", "slope", "lapse")


class QuestPlus2D:
    """QUEST+ on a two-dimensional stimulus grid (module docstring).

    Parameters
    ----------
    x, y : list or dict
        The stimulus grids (a list, or ``{"min", "max", "n", "spacing"}``): ``x`` in the unit the
        psychometric function runs along (> 0 for the Weibull), ``y`` in the unit the threshold line is
        written in (e.g. log10 Hz).
    intercepts, gains : list or dict
        Grids of ``t_0`` and ``t_1`` (log10 units of ``x`` with ``threshold_scale = "log10"``; per unit of
        ``y``).
    slopes, lapses : list or dict
        Grids of ``beta`` (> 0) and ``lambda`` (in [0, 0.5); default the single value 0.02).
    floors : list, dict or None
        Grid of ``t_min`` (same unit as ``t_0``); None: no floor.
    guess : float
        ``gamma`` (1/n for n-AFC), fixed.
    function : {"logistic", "normal", "weibull"}
    threshold_scale : {"log10", "linear"}
        Whether the line gives ``log10 alpha`` or ``alpha``.
    max_trials : int
        Stopping rule.
    """

    name = "quest+2d"

    def __init__(self, x, y, intercepts, gains, slopes, lapses=(0.02,), floors=None, guess: float = 0.5,
                 function: str = "weibull", threshold_scale: str = "log10", max_trials: int = 200,
                 prefix: str = "") -> None:
        check_function(function, f"{prefix}function")
        require_number("guess", guess, minimum=0.0, prefix=prefix)
        if not guess < 1.0:
            raise ValueError(f"{prefix}guess must be in [0, 1), got {guess!r}")
        if threshold_scale not in SPACINGS:
            raise ValueError(f"{prefix}threshold_scale must be one of {', '.join(SPACINGS)}, got {threshold_scale!r}")
        self.max_trials = require_int("max_trials", max_trials, minimum=1, prefix=prefix)
        weib = function == "weibull"
        self.x = make_grid("x", x, positive=weib, prefix=prefix)
        self.y = make_grid("y", y, prefix=prefix)
        grids = {"intercept": make_grid("intercepts", intercepts, prefix=prefix),
                 "gain": make_grid("gains", gains, prefix=prefix),
                 "floor": (np.array([-np.inf]) if floors is None else make_grid("floors", floors, prefix=prefix)),
                 "slope": make_grid("slopes", slopes, positive=True, prefix=prefix),
                 "lapse": make_grid("lapses", lapses, unit_interval=True, prefix=prefix)}
        self.grids = grids
        self._spec = {"x": _jsonable(x), "y": _jsonable(y), "intercepts": _jsonable(intercepts),
                      "gains": _jsonable(gains), "slopes": _jsonable(slopes), "lapses": _jsonable(lapses),
                      "floors": None if floors is None else _jsonable(floors)}
        self.guess, self.function, self.threshold_scale = float(guess), function, threshold_scale
        self.shape = tuple(len(grids[p]) for p in PARAMETERS)
        line = self.threshold_line(self.y[:, None, None, None], grids["intercept"][None, :, None, None],
                                   grids["gain"][None, None, :, None], grids["floor"][None, None, None, :])
        if weib and not np.all(line > 0):
            raise ValueError(f"{prefix}the threshold line must stay > 0 for the Weibull on the grids given "
                             "(use threshold_scale = \"log10\")")
        # (x, y, t0, t1, floor, slope, lapse): probability correct per stimulus pair and parameter set, both
        # flattened in C order (x before y; the parameters in PARAMETERS' order)
        pc = psi(self.x[:, None, None, None, None, None, None], line[None, :, :, :, :, None, None],
                 grids["slope"][None, None, None, None, None, :, None], self.guess,
                 grids["lapse"][None, None, None, None, None, None, :], function)
        self.p_correct = np.ascontiguousarray(pc.reshape(len(self.x) * len(self.y), -1))
        self.p_wrong = 1.0 - self.p_correct
        self._tables = np.vstack([self.p_correct, _binary_entropy(self.p_correct)])
        k = self.p_correct.shape[1]
        self.posterior = np.full(k, 1.0 / k)
        #: ``[x, y, correct]`` of every trial, in order
        self.history: list[list] = []
        self._next = self._choose()

    # -- the model ------------------------------------------------------------------------------------------
    def threshold_line(self, y, intercept, gain, floor=-np.inf):
        """``alpha(y)`` of the model (module docstring), broadcasting; in ``x``'s unit."""
        t = np.maximum(floor, intercept + gain * np.asarray(y, dtype=float))
        return 10.0 ** t if self.threshold_scale == "log10" else t

    def config(self) -> dict:
        """The constructor's keyword arguments (JSON-serialisable)."""
        return {**self._spec, "guess": self.guess, "function": self.function,
                "threshold_scale": self.threshold_scale, "max_trials": self.max_trials}

    # -- the interface of the adaptive methods, with a pair for the intensity ----------------------------------
    @property
    def finished(self) -> bool:
        """True once ``max_trials`` trials are done."""
        return len(self.history) >= self.max_trials

    @property
    def trials(self) -> int:
        """Number of trials so far."""
        return len(self.history)

    def next_stimulus(self) -> tuple[float, float]:
        """The ``(x, y)`` of the next trial (unchanged until :meth:`update`)."""
        i, j = divmod(self._next, len(self.y))
        return float(self.x[i]), float(self.y[j])

    def expected_entropy(self) -> np.ndarray:
        """Expected posterior entropy (nats) after a trial at each stimulus pair, shape ``(len(x), len(y))``."""
        n = self.p_correct.shape[0]
        prod = self._tables @ self.posterior
        pc = np.clip(prod[:n], 0.0, 1.0)
        h = float(np.sum(entr(self.posterior))) - _binary_entropy(pc) + prod[n:]
        return h.reshape(len(self.x), len(self.y))

    def _choose(self) -> int:
        return int(np.argmin(self.expected_entropy()))

    def _index(self, grid: np.ndarray, value: float, axis: str) -> int:
        i = int(np.argmin(np.abs(grid - value)))
        if not on_grid(float(grid[i]), value):
            raise ValueError(f"{self.name}: {axis} = {value!r} is not on the stimulus grid "
                             f"({grid[0]:g}..{grid[-1]:g}, {len(grid)} values)")
        return i

    def update(self, x: float, y: float, correct: bool) -> None:
        """Record one trial's response at the stimulus ``(x, y)`` presented, and choose the next.

        Raises
        ------
        ValueError
            A value not finite or off the grid, ``correct`` not a boolean or 0/1, the method finished, or a
            response impossible under every function of the grid.
        """
        if not (is_finite_number(x) and is_finite_number(y)):
            raise ValueError(f"{self.name}: a trial's stimulus must be finite numbers, got ({x!r}, {y!r})")
        if not (isinstance(correct, (bool, np.bool_)) or (isinstance(correct, int) and correct in (0, 1))):
            raise ValueError(f"{self.name}: a response must be correct (1) or not (0), got {correct!r}")
        if self.finished:
            raise ValueError(f"{self.name}: the method finished after {len(self.history)} trials; no more updates")
        k = self._index(self.x, float(x), "x") * len(self.y) + self._index(self.y, float(y), "y")
        post = self.posterior * (self.p_correct[k] if correct else self.p_wrong[k])
        total = post.sum()
        if not total > 0.0:
            raise ValueError(f"{self.name}: a {'correct' if correct else 'wrong'} response at ({x!r}, {y!r}) is "
                             "impossible under every function of the grid; give the lapse grid a value > 0")
        self.posterior = post / total
        self.history.append([float(x), float(y), bool(correct)])
        self._next = self._choose()

    # -- estimates --------------------------------------------------------------------------------------------
    def marginals(self) -> dict:
        """The marginal posterior of each parameter over its grid (each sums to 1), by name."""
        p = self.posterior.reshape(self.shape)
        return {name: p.sum(axis=tuple(a for a in range(len(PARAMETERS)) if a != k))
                for k, name in enumerate(PARAMETERS)}

    def estimate(self) -> dict:
        """Posterior estimates of every parameter.

        Returns
        -------
        dict
            Per parameter (``intercept``, ``gain``, ``floor`` (absent without floors), ``slope``, ``lapse``):
            its posterior mean, and ``<name>_sd`` and ``<name>_ci`` (the 2.5 % and 97.5 % points of its
            marginal posterior, grid values); ``map`` (the joint mode), ``threshold`` (the posterior mean
            threshold ``alpha(y)`` at every ``y`` of the grid: geometric with ``threshold_scale = "log10"``),
            ``guess``, ``trials``.
        """
        out = {}
        for name, pm in self.marginals().items():
            grid = self.grids[name]
            if name == "floor" and not np.isfinite(grid[0]):
                continue
            m = float(pm @ grid)
            out[name] = m
            out[f"{name}_sd"] = float(np.sqrt(max(pm @ (grid - m) ** 2, 0.0)))
            out[f"{name}_ci"] = credible_interval(grid, pm)
        idx = np.unravel_index(int(np.argmax(self.posterior)), self.shape)
        out["map"] = {name: float(self.grids[name][i]) for name, i in zip(PARAMETERS, idx)
                      if not (name == "floor" and not np.isfinite(self.grids[name][0]))}
        g = self.grids
        line = self.threshold_line(self.y[:, None, None, None], g["intercept"][None, :, None, None],
                                   g["gain"][None, None, :, None], g["floor"][None, None, None, :])
        w = self.posterior.reshape(self.shape).sum(axis=(3, 4))          # (t0, t1, floor)
        t = np.log10(line) if self.threshold_scale == "log10" else line
        mean = np.einsum("yabc,abc->y", t, w)
        out["threshold"] = (10.0 ** mean if self.threshold_scale == "log10" else mean).tolist()
        out["guess"] = self.guess
        out["trials"] = self.trials
        return out

    # -- state and replay ---------------------------------------------------------------------------------------
    def state(self) -> dict:
        """The method as JSON: ``method``, ``config``, ``history`` (every ``[x, y, correct]``), ``trials``,
        ``finished``, ``next_stimulus``; :meth:`from_state` rebuilds it."""
        return {"method": self.name, "config": self.config(), "history": [list(h) for h in self.history],
                "trials": self.trials, "finished": self.finished, "next_stimulus": list(self.next_stimulus())}

    @classmethod
    def from_state(cls, state: dict) -> "QuestPlus2D":
        """Rebuild from :meth:`state` by replaying its history (exact: the same bits).

        Raises
        ------
        ValueError
            Not a state of this method, a malformed trial, or a replay that does not end at the stored next
            stimulus (a state written by another version).
        """
        if not isinstance(state, dict) or not isinstance(state.get("config"), dict):
            raise ValueError("a quest+2d state must be a dict with 'method', 'config' and 'history', "
                             f"got {type(state).__name__}")
        if state.get("method") != cls.name:
            raise ValueError(f"state is of method {state.get('method')!r}, not {cls.name!r}")
        method = build(cls, state["config"], f"{cls.name} state config.")
        history = state.get("history", [])
        if not isinstance(history, list):
            raise ValueError(f"{cls.name} state: 'history' must be a list of [x, y, correct]")
        for i, trial in enumerate(history, 1):
            if not (isinstance(trial, (list, tuple)) and len(trial) == 3):
                raise ValueError(f"{cls.name} state: history trial {i} must be [x, y, correct], got {trial!r}")
            method.update(*trial)
        stored = state.get("next_stimulus")
        if stored is not None and list(stored) != list(method.next_stimulus()):
            raise ValueError(f"{cls.name} state does not replay: it stores next stimulus {stored!r} but the "
                             f"replayed method proposes {list(method.next_stimulus())!r} (written by another version?)")
        return method

    @classmethod
    def from_table(cls, table: dict, prefix: str = "") -> "QuestPlus2D":
        """Build from a protocol table (the constructor's keywords); an unknown or missing key is one ValueError
        naming it with ``prefix``."""
        if not isinstance(table, dict):
            raise ValueError(f"{prefix or 'the method '}must be a table, got {type(table).__name__}")
        return build(cls, {k: v for k, v in table.items() if k != "method"}, prefix)


def credible_interval(grid: np.ndarray, mass: np.ndarray, level: float = 0.95) -> list[float]:
    """The central credible interval of a marginal posterior on a grid, each grid value standing for the cell
    from the midpoints to its neighbours (the outer cells as wide as their inner half, doubled): the
    cumulative mass is interpolated linearly over the cell edges. Grid points alone make the interval jump
    by whole steps and, once the posterior sits on two or three points, too narrow (measured: 15 of 20
    intervals covered the truth in the recovery test, 19 of 20 with cells).

    Returns
    -------
    [float, float]
        A single grid value gives ``[value, value]``.
    """
    grid = np.asarray(grid, dtype=float)
    if len(grid) == 1:
        return [float(grid[0]), float(grid[0])]
    mid = 0.5 * (grid[1:] + grid[:-1])
    edges = np.concatenate([[grid[0] - (mid[0] - grid[0])], mid, [grid[-1] + (grid[-1] - mid[-1])]])
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    cdf /= cdf[-1]
    tail = 0.5 * (1.0 - level)
    lo, hi = np.interp([tail, 1.0 - tail], cdf, edges)
    return [float(lo), float(hi)]


def simulate_response(rng: np.random.Generator, x: float, y: float, *, intercept: float, gain: float,
                      slope: float, lapse: float = 0.02, floor: float = -np.inf, guess: float = 0.5,
                      function: str = "weibull", threshold_scale: str = "log10") -> bool:
    """A simulated observer's answer at ``(x, y)``: correct with the model's probability (module docstring)."""
    t = max(floor, intercept + gain * y)
    alpha = 10.0 ** t if threshold_scale == "log10" else t
    return bool(rng.random() < float(psi(x, alpha, slope, guess, lapse, function)))
