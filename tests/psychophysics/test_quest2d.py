"""Two-dimensional QUEST+ against the ``questplus`` package (Watson 2017's own two-dimensional example, the
contrast sensitivity function ``csf``), its state's replay, and the recovery of a simulated observer.

questplus's ``csf`` on a log10 contrast axis is ``1 - delta - (1 - gamma - delta) exp(-10^(beta (x - t)))`` with
``t = max(min_thresh, c0 + cf f + cw w)``: a Weibull whose threshold is the 63.2 % point of the sigmoid. Ours
puts the threshold at F = 0.5 (``F = 1 - exp(-ln 2 (x / alpha)^beta)``), so with one slope ``beta`` the two grids
are the same functions with intercept and floor shifted by ``log10(ln 2) / beta``. With several slopes the shift
differs per slope (not a product grid): there the likelihood tables are compared point by point, and the Bayes
update and the stimulus choice with questplus running on our table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import questplus

from psychophysics.quest2d import QuestPlus2D, simulate_response

LOG_CONTRAST = np.linspace(-3.0, -0.5, 11)
FREQ = np.array([0.0, 0.5, 1.0, 1.5, 2.0])          # the second dimension (e.g. log10 frequency)
C0 = np.linspace(-3.2, -1.0, 12)
CF = np.array([-0.6, -0.3, 0.0, 0.3, 0.6])
MIN_T = np.array([-3.5, -2.5])
LAPSES = np.array([0.0, 0.02, 0.05])
GUESS = 0.5


def _shift(beta: float) -> float:
    return math.log10(math.log(2.0)) / beta


def _ours(slopes, lapses=LAPSES, floors=MIN_T, max_trials=40):
    s = _shift(slopes[0]) if len(slopes) == 1 else 0.0
    return QuestPlus2D(x=(10.0 ** LOG_CONTRAST).tolist(), y=FREQ.tolist(), intercepts=(C0 + s).tolist(),
                       gains=CF.tolist(), floors=None if floors is None else (np.asarray(floors) + s).tolist(),
                       slopes=list(slopes), lapses=list(lapses), guess=GUESS, function="weibull",
                       threshold_scale="log10", max_trials=max_trials)


def _ref(slopes, lapses=LAPSES):
    return questplus.QuestPlus(
        stim_domain={"contrast": LOG_CONTRAST, "spatial_freq": FREQ, "temporal_freq": np.array([0.0])},
        param_domain={"c0": C0, "cf": CF, "cw": np.array([0.0]), "min_thresh": MIN_T, "slope": np.asarray(slopes),
                      "lower_asymptote": np.array([GUESS]), "lapse_rate": np.asarray(lapses)},
        outcome_domain={"response": ["Correct", "Incorrect"]}, func="csf", stim_scale="log10",
        stim_selection_method="min_entropy")


def _ref_posterior(ref) -> np.ndarray:
    p = ref.posterior.transpose("c0", "cf", "min_thresh", "slope", "lapse_rate", "cw", "lower_asymptote")
    return p.values[..., 0, 0].ravel()


def _run_against(ours, ref, truth, trials=40, seed=3):
    u = np.random.default_rng(seed).random(trials)
    chosen = []
    for k in range(trials):
        want = ref.next_stim
        x, y = ours.next_stimulus()
        assert (math.log10(x), y) == pytest.approx((want["contrast"], want["spatial_freq"]), abs=1e-12), \
            f"trial {k + 1}: next stimulus {(math.log10(x), y)} vs questplus {want}"
        t = max(truth["min_thresh"], truth["c0"] + truth["cf"] * y)
        p = 1 - truth["lapse"] - (1 - GUESS - truth["lapse"]) * math.exp(-10 ** (truth["slope"] * (math.log10(x) - t)))
        correct = bool(u[k] < p)
        ours.update(x, y, correct)
        ref.update(stim=want, outcome={"response": "Correct" if correct else "Incorrect"})
        np.testing.assert_allclose(ours.posterior, _ref_posterior(ref), rtol=1e-9, atol=1e-15,
                                   err_msg=f"posterior after trial {k + 1}")
        chosen.append((x, y))
    return chosen


def test_one_slope_equals_questplus_csf_trial_by_trial():
    ours, ref = _ours([3.0]), _ref([3.0])
    # the likelihood tables are the same functions
    lik = ref.likelihoods.sel(response="Correct").transpose(
        "contrast", "spatial_freq", "c0", "cf", "min_thresh", "slope", "lapse_rate", "temporal_freq", "cw",
        "lower_asymptote").values[..., 0, 0, 0]
    np.testing.assert_allclose(ours.p_correct, lik.reshape(ours.p_correct.shape), rtol=1e-12, atol=1e-15)
    chosen = _run_against(ours, ref, {"c0": -2.0, "cf": 0.3, "min_thresh": -2.5, "slope": 3.0, "lapse": 0.02})
    assert len(set(chosen)) >= 6 and len({y for _, y in chosen}) >= 3   # it searched both dimensions


def test_several_slopes_same_tables_update_and_choice_as_questplus():
    slopes = [1.5, 3.0, 5.0]
    ours, ref = _ours(slopes), _ref(slopes)
    # our function at threshold t is questplus's csf at t - log10(ln 2) / beta: every entry of the table
    x = LOG_CONTRAST[:, None, None, None, None, None, None]
    y = FREQ[None, :, None, None, None, None, None]
    t0 = C0[None, None, :, None, None, None, None]
    t1 = CF[None, None, None, :, None, None, None]
    tmin = MIN_T[None, None, None, None, :, None, None]
    beta = np.asarray(slopes)[None, None, None, None, None, :, None]
    lam = LAPSES[None, None, None, None, None, None, :]
    t = np.maximum(tmin, t0 + t1 * y) - np.log10(np.log(2.0)) / beta
    want = 1 - lam - (1 - GUESS - lam) * np.exp(-10 ** (beta * (x - t)))
    np.testing.assert_allclose(ours.p_correct, want.reshape(ours.p_correct.shape), rtol=1e-12, atol=1e-15)
    # the Bayes update and the stimulus choice on a shared table: questplus given our likelihoods
    table = ours.p_correct.reshape(want.shape)
    like = ref.likelihoods.copy()
    like.loc[{"response": "Correct"}] = _as_ref(ref, table, "Correct")
    like.loc[{"response": "Incorrect"}] = _as_ref(ref, 1.0 - table, "Incorrect")
    ref.likelihoods = like
    _run_against_table(ours, ref, seed=9)


def _as_ref(ref, table, outcome):
    """Our (x, y, t0, t1, tmin, beta, lambda) table in the axis order of questplus's likelihood array."""
    dims = ref.likelihoods.sel(response=outcome).dims
    ours_dims = ("contrast", "spatial_freq", "c0", "cf", "min_thresh", "slope", "lapse_rate")
    arr = table
    for extra in ("temporal_freq", "cw", "lower_asymptote"):
        arr = arr[..., None]
        ours_dims = ours_dims + (extra,)
    return np.transpose(arr, [ours_dims.index(d) for d in dims])


