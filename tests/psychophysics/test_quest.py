"""QUEST+ and Psi against the ``questplus`` package (Watson 2017's method, test-only reference): the same grid,
the same fixed response sequence, the same posterior after every trial and the same next intensity.

questplus's ``norm_cdf`` is the contract's normal function with ``sd = 1 / slope``
(``gamma + (1 - gamma - lambda) Phi((x - mean) / sd)``), so the two grids are the same functions with the slope
axis reversed (sd increasing = slope decreasing)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import questplus

from psychophysics.observer import ObserverParams, SimulatedObserver
from psychophysics.quest import Psi, QuestPlus

INTENSITIES = np.linspace(-2.0, 2.0, 21)
MEANS = np.linspace(-1.5, 1.5, 13)
SDS = np.array([0.25, 0.4, 0.6, 0.9, 1.4])
GUESS = 0.5


def _pair(method_cls, lapses):
    ours = method_cls(intensities=INTENSITIES.tolist(), thresholds=MEANS.tolist(), slopes=(1.0 / SDS[::-1]).tolist(),
                      lapses=list(lapses), guess=GUESS, function="normal", threshold_scale="linear",
                      max_trials=40)
    ref = questplus.QuestPlus(stim_domain={"intensity": INTENSITIES},
                              param_domain={"mean": MEANS, "sd": SDS, "lower_asymptote": np.array([GUESS]),
                                            "lapse_rate": np.asarray(lapses, dtype=float)},
                              outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf",
                              stim_scale="linear", stim_selection_method="min_entropy")
    return ours, ref


def _ref_posterior(ref) -> np.ndarray:
    """questplus's posterior as (mean, slope ascending, lapse), flattened like ours."""
    p = ref.posterior.transpose("mean", "sd", "lower_asymptote", "lapse_rate").values[:, :, 0, :]
    return p[:, ::-1, :].ravel()


def _responses(n=40, seed=11):
    """A fixed response sequence: a seeded observer's answers at the reference's intensities are drawn as
    uniforms once, so both implementations see the same sequence whatever intensities they choose."""
    return np.random.default_rng(seed).random(n)


@pytest.mark.parametrize(("method_cls", "lapses"), [(QuestPlus, (0.0, 0.02, 0.05)), (QuestPlus, (0.02,)),
                                                    (Psi, (0.02,))])
def test_posteriors_and_next_intensities_equal_questplus(method_cls, lapses):
    """Psi with one lapse rate is Kontsevich & Tyler's method: the joint entropy over threshold x slope is what
    QUEST+ minimises, so it must pick the same intensities as questplus too."""
    ours, ref = _pair(method_cls, lapses)
    observer = ObserverParams(0.3, 1.0 / 0.6, 0.02, GUESS, "normal")
    u = _responses()
    chosen = []
    for trial in range(40):
        x_ref = ref.next_stim["intensity"]
        x = ours.next_intensity()
        assert x == pytest.approx(x_ref, abs=1e-12), f"trial {trial + 1}: next intensity {x} vs questplus {x_ref}"
        correct = bool(u[trial] < observer.p_correct(x))
        ours.update(x, correct)
        ref.update(stim={"intensity": x_ref}, outcome={"response": "Correct" if correct else "Incorrect"})
        np.testing.assert_allclose(ours.posterior, _ref_posterior(ref), rtol=1e-9, atol=1e-15,
                                   err_msg=f"posterior after trial {trial + 1}")
        chosen.append(x)
    # the sequence really adapted (not one intensity all along) and the posterior concentrated
    assert len(set(chosen)) >= 4
    entropy = -np.sum(ours.posterior * np.log(np.maximum(ours.posterior, 1e-300)))
    assert entropy < np.log(ours.posterior.size) - 0.75


