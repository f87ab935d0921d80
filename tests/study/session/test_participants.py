"""The simulated participant (study.session.participants) on its own: seeded, per subject, within its ranges."""

import numpy as np
import pytest

from study.session.participants import SimParticipantConfig, SimulatedParticipant, load_participant_config
from study.session.rng import PHASE_CODES, session_rng

from tests.support.study import write


def test_the_same_seed_and_subject_make_the_same_choices_and_others_differ():
    a, b = SimulatedParticipant("P1", "few", 7), SimulatedParticipant("P1", "few", 7)
    plans = [(ph, t, k) for ph in ("demonstration", "testing") for t in (1, 2, 3) for k in (1, 2)]
    assert [a.plan(*p, 5.0) for p in plans] == [b.plan(*p, 5.0) for p in plans]
    assert a.grip_N == b.grip_N and a.profile == b.profile
    other = SimulatedParticipant("P2", "few", 7)
    assert [other.plan(*p, 5.0) for p in plans] != [a.plan(*p, 5.0) for p in plans]
    # the participant's generator is the session's (study.session.rng): seed, subject, phase, trial, attempt, purpose
    assert a.rng("testing", 3, 2, 34).random() == session_rng(7, "P1", PHASE_CODES["testing"], 3, 2, 34).random()


def test_plans_stay_in_their_ranges_and_familiarization_ends_on_its_tap_count():
    cfg = SimParticipantConfig(p_hard_tap=0.0)
    sim = SimulatedParticipant("P3", "regular", 11, cfg)
    assert cfg.grip_min_N <= sim.grip_N <= cfg.grip_max_N
    assert cfg.familiarization_taps_min <= sim.familiarization_taps <= cfg.familiarization_taps_max
    v = np.concatenate([sim.plan("testing", t, 1, 5.0).velocities_m_s for t in range(1, 200)])
    assert v.min() >= cfg.velocity_min_m_s and v.max() <= cfg.velocity_max_m_s
    assert abs(np.median(v) - cfg.velocity_mean_m_s) < 0.01
    # taps from t = 0 every tap_period_s (0.7 s) that end their dwell (0.15 s) inside the 5 s window: 7
    assert sim.taps_per_window(5.0) == len(sim.plan("testing", 1, 1, 5.0).velocities_m_s) == 7
    done, windows = 0, 0
    while True:
        windows += 1
        plan = sim.plan("familiarization", windows, 1, 5.0, done)
        done += len(plan.velocities_m_s)
        assert not plan.reject    # familiarization is never rejected
        if plan.end_familiarization:
            break
    assert done == sim.familiarization_taps


def test_a_rejected_plan_gives_no_rating_and_the_description_is_plain_data():
    sim = SimulatedParticipant("P4", "none", 2, SimParticipantConfig(p_reject=1.0))
    plan = sim.plan("testing", 1, 1, 5.0)
    assert plan.reject and sim.rate("testing", 1, 1, plan, None, [], [], None) == (None, True, {})
    d = sim.describe()
    assert d["kind"] == "simulated" and d["grip_N"] == sim.grip_N and d["config"]["p_reject"] == 1.0


def test_a_participant_file_is_checked_naming_the_key(tmp_path):
    assert load_participant_config(None) == SimParticipantConfig()
    ok = load_participant_config(write(tmp_path / "ok.toml", "lapse = 0.1\np_reject = 0.2\n"))
    assert ok.lapse == 0.1 and ok.p_reject == 0.2
    for text, says in (("p_reject = 1.5\n", "participant.p_reject is a probability"),
                       ("velocity_min_m_s = 0.5\n", "velocity range"), ("lapse = 0.5\n", "participant.lapse"),
                       ("nope = 1\n", "nope")):
        with pytest.raises(ValueError, match=says):
            load_participant_config(write(tmp_path / "bad.toml", text))
