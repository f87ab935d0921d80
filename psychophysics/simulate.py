"""An adaptive method against a simulated observer, once or R times (``python -m study simulate-observer``).

Answers the planning question asked before a study: with this method, how many trials give what precision?
One run gives the trial track and the method's estimate; ``repeat`` runs (seeds ``seed .. seed+R-1``)
give the error of the estimate after every ``checkpoint`` trials (:func:`precision_table`).

Defaults when the user gives only the threshold ``T`` (docs/psychophysics.md):

* observer: Weibull (the contract's, threshold at F = 0.5), slope 3.5 (QUEST's default for detection,
  Watson & Pelli 1983, *Percept. Psychophys.* 33(2):113-120; May & Solomon 2013 report 2-5 for 2AFC
  detection), lapse 0.02, 2 alternatives (guess 1/2);
* stimulus range ``T/10 .. 10 T``, 41 log-spaced levels (0.05 log10 units apart);
* staircases start at the top of the range (the easy end) with log10 steps 0.4, 0.2, then 0.1 after the
  second reversal; ``updown`` is 1-up-2-down (tracks the 70.7 % point), ``weighted`` tracks the point
  midway between chance and 1 (0.75 in 2AFC);
* QUEST+ and Psi: thresholds on the stimulus grid, Weibull slopes 0.7..10 (12 log-spaced: beyond the
  range of 2AFC detection and discrimination slopes on both sides, so that a shallow observer's slope is
  inside the grid, not at its edge), lapses 0, 0.02, ..., 0.1 (Psi marginalises the lapse), with priors:
  log10 slope Gaussian around log10 3 (SD 0.5: the 2AFC range 2-5 at the centre, a factor 3 either way
  still likely) and lapse weights (1 - lambda)^9 (psignifit's Beta(1, 10)); with a flat grid ending at
  slope 1.5 and lapse 0.05, observers of slope 1.5 and lapse 0.05 were estimated 22-26 % high, with a
  flat wide grid typical observers lost precision (docs/psychophysics.md);
* 80 trials.

Each method's estimate is compared with its own target: the threshold ``T`` for QUEST+/Psi, the intensity
where the observer is correct with the staircase's target probability for ``updown``/``weighted``
(``reference`` in estimate.json).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from plumbing.validation import require_int, require_number

from .adaptive import AdaptiveMethod
from .methods import METHODS
from .observer import ObserverParams, SimulatedObserver, check_observer
from .quest import Psi, QuestPlus
from .staircase import UpDown, WeightedUpDown

#: documented defaults (module docstring)
DEFAULT_SLOPE = 3.5
DEFAULT_LAPSE = 0.02
DEFAULT_ALTERNATIVES = 2
DEFAULT_TRIALS = 80
#: the most trials of one run, runs, and trials in all (runs x trials): time and memory stay bounded (every run's
#: estimate after every 10 trials is kept for precision.csv); a planning question needs far fewer
MAX_TRIALS = 10_000
MAX_REPEAT = 10_000
MAX_TOTAL_TRIALS = 2_000_000
RANGE_FACTOR = 10.0
LEVELS = 41
STAIR_STEPS_LOG10 = [0.4, 0.2, 0.1]
SLOPE_GRID = {"min": 0.7, "max": 10.0, "n": 12, "spacing": "log10"}
LAPSE_GRID = [0.0, 0.02, 0.04, 0.06, 0.08, 0.1]
#: priors of QUEST+ and Psi (module docstring)
PRIOR = {"slopes": {"mean": math.log10(3.0), "sd": 0.5, "scale": "log10"},
         "lapses": [(1.0 - lam) ** 9 for lam in LAPSE_GRID]}
#: the command's flags, named in messages about the observer
FLAGS = {"threshold": "--threshold", "slope": "--slope", "lapse": "--lapse", "guess": "--alternatives",
         "function": "--function"}


@dataclass(frozen=True)
class SimulationSettings:
    """One simulate-observer run's settings (validated; messages name the command's flags).

    Attributes
    ----------
    method : str
        ``updown``, ``weighted``, ``quest+`` or ``psi``.
    threshold : float
        The observer's threshold (> 0; the intensity unit of the study).
    slope : float
        Weibull slope (shape) of the observer.
    lapse : float
        Lapse rate in [0, 0.5).
    alternatives : int
        n of the n-alternative forced choice (>= 2); guess rate 1/n.
    trials : int
        Trials per run.
    seed : int
        Seed of the first run (run r uses ``seed + r``).
    repeat : int
        Number of runs.
    intensity_min, intensity_max : float or None
        Stimulus range (default ``threshold / 10 .. 10 threshold``).
    """

    method: str
    threshold: float
    slope: float = DEFAULT_SLOPE
    lapse: float = DEFAULT_LAPSE
    alternatives: int = DEFAULT_ALTERNATIVES
    trials: int = DEFAULT_TRIALS
    seed: int = 0
    repeat: int = 1
    intensity_min: float | None = None
    intensity_max: float | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"--method must be one of {', '.join(METHODS)}, got {self.method!r}")
        require_int("--alternatives", self.alternatives, minimum=2)
        check_observer(self.threshold, self.slope, self.lapse, 1.0 / self.alternatives, "weibull", FLAGS)
        require_int("--trials", self.trials, minimum=1, maximum=MAX_TRIALS)
        require_int("--seed", self.seed, minimum=0)
        require_int("--repeat", self.repeat, minimum=1, maximum=MAX_REPEAT)
        if self.trials * self.repeat > MAX_TOTAL_TRIALS:
            raise ValueError(f"--trials x --repeat must be at most {MAX_TOTAL_TRIALS} trials in all, got "
                             f"{self.trials} x {self.repeat} = {self.trials * self.repeat}")
        require_number("--intensity-min", self.intensity_min, minimum=0.0, strict=True, optional=True)
        require_number("--intensity-max", self.intensity_max, minimum=0.0, strict=True, optional=True)
        if not self.range[1] > self.range[0]:
            raise ValueError(f"--intensity-max must be > --intensity-min, got {self.range[1]!r} <= {self.range[0]!r}")

    @property
    def range(self) -> tuple[float, float]:
        """Stimulus range (low, high), the method's unit."""
        lo = self.threshold / RANGE_FACTOR if self.intensity_min is None else self.intensity_min
        hi = self.threshold * RANGE_FACTOR if self.intensity_max is None else self.intensity_max
        return float(lo), float(hi)

    @property
    def observer(self) -> ObserverParams:
        """The simulated observer (Weibull, guess 1/alternatives)."""
        return ObserverParams(self.threshold, self.slope, self.lapse, 1.0 / self.alternatives, "weibull")