def test_expected_entropy_equals_questplus_formula():
    """Our closed form H(post) - I(s) equals the direct sum questplus evaluates, at every intensity, after some
    trials (the argmin test above cannot see an error that keeps the order of the entropies)."""
    ours, _ = _pair(QuestPlus, (0.0, 0.02, 0.05))
    obs = SimulatedObserver(ObserverParams(-0.4, 2.0, 0.02, GUESS, "normal"), seed=5)
    for _ in range(12):
        x = ours.next_intensity()
        ours.update(x, obs.respond(x))
    post = ours.posterior
    direct = []
    for i in range(len(INTENSITIES)):
        eh = 0.0
        for like in (ours.p_correct[i], ours.p_wrong[i]):
            joint = post * like
            pk = joint.sum()
            q = joint / pk
            q = q[q > 0]
            eh += pk * -(q * np.log(q)).sum()
        direct.append(eh)
    np.testing.assert_allclose(ours.expected_entropy(), direct, rtol=1e-10)


def test_psi_marginal_expected_entropy_equals_brute_force():
    """Psi with several lapse rates (psi-marginal): the expected entropy of the threshold x slope posterior, from
    the factorised sum over lapses, equals summing the lapse out of each outcome's joint posterior directly."""
    ours, _ = _pair(Psi, (0.0, 0.02, 0.05))
    obs = SimulatedObserver(ObserverParams(0.5, 1.5, 0.02, GUESS, "normal"), seed=8)
    for _ in range(15):
        x = ours.next_intensity()
        ours.update(x, obs.respond(x))
    post = ours.posterior
    direct = []
    for i in range(len(INTENSITIES)):
        eh = 0.0
        for like in (ours.p_correct[i], ours.p_wrong[i]):
            joint = (post * like).reshape(-1, 3).sum(axis=1)     # lapse summed out
            pk = joint.sum()
            q = joint / pk
            q = q[q > 0]
            eh += pk * -(q * np.log(q)).sum()
        direct.append(eh)
    np.testing.assert_allclose(ours.expected_entropy(), direct, rtol=1e-10)
    # and it is not QUEST+'s joint entropy (the lapse is not what Psi spends trials on)
    joint_h, _ = _pair(QuestPlus, (0.0, 0.02, 0.05))
    joint_h.posterior = post.copy()
    assert not np.allclose(joint_h.expected_entropy(), direct, rtol=1e-3)


def test_a_user_prior_gives_questplus_posteriors_and_intensities():
    """A Gaussian prior on the threshold and a weighted one on the slope (the product is the joint prior, as
    questplus builds it): the same posterior after every trial and the same next intensity as questplus given
    the same per-parameter priors."""
    prior = {"thresholds": {"mean": 0.4, "sd": 0.5, "scale": "linear"}, "slopes": [1, 2, 4, 2, 1]}
    ours = QuestPlus(intensities=INTENSITIES.tolist(), thresholds=MEANS.tolist(), slopes=(1.0 / SDS[::-1]).tolist(),
                     lapses=[0.0, 0.02, 0.05], guess=GUESS, function="normal", threshold_scale="linear",
                     max_trials=30, prior=prior)
    gauss = np.exp(-0.5 * ((MEANS - 0.4) / 0.5) ** 2)
    ref = questplus.QuestPlus(stim_domain={"intensity": INTENSITIES},
                              param_domain={"mean": MEANS, "sd": SDS, "lower_asymptote": np.array([GUESS]),
                                            "lapse_rate": np.array([0.0, 0.02, 0.05])},
                              outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf",
                              stim_scale="linear", stim_selection_method="min_entropy",
                              prior={"mean": gauss / gauss.sum(), "sd": np.array([1, 2, 4, 2, 1.0])[::-1] / 10,
                                     "lower_asymptote": np.array([1.0]), "lapse_rate": np.ones(3) / 3})
    np.testing.assert_allclose(ours.posterior, _ref_posterior(ref), rtol=1e-9, atol=1e-15)
    observer = ObserverParams(-0.2, 1.0 / 0.6, 0.02, GUESS, "normal")
    u = _responses(30, seed=4)
    for trial in range(30):
        x_ref = ref.next_stim["intensity"]
        x = ours.next_intensity()
        assert x == pytest.approx(x_ref, abs=1e-12), f"trial {trial + 1}"
        correct = bool(u[trial] < observer.p_correct(x))
        ours.update(x, correct)
        ref.update(stim={"intensity": x_ref}, outcome={"response": "Correct" if correct else "Incorrect"})
        np.testing.assert_allclose(ours.posterior, _ref_posterior(ref), rtol=1e-9, atol=1e-15)
    # and the prior replays from the state
    again = QuestPlus.from_state(json.loads(json.dumps(ours.state())))
    np.testing.assert_array_equal(again.posterior, ours.posterior)