def _run_against_table(ours, ref, trials=40, seed=9):
    u = np.random.default_rng(seed).random(trials)
    for k in range(trials):
        want = ref.next_stim
        x, y = ours.next_stimulus()
        assert (math.log10(x), y) == pytest.approx((want["contrast"], want["spatial_freq"]), abs=1e-12), \
            f"trial {k + 1}: next stimulus {(math.log10(x), y)} vs questplus {want}"
        correct = bool(u[k] < 0.5 + 0.45 * (math.log10(x) > -2.0 + 0.3 * y))
        ours.update(x, y, correct)
        ref.update(stim=want, outcome={"response": "Correct" if correct else "Incorrect"})
        np.testing.assert_allclose(ours.posterior, _ref_posterior(ref), rtol=1e-9, atol=1e-15,
                                   err_msg=f"posterior after trial {k + 1}")


@pytest.mark.parametrize("after", [0, 1, 7, 29])
def test_state_through_json_resumes_exactly(after):
    truth = dict(intercept=-1.8, gain=0.4, slope=3.0, lapse=0.02, floor=-3.0)
    full, rng = _ours([2.0, 3.5], floors=[-3.0, -2.0], max_trials=40), np.random.default_rng(5)
    answers = []
    for _ in range(40):
        x, y = full.next_stimulus()
        answers.append(simulate_response(rng, x, y, **truth))
        full.update(x, y, answers[-1])
    part = _ours([2.0, 3.5], floors=[-3.0, -2.0], max_trials=40)
    for k in range(after):
        part.update(*part.next_stimulus(), answers[k])
    again = QuestPlus2D.from_state(json.loads(json.dumps(part.state())))
    for k in range(after, 40):
        again.update(*again.next_stimulus(), answers[k])
    assert again.history == full.history and again.finished
    assert again.posterior.tobytes() == full.posterior.tobytes()
    assert again.estimate() == full.estimate()