def make_method(s: SimulationSettings) -> AdaptiveMethod:
    """The adaptive method of ``s`` with the documented defaults (module docstring), stopping at ``s.trials``."""
    lo, hi = s.range
    guess = 1.0 / s.alternatives
    if s.method in ("updown", "weighted"):
        common = dict(start=hi, step_down=list(STAIR_STEPS_LOG10), step_scale="log10", min_intensity=lo,
                      max_intensity=hi, max_trials=s.trials)
        if s.method == "updown":
            return UpDown(n_down=2, n_up=1, **common)
        return WeightedUpDown(target=(1.0 + guess) / 2.0, **common)
    grid = {"min": lo, "max": hi, "n": LEVELS, "spacing": "log10"}
    cls = QuestPlus if s.method == "quest+" else Psi
    return cls(intensities=grid, thresholds=grid, slopes=dict(SLOPE_GRID), lapses=list(LAPSE_GRID), guess=guess,
               function="weibull", threshold_scale="log10", max_trials=s.trials,
               prior={key: (dict(v) if isinstance(v, dict) else list(v)) for key, v in PRIOR.items()})


def reference_intensity(method: AdaptiveMethod, observer: ObserverParams) -> float:
    """What the method's estimate should equal for this observer: the threshold (QUEST+/Psi) or the
    intensity at the staircase's target probability (up-down methods)."""
    if isinstance(method, UpDown):
        return observer.intensity_at(method.target_probability())
    return observer.threshold


def run_once(s: SimulationSettings, seed: int, checkpoints=()) -> dict:
    """One run: the method against the observer (seeded), with estimates at the ``checkpoints`` trials.

    Returns
    -------
    dict
        ``method`` (the finished AdaptiveMethod), ``track`` (rows: trial, intensity, correct,
        p_correct_true, reversal), ``estimate`` (final), ``at`` ({trials: threshold estimate}).
    """
    method = make_method(s)
    observer = SimulatedObserver(s.observer, seed)
    at, track = {}, []
    want = set(checkpoints)
    while not method.finished:
        x = method.next_intensity()
        correct = observer.respond(x)
        method.update(x, correct)
        track.append({"trial": method.trials, "intensity": x, "correct": int(correct),
                      "p_correct_true": float(s.observer.p_correct(x)),
                      "reversal": int(method.last_trial_reversal)})
        if method.trials in want:
            at[method.trials] = method.estimate()["threshold"]
    return {"method": method, "track": track, "estimate": method.estimate(), "at": at}