def test_randomised_choice_equals_questplus_min_n_entropy_and_replays():
    """choose_among = 4 with max_repeats = 2 (questplus's min_n_entropy with its defaults and a seed): the same
    intensities as questplus trial by trial; the state replays to the same track; the track is not the
    deterministic one."""
    ours = QuestPlus(intensities=INTENSITIES.tolist(), thresholds=MEANS.tolist(), slopes=(1.0 / SDS[::-1]).tolist(),
                     lapses=[0.02], guess=GUESS, function="normal", threshold_scale="linear", max_trials=40,
                     choose_among=4, max_repeats=2, seed=123)
    ref = questplus.QuestPlus(stim_domain={"intensity": INTENSITIES},
                              param_domain={"mean": MEANS, "sd": SDS, "lower_asymptote": np.array([GUESS]),
                                            "lapse_rate": np.array([0.02])},
                              outcome_domain={"response": ["Correct", "Incorrect"]}, func="norm_cdf",
                              stim_scale="linear", stim_selection_method="min_n_entropy",
                              stim_selection_options={"n": 4, "max_consecutive_reps": 2, "random_seed": 123})
    best, _ = _pair(QuestPlus, (0.02,))
    observer = ObserverParams(0.3, 1.0 / 0.6, 0.02, GUESS, "normal")
    u = _responses(40, seed=9)
    track, deterministic = [], []
    for trial in range(40):
        x = ours.next_intensity()
        x_ref = ref.next_stim["intensity"]
        assert x == pytest.approx(x_ref, abs=1e-12), f"trial {trial + 1}: {x} vs questplus {x_ref}"
        # within the four best of the deterministic ranking
        ranked = INTENSITIES[np.argsort(ours.expected_entropy())[:4]]
        assert np.any(np.isclose(ranked, x))
        correct = bool(u[trial] < observer.p_correct(x))
        ours.update(x, correct)
        ref.update(stim={"intensity": x_ref}, outcome={"response": "Correct" if correct else "Incorrect"})
        xd = best.next_intensity()
        best.update(xd, bool(u[trial] < observer.p_correct(xd)))
        track.append(x)
        deterministic.append(xd)
        if trial >= 2:
            assert not (track[-1] == track[-2] == track[-3]), "more than max_repeats in a row"
    assert track != deterministic
    again = QuestPlus.from_state(json.loads(json.dumps(ours.state())))
    assert again.intensities == ours.intensities and again.next_intensity() == ours.next_intensity()


def test_stopping_on_posterior_precision():
    """stop_sd: the method ends once the threshold's posterior SD reaches it (before max_trials), and its
    estimate's SD says so; without max_trials it is refused."""
    grid = {"min": 0.1, "max": 10.0, "n": 41}
    m = QuestPlus(intensities=grid, thresholds=grid, slopes=[2, 3.5, 5], lapses=[0.02], guess=0.5,
                  max_trials=400, stop_sd=0.05)
    obs = SimulatedObserver(ObserverParams(1.0, 3.5, 0.02, 0.5, "weibull"), seed=3)
    sds = []
    while not m.finished:
        x = m.next_intensity()
        m.update(x, obs.respond(x))
        sds.append(m.estimate()["threshold_sd"])
    assert m.trials < 400 and sds[-1] <= 0.05 < sds[-2]
    assert QuestPlus.from_state(json.loads(json.dumps(m.state()))).finished
    with pytest.raises(ValueError, match="stop_sd needs staircase.max_trials"):
        QuestPlus(intensities=grid, thresholds=grid, slopes=[2], max_reversals=10, stop_sd=0.05,
                  prefix="staircase.")
    with pytest.raises(ValueError, match=r"prior.slopes has 2 weights for 3 grid values"):
        QuestPlus(intensities=grid, thresholds=grid, slopes=[2, 3, 4], max_trials=5, prior={"slopes": [1, 2]})
