"""Bayesian adaptive methods on a parameter grid: QUEST+ (Watson 2017) and Psi (Kontsevich & Tyler 1999).

Both keep a posterior over a grid of psychometric functions of the contract
(:func:`psychophysics.psychometric.psi`: threshold x slope x lapse, guess rate fixed at ``1/n``), multiply it by
the likelihood of each response (Bayes' rule) and put the next trial at the intensity of the stimulus grid
whose outcome is expected to leave the least posterior entropy:

* **QUEST+** (Watson 2017, *J. Vision* 17(3):10): the entropy of the joint posterior over all parameters.
  For a binary response the expected entropy is ``H(post) - I(s)`` with the mutual information
  ``I(s) = h(P_c(s)) - sum_k post_k h(psi_k(s))`` (``h`` the binary entropy, ``P_c`` the predicted
  probability correct), so one update is two matrix-vector products over the (stimulus x parameter) grid.
* **Psi** (Kontsevich & Tyler 1999, *Vision Res.* 39:2729-2737): the entropy of the posterior over
  threshold and slope. With more than one lapse rate in the grid, the lapse is a nuisance parameter that is
  marginalised out before the entropy is taken (the psi-marginal method, Prins 2013, *J. Vision* 13(7):3),
  so trials are not spent on pinning the lapse down; with one lapse rate it is Kontsevich & Tyler's method.

The prior is uniform over the grid (uniform in log threshold when the threshold grid is log-spaced) unless
``prior`` gives one per parameter (weights over its grid, or a Gaussian ``{"mean", "sd", "scale"}``); the
joint prior is their product (questplus's convention). The method stops on ``max_trials``, ``max_reversals``
or, with ``stop_sd``, once the threshold's posterior SD falls to it. ``choose_among = n > 1`` puts each trial
at one of the n intensities of lowest expected entropy, drawn at random (questplus's ``min_n_entropy``, with
its ``max_consecutive_reps`` as ``max_repeats``): a track that cannot be anticipated. The
estimates are posterior means (in log10 units with ``threshold_scale="log10"``: a geometric mean) with
95 % credible intervals from the marginal posterior; the maximum a posteriori parameters are reported too.
The state is the configuration plus the trial history (:class:`psychophysics.adaptive.AdaptiveMethod`): the
posterior is rebuilt by replaying the updates in the same order, which gives the same bits.

A grid is given either as a list of values or as ``{"min": a, "max": b, "n": k, "spacing": "log10"}``
(``"linear"`` for evenly spaced values).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import entr

from plumbing.validation import require_int, require_number

from .adaptive import AdaptiveMethod
from .psychometric import check_function, psi, sigmoid

#: grid spacings of a ``{"min", "max", "n", "spacing"}`` grid
SPACINGS = ("log10", "linear")


def make_grid(name: str, spec, *, positive: bool = False, unit_interval: bool = False,
              prefix: str = "") -> np.ndarray:
    """A parameter or stimulus grid from a list of numbers or a ``{"min", "max", "n", "spacing"}`` table.

    Parameters
    ----------
    name : str
        Key in the protocol table (for messages).
    spec : list of float or dict
        Values, or ``{"min": float, "max": float, "n": int, "spacing": "log10" | "linear"}``.
    positive : bool
        Require every value > 0.
    unit_interval : bool
        Require every value in [0, 0.5) (a lapse rate).
    prefix : str
        Put before ``name`` in messages.

    Returns
    -------
    ndarray, shape (k,)
        Strictly increasing values.

    Raises
    ------
    ValueError
        Naming ``prefix + name`` and what is wrong.
    """
    if isinstance(spec, dict):
        unknown = set(spec) - {"min", "max", "n", "spacing"}
        if unknown:
            raise ValueError(f"{prefix}{name} has unknown key(s) {sorted(unknown)}; a grid is "
                             "{min, max, n, spacing} or a list of values")
        for key in ("min", "max", "n"):
            if key not in spec:
                raise ValueError(f"{prefix}{name}.{key} is missing (a grid is {{min, max, n, spacing}})")
        spacing = spec.get("spacing", "log10")
        if spacing not in SPACINGS:
            raise ValueError(f"{prefix}{name}.spacing must be one of {', '.join(SPACINGS)}, got {spacing!r}")
        lo = require_number("min", spec["min"], minimum=0.0 if spacing == "log10" else None, strict=True,
                            prefix=f"{prefix}{name}.")
        hi = require_number("max", spec["max"], prefix=f"{prefix}{name}.")
        n = require_int("n", spec["n"], minimum=1, prefix=f"{prefix}{name}.")
        if n > 1 and not hi > lo:
            raise ValueError(f"{prefix}{name}.max must be > {prefix}{name}.min, got {hi!r} <= {lo!r}")
        values = np.geomspace(lo, hi, n) if spacing == "log10" else np.linspace(lo, hi, n)
    elif isinstance(spec, (list, tuple)) and spec:
        for i, v in enumerate(spec):
            require_number(f"{name}[{i}]", v, prefix=prefix)
        values = np.asarray(spec, dtype=float)
        if np.any(np.diff(values) <= 0):
            raise ValueError(f"{prefix}{name} must be strictly increasing, got {list(spec)!r}")
    else:
        raise ValueError(f"{prefix}{name} must be a non-empty list of numbers or a {{min, max, n, spacing}} "
                         f"table, got {spec!r}")
    if positive and values[0] <= 0:
        raise ValueError(f"{prefix}{name} values must be > 0, got {values[0]!r}")
    if unit_interval and (values[0] < 0 or values[-1] >= 0.5):
        raise ValueError(f"{prefix}{name} values must be in [0, 0.5), got {values.tolist()!r}")
    return values


def _jsonable(spec):
    """A grid spec as plain JSON types (lists of float, or the table as given)."""
    if isinstance(spec, dict):
        return dict(spec)
    return [float(v) for v in spec]


PRIOR_KEYS = ("thresholds", "slopes", "lapses")


def _prior_jsonable(prior, prefix: str) -> dict:
    if not isinstance(prior, dict):
        raise ValueError(f"{prefix}prior must be a table of thresholds, slopes and lapses, got {prior!r}")
    unknown = set(prior) - set(PRIOR_KEYS)
    if unknown:
        raise ValueError(f"{prefix}prior.{sorted(unknown)[0]} is not a parameter (the prior is over "
                         f"{', '.join(PRIOR_KEYS)})")
    return {key: (dict(v) if isinstance(v, dict) else [float(x) for x in v]) for key, v in prior.items()}


def prior_weights(name: str, spec, values: np.ndarray, log_scale: bool, prefix: str = "") -> np.ndarray:
    """One parameter's prior over its grid ``values``: a list of weights (one per value, >= 0), or a Gaussian
    ``{"mean": m, "sd": s, "scale": "linear" | "log10"}`` (log10: of log10 of the values; default the
    threshold's scale for thresholds, linear otherwise); normalised to sum 1."""
    where = f"{prefix}prior.{name}"
    if isinstance(spec, dict):
        unknown = set(spec) - {"mean", "sd", "scale"}
        if unknown:
            raise ValueError(f"{where} has unknown key(s) {sorted(unknown)}; a Gaussian prior is "
                             "{mean, sd, scale}")
        for key in ("mean", "sd"):
            if key not in spec:
                raise ValueError(f"{where}.{key} is missing (a Gaussian prior is {{mean, sd, scale}})")
        mean = require_number("mean", spec["mean"], prefix=f"{where}.")
        sd = require_number("sd", spec["sd"], minimum=0.0, strict=True, prefix=f"{where}.")
        scale = spec.get("scale", "log10" if log_scale else "linear")
        if scale not in SPACINGS:
            raise ValueError(f"{where}.scale must be one of {', '.join(SPACINGS)}, got {scale!r}")
        if scale == "log10" and values[0] <= 0:
            raise ValueError(f"{where}.scale log10 needs values > 0, got {values[0]!r}")
        v = np.log10(values) if scale == "log10" else values
        w = np.exp(-0.5 * ((v - mean) / sd) ** 2)
    elif isinstance(spec, (list, tuple)):
        if len(spec) != len(values):
            raise ValueError(f"{where} has {len(spec)} weights for {len(values)} grid values")
        for i, x in enumerate(spec):
            require_number(f"{name}[{i}]", x, minimum=0.0, prefix=f"{prefix}prior.")
        w = np.asarray(spec, dtype=float)
    else:
        raise ValueError(f"{where} must be a list of weights or a {{mean, sd, scale}} table, got {spec!r}")
    if not w.sum() > 0:
        raise ValueError(f"{where} gives every grid value zero weight")
    return w / w.sum()


def joint_prior(prior: dict, grids: dict, threshold_scale: str, prefix: str = "") -> np.ndarray:
    """The joint prior over (threshold, slope, lapse), flattened like the posterior: the product of the
    parameters' priors (uniform for a parameter not given)."""
    _prior_jsonable(prior, prefix)
    parts = [prior_weights(key, prior[key], grids[key], key == "thresholds" and threshold_scale == "log10", prefix)
             if key in prior else np.full(len(grids[key]), 1.0 / len(grids[key])) for key in PRIOR_KEYS]
    joint = parts[0][:, None, None] * parts[1][None, :, None] * parts[2][None, None, :]
    return (joint / joint.sum()).ravel()


class _GridPosterior(AdaptiveMethod):
    """The Bayesian grid engine of :class:`QuestPlus` and :class:`Psi` (module docstring).

    Parameters
    ----------
    intensities : list or dict
        Stimulus grid: the intensities a trial may have (the method's unit).
    thresholds, slopes, lapses : list or dict
        Parameter grids (``lapses`` in [0, 0.5); default the single value 0.02).
    guess : float
        Guess rate ``gamma`` (1/n for n-AFC), fixed.
    function : {"logistic", "normal", "weibull"}
    threshold_scale : {"log10", "linear"}
        How the threshold's posterior mean and SD are taken (log10: geometric mean, SD in log10 units).
    max_trials, max_reversals : int or None
        Stopping rule.
    prior : dict or None
        ``thresholds``, ``slopes``, ``lapses`` -> weights over the grid or ``{mean, sd, scale}``
        (:func:`prior_weights`); None: uniform.
    stop_sd : float or None
        Also stop once the threshold's posterior SD (log10 units on a log10 threshold scale) is at most
        this (needs ``max_trials`` as a cap).
    choose_among : int
        1: the intensity of lowest expected entropy; n > 1: one of the n lowest at random (seeded).
    max_repeats : int
        With ``choose_among > 1``: at most this many trials in a row at one intensity.
    seed : int
        The random choice's seed.
    """

    def __init__(self, intensities, thresholds, slopes, lapses=(0.02,), guess: float = 0.5,
                 function: str = "weibull", threshold_scale: str = "log10", max_trials: int | None = None,
                 max_reversals: int | None = None, prior: dict | None = None, stop_sd: float | None = None,
                 choose_among: int = 1, max_repeats: int = 2, seed: int = 0, prefix: str = ""):
        super().__init__(max_trials, max_reversals, prefix)
        check_function(function, f"{prefix}function")
        require_number("guess", guess, minimum=0.0, prefix=prefix)
        if not guess < 1.0:
            raise ValueError(f"{prefix}guess must be in [0, 1), got {guess!r}")
        if threshold_scale not in SPACINGS:
            raise ValueError(f"{prefix}threshold_scale must be one of {', '.join(SPACINGS)}, "
                             f"got {threshold_scale!r}")
        require_number("stop_sd", stop_sd, minimum=0.0, strict=True, optional=True, prefix=prefix)
        if stop_sd is not None and max_trials is None:
            raise ValueError(f"{prefix}stop_sd needs {prefix}max_trials too (a cap for an observer whose "
                             "threshold never gets that precise)")
        self.choose_among = require_int("choose_among", choose_among, minimum=1, prefix=prefix)
        self.max_repeats = require_int("max_repeats", max_repeats, minimum=1, prefix=prefix)
        self.seed = require_int("seed", seed, minimum=0, prefix=prefix)
        self.stop_sd = None if stop_sd is None else float(stop_sd)
        weib = function == "weibull"
        self.x = make_grid("intensities", intensities, positive=weib, prefix=prefix)
        self.t = make_grid("thresholds", thresholds, positive=weib or threshold_scale == "log10", prefix=prefix)
        self.s = make_grid("slopes", slopes, positive=True, prefix=prefix)
        self.lam = make_grid("lapses", lapses, unit_interval=True, prefix=prefix)
        self._spec = {"intensities": _jsonable(intensities), "thresholds": _jsonable(thresholds),
                      "slopes": _jsonable(slopes), "lapses": _jsonable(lapses)}
        self.guess, self.function, self.threshold_scale = float(guess), function, threshold_scale
        self.shape = (len(self.t), len(self.s), len(self.lam))
        pc = psi(self.x[:, None, None, None], self.t[None, :, None, None], self.s[None, None, :, None],
                 self.guess, self.lam[None, None, None, :], function)
        #: probability correct per (stimulus, parameter set), parameters flattened in C order (t, s, lapse)
        self.p_correct = np.ascontiguousarray(pc.reshape(len(self.x), -1))
        self.p_wrong = 1.0 - self.p_correct
        k = self.p_correct.shape[1]
        self._prior_spec = None if prior is None else _prior_jsonable(prior, prefix)
        if prior is None:
            self.posterior = np.full(k, 1.0 / k)
        else:
            self.posterior = joint_prior(prior, {"thresholds": self.t, "slopes": self.s, "lapses": self.lam},
                                         threshold_scale, prefix)
        # questplus's min_n_entropy draws with numpy's legacy generator: the same draws, the same choices
        self._rng = np.random.RandomState(self.seed) if self.choose_among > 1 else None
        self._applying = None
        self._prepare()
        self._next_index = self._choose()
        self._sd = self._threshold_sd()

    def config(self) -> dict:
        """The constructor's keyword arguments (JSON-serialisable; the optional ones only when set)."""
        out = {**self._spec, "guess": self.guess, "function": self.function,
               "threshold_scale": self.threshold_scale, **self._stop_config()}
        if self._prior_spec is not None:
            out["prior"] = self._prior_spec
        if self.stop_sd is not None:
            out["stop_sd"] = self.stop_sd
        if self.choose_among > 1:
            out.update(choose_among=self.choose_among, max_repeats=self.max_repeats, seed=self.seed)
        return out

    @property
    def finished(self) -> bool:
        """True once ``max_trials`` or ``max_reversals`` is reached, or the threshold's posterior SD falls to
        ``stop_sd``."""
        return super().finished or (self.stop_sd is not None and self._sd <= self.stop_sd)

    def _threshold_sd(self) -> float:
        pt = self.posterior.reshape(self.shape).sum(axis=(1, 2))
        tt = np.log10(self.t) if self.threshold_scale == "log10" else self.t
        m = float(pt @ tt)
        return float(np.sqrt(max(pt @ (tt - m) ** 2, 0.0)))

    def _select(self, expected: np.ndarray) -> int:
        """The stimulus index of lowest expected entropy, or one of the ``choose_among`` lowest at random
        (never the same intensity more than ``max_repeats`` times in a row while another is possible)."""
        if self._rng is None:
            return int(np.argmin(expected))
        candidates = np.argsort(expected)[:self.choose_among]
        # the trials so far, the one being applied included (history gets it after _apply)
        shown = self.intensities + ([self._applying] if self._applying is not None else [])
        recent = shown[-self.max_repeats:]
        while True:
            i = int(self._rng.choice(candidates))
            if len(shown) < 2 or len(candidates) < 2 or not all(self.x[i] == x for x in recent):
                return i

    def _prepare(self) -> None:
        """Precompute what the stimulus choice needs (subclasses)."""

    def _choose(self) -> int:
        """Index into the stimulus grid of the next trial (subclasses)."""
        raise NotImplementedError

    def _index(self, intensity: float) -> int:
        i = int(np.argmin(np.abs(self.x - intensity)))
        if not on_grid(float(self.x[i]), intensity):
            raise ValueError(f"{self.name}: intensity {intensity!r} is not on the stimulus grid "
                             f"({self.x[0]:g}..{self.x[-1]:g}, {len(self.x)} values)")
        return i

    def _apply(self, intensity: float, correct: bool) -> None:
        i = self._index(intensity)
        post = self.posterior * (self.p_correct[i] if correct else self.p_wrong[i])
        total = post.sum()
        if not total > 0.0:
            # every function of the grid gives this response probability 0 (no lapse, no guessing): the posterior
            # would be 0/0, NaN, and the next intensity garbage
            raise ValueError(f"{self.name}: a {'correct' if correct else 'wrong'} response at {intensity!r} is "
                             "impossible under every psychometric function of the grid; give the lapse grid a "
                             "value > 0 (or a guess rate > 0)")
        self.posterior = post / total
        self._applying = intensity
        self._next_index = self._choose()
        self._applying = None
        self._sd = self._threshold_sd()

    def _proposal(self) -> float:
        return self.x[self._next_index]

    def marginals(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Marginal posteriors over the threshold, slope and lapse grids (each sums to 1)."""
        p = self.posterior.reshape(self.shape)
        return p.sum(axis=(1, 2)), p.sum(axis=(0, 2)), p.sum(axis=(0, 1))

    def estimate(self) -> dict:
        """Posterior estimates of the psychometric function's parameters.

        Returns
        -------
        dict
            ``threshold`` (posterior mean; geometric with ``threshold_scale="log10"``), ``threshold_sd``
            (log10 units with log10 scale), ``threshold_ci`` ([2.5 %, 97.5 %] of the marginal posterior),
            ``slope``, ``lapse`` (posterior means), ``guess``, ``map`` (``threshold``, ``slope``, ``lapse`` of
            the posterior's mode), ``trials``, ``reversals``.
        """
        pt, ps, pl = self.marginals()
        tt = np.log10(self.t) if self.threshold_scale == "log10" else self.t
        m = float(pt @ tt)
        sd = float(np.sqrt(max(pt @ (tt - m) ** 2, 0.0)))
        cdf = np.cumsum(pt)
        lo = self.t[min(int(np.searchsorted(cdf, 0.025)), len(self.t) - 1)]
        hi = self.t[min(int(np.searchsorted(cdf, 0.975)), len(self.t) - 1)]
        it, is_, il = np.unravel_index(int(np.argmax(self.posterior)), self.shape)
        return {"threshold": 10.0 ** m if self.threshold_scale == "log10" else m, "threshold_sd": sd,
                "threshold_mode": self._marginal_mode(pt),
                "threshold_ci": [float(lo), float(hi)], "slope": float(ps @ self.s), "lapse": float(pl @ self.lam),
                "guess": self.guess,
                "map": {"threshold": float(self.t[it]), "slope": float(self.s[is_]), "lapse": float(self.lam[il])},
                "trials": self.trials, "reversals": len(self.reversal_intensities)}


    def _marginal_mode(self, pt: np.ndarray) -> float:
        """Mode of the threshold marginal ``pt``, refined between grid points (log-parabola; in log10 units on
        a log10 scale); the grid point itself at the grid's ends or on an uneven grid."""
        j = int(np.argmax(pt))
        tt = np.log10(self.t) if self.threshold_scale == "log10" else self.t
        if 0 < j < len(pt) - 1 and np.isclose(tt[j + 1] - tt[j], tt[j] - tt[j - 1], rtol=1e-6):
            a, b, c = np.log(np.maximum(pt[j - 1:j + 2], 1e-300))
            curv = a - 2.0 * b + c
            shift = 0.5 * (a - c) / curv if curv < 0 else 0.0
            t = tt[j] + float(np.clip(shift, -0.5, 0.5)) * (tt[j + 1] - tt[j])
            return 10.0 ** t if self.threshold_scale == "log10" else t
        return float(self.t[j])


def on_grid(value: float, target: float) -> bool:
    """``np.isclose(value, target, rtol=1e-9, atol=0)`` for two floats, as plain float arithmetic (the same
    test, without the ~10 us of the array call on every trial)."""
    if not (math.isfinite(value) and math.isfinite(target)):
        return bool(np.isclose(value, target, rtol=1e-9, atol=0.0))
    return abs(value - target) <= 1e-9 * abs(target) or value == target


def _binary_entropy(p: np.ndarray) -> np.ndarray:
    """Entropy (nats) of a Bernoulli(p), 0 at p = 0 and 1."""
    return entr(p) + entr(1.0 - p)


def _neg_xlogx_sum(a: np.ndarray, work: np.ndarray | None = None) -> np.ndarray:
    """``-sum(a * log(a))`` over the last axis, with ``0 log 0 = 0`` (faster than ``scipy.special.entr``);
    ``work``, an array of ``a``'s shape, holds the logarithms (no allocation per call)."""
    logs = np.maximum(a, 1e-300, out=work)
    return -np.einsum("ij,ij->i", a, np.log(logs, out=logs))


class QuestPlus(_GridPosterior):
    """QUEST+ (Watson 2017, *J. Vision* 17(3):10) on a threshold x slope x lapse grid: the next intensity
    minimises the expected entropy of the joint posterior (module docstring for the arithmetic).

    Parameters are those of the grid engine: ``intensities``, ``thresholds``, ``slopes``, ``lapses``,
    ``guess``, ``function``, ``threshold_scale``, ``max_trials``, ``max_reversals``, ``prior``, ``stop_sd``,
    ``choose_among``, ``max_repeats``, ``seed``.
    """

    name = "quest+"

    def _prepare(self) -> None:
        # the expected entropy is H(post) - h(P_c(s)) + sum_k post_k h(psi_k(s)); both s-dependent parts are
        # products of a (stimulus x parameter) table with the posterior, stacked to read the tables once
        self._tables = np.vstack([self.p_correct, _binary_entropy(self.p_correct)])

    def expected_entropy(self) -> np.ndarray:
        """Expected posterior entropy (nats) after a trial at each intensity of the grid, shape (n_stim,)."""
        n = len(self.x)
        prod = self._tables @ self.posterior
        pc = np.clip(prod[:n], 0.0, 1.0)
        return float(np.sum(entr(self.posterior))) - _binary_entropy(pc) + prod[n:]

    def _choose(self) -> int:
        return self._select(self.expected_entropy())


class Psi(_GridPosterior):
    """Psi (Kontsevich & Tyler 1999, *Vision Res.* 39:2729-2737), lapse marginalised when it has several
    values (psi-marginal, Prins 2013, *J. Vision* 13(7):3): the next intensity minimises the expected
    entropy of the posterior over threshold and slope.

    Parameters are those of the grid engine: ``intensities``, ``thresholds``, ``slopes``, ``lapses``,
    ``guess``, ``function``, ``threshold_scale``, ``max_trials``, ``max_reversals``, ``prior``, ``stop_sd``,
    ``choose_among``, ``max_repeats``, ``seed``.
    """

    name = "psi"

    def _prepare(self) -> None:
        # psi = gamma + (1 - gamma - lambda) F(x; t, s): summed over the lapse rates with the posterior,
        # P(correct, t, s | x) = gamma m(t, s) + F(x; t, s) w(t, s) with m the (t, s) marginal and
        # w = sum_l (1 - gamma - lambda_l) post(t, s, l), so the choice costs one (stimulus x t-s) table
        # whatever the number of lapse rates
        f = sigmoid(self.x[:, None, None], self.t[None, :, None], self.s[None, None, :], self.function)
        self._sigmoid = np.ascontiguousarray(f.reshape(len(self.x), -1))
        self._lapse_scale = 1.0 - self.guess - self.lam
        # (stimulus x t-s) work arrays reused by every choice: the same arithmetic without three allocations
        self._work = np.empty((3,) + self._sigmoid.shape)

    def expected_entropy(self) -> np.ndarray:
        """Expected entropy (nats) of the threshold x slope posterior after a trial at each intensity."""
        post = self.posterior.reshape(-1, self.shape[2])
        marginal = post.sum(axis=1)
        joint_c, joint_w, work = self._work
        np.multiply(self._sigmoid, post @ self._lapse_scale, out=joint_c)
        np.add(self.guess * marginal, joint_c, out=joint_c)                             # P(correct, t, s | x)
        np.clip(np.subtract(marginal, joint_c, out=joint_w), 0.0, None, out=joint_w)
        p_c = joint_c.sum(axis=1)
        p_w = joint_w.sum(axis=1)
        # P * H(J / P) = -sum_j J_j log J_j + P log P
        return _neg_xlogx_sum(joint_c, work) - entr(p_c) + _neg_xlogx_sum(joint_w, work) - entr(p_w)

    def _choose(self) -> int:
        return self._select(self.expected_entropy())