def checkpoints_for(trials: int) -> list[int]:
    """Trial counts at which precision is tabulated: every 10 trials (every trial below 10) and the last."""
    step = 10 if trials >= 10 else 1
    return sorted(set(range(step, trials + 1, step)) | {trials})


def precision_table(errors: dict, within: float = 0.2) -> list[dict]:
    """Precision of the estimates per number of trials, over runs.

    Parameters
    ----------
    errors : dict of int -> list of float
        Trials -> ``log10(estimate / reference)`` of each run.
    within : float
        Relative error bound of the ``within`` column (0.2: 20 %).

    Returns
    -------
    list of dict
        Per trials: ``trials``, ``runs``, ``bias_pct`` (geometric mean ratio - 1, %), ``rms_log10``,
        ``sd_log10``, ``median_abs_error_pct``, ``p90_abs_error_pct``, ``within_20pct`` (fraction of runs
        whose estimate is within ``within`` of the reference).
    """
    rows = []
    for k in sorted(errors):
        e = np.asarray(errors[k], dtype=float)
        rel = np.abs(10.0 ** e - 1.0)
        rows.append({"trials": k, "runs": len(e), "bias_pct": 100.0 * (10.0 ** float(np.mean(e)) - 1.0),
                     "rms_log10": float(np.sqrt(np.mean(e ** 2))),
                     "sd_log10": float(np.std(e, ddof=1)) if len(e) > 1 else 0.0,
                     "median_abs_error_pct": 100.0 * float(np.median(rel)),
                     "p90_abs_error_pct": 100.0 * float(np.percentile(rel, 90)),
                     f"within_{round(100 * within)}pct": float(np.mean(rel <= within))})
    return rows


def simulate(s: SimulationSettings, progress=None) -> dict:
    """Run ``s.repeat`` runs and collect what ``simulate-observer`` writes.

    Parameters
    ----------
    s : SimulationSettings
    progress : callable or None
        Called with the number of runs done after each run.

    Returns
    -------
    dict
        ``settings``, ``first`` (run 1's :func:`run_once` result), ``reference``, ``runs`` (per run: seed,
        threshold, error_log10), ``precision`` (:func:`precision_table`), ``tracks`` (all runs' rows with a
        ``run`` column).
    """
    checks = checkpoints_for(s.trials)
    errors = {k: [] for k in checks}
    runs, tracks, first, reference = [], [], None, None
    for r in range(s.repeat):
        res = run_once(s, s.seed + r, checks)
        if first is None:
            first, reference = res, reference_intensity(res["method"], s.observer)
        for k, est in res["at"].items():
            errors[k].append(math.log10(est / reference))
        est = res["estimate"]["threshold"]
        runs.append({"run": r + 1, "seed": s.seed + r, "threshold": est, "error_log10": math.log10(est / reference),
                     "trials": res["method"].trials, "reversals": len(res["method"].reversal_intensities)})
        tracks.extend({"run": r + 1, **row} for row in res["track"])
        if progress is not None:
            progress(r + 1)
    return {"settings": s, "first": first, "reference": reference, "runs": runs,
            "precision": precision_table(errors), "tracks": tracks}


def estimate_record(result: dict) -> dict:
    """The content of estimate.json: the first run's estimate, the truth, the settings and, for several
    runs, the summary over runs."""
    s: SimulationSettings = result["settings"]
    first = result["first"]
    method = first["method"]
    record = {**first["estimate"], "method": s.method, "reference": result["reference"],
              "reference_is": ("threshold" if not isinstance(method, UpDown)
                               else f"intensity where the observer is correct with p = {method.target_probability():.4g}"),
              "error_pct": 100.0 * (first["estimate"]["threshold"] / result["reference"] - 1.0),
              "first_intensity": method.intensities[0],
              "observer": {**asdict(s.observer)}, "settings": asdict(s),
              "method_config": method.config()}
    if s.repeat > 1:
        last = result["precision"][-1]
        record["repeat"] = {"runs": s.repeat, **{k: v for k, v in last.items() if k != "runs"}}
    return record