def test_a_state_that_does_not_replay_or_a_bad_trial_is_refused():
    m = _ours([3.0], max_trials=10)
    m.update(*m.next_stimulus(), True)
    state = m.state()
    state["next_stimulus"] = [1.0, 0.0]
    with pytest.raises(ValueError, match="does not replay"):
        QuestPlus2D.from_state(state)
    with pytest.raises(ValueError, match="x = 0.5 is not on the stimulus grid"):
        m.update(0.5, 0.0, True)
    with pytest.raises(ValueError, match="quest\\+2d state config.gains is missing"):
        QuestPlus2D.from_state({"method": "quest+2d", "config": {k: v for k, v in m.config().items()
                                                                  if k != "gains"}, "history": []})
    with pytest.raises(ValueError, match="staircase.A.slopes values must be > 0"):
        QuestPlus2D.from_table({"x": [1, 2], "y": [0, 1], "intercepts": [0], "gains": [0], "slopes": [0, 1]},
                               "staircase.A.")


def test_recovers_intercept_and_gain_of_simulated_observers_in_200_trials():
    """Ten 2AFC Weibull observers, threshold line log10 alpha = t0 + t1 y with y = log10(f / 100 Hz) from -0.5 to
    0.5 (32-316 Hz), 200 trials each: the posterior means of both line parameters land near the truth and their
    95 % credible intervals cover it."""
    rng = np.random.default_rng(2024)
    errors, covered = [], 0
    for _ in range(10):
        t0, t1 = rng.uniform(-0.6, 0.2), rng.uniform(-0.8, 0.4)
        m = QuestPlus2D(x={"min": 0.01, "max": 10.0, "n": 25}, y={"min": -0.5, "max": 0.5, "n": 5, "spacing": "linear"},
                        intercepts={"min": -1.2, "max": 0.8, "n": 21, "spacing": "linear"},
                        gains={"min": -1.2, "max": 0.8, "n": 21, "spacing": "linear"},
                        slopes=[2.0, 3.5, 5.0], lapses=[0.02], guess=0.5, max_trials=200)
        while not m.finished:
            x, y = m.next_stimulus()
            m.update(x, y, simulate_response(rng, x, y, intercept=t0, gain=t1, slope=3.5, lapse=0.02))
        est = m.estimate()
        errors.append((est["intercept"] - t0, est["gain"] - t1))
        covered += (est["intercept_ci"][0] <= t0 <= est["intercept_ci"][1]) + (est["gain_ci"][0] <= t1 <= est["gain_ci"][1])
    errors = np.abs(np.array(errors))
    assert np.max(errors[:, 0]) < 0.1, errors                 # the threshold at 100 Hz within 0.1 log10 (26 %)
    assert np.max(errors[:, 1]) < 0.25 and np.median(errors[:, 1]) < 0.12, errors   # decades per decade
    assert covered >= 18, covered                             # of 20 intervals (19 measured)
