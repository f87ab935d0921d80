"""The protocol state machine: counts, redraws later in the order, seeded orders, replay."""

import numpy as np
import pytest

from study.ratings.schedule import PhaseSchedule, Schedule

SAMPLES = ["wood", "wood_on_foam", "foam", "very_firm", "firm", "soft", "pulse_firm", "pulse_soft",
           "sinusoid_firm", "sinusoid_soft", "hfam_firm", "hfam_soft"]


def drive(schedule: Schedule, invalid_every=0, fam_windows=3):
    """Run a schedule to the end; every ``invalid_every``-th testing attempt is invalid. Returns the attempts."""
    out = []
    k = 0
    while (nxt := schedule.next()) is not None:
        trial, attempt = nxt
        k += 1
        valid = not (invalid_every and trial.phase == "testing" and k % invalid_every == 0)
        end = trial.phase == "familiarization" and trial.trial >= fam_windows
        schedule.record(trial, attempt, valid, "" if valid else "saturated", end_familiarization=end)
        out.append({"phase": trial.phase, "trial": trial.trial, "attempt": attempt, "sample": trial.sample,
                    "valid": valid})
    return out


def test_counts_per_phase_and_three_valid_testing_trials_per_sample():
    rows = drive(Schedule(SAMPLES, 3, seed=1, familiarization_sample="wood"), invalid_every=5)
    fam = [r for r in rows if r["phase"] == "familiarization"]
    demo = [r for r in rows if r["phase"] == "demonstration"]
    test = [r for r in rows if r["phase"] == "testing"]
    assert [r["trial"] for r in fam] == [1, 2, 3] and {r["sample"] for r in fam} == {"wood"}
    assert sorted(r["sample"] for r in demo) == sorted(SAMPLES)           # each sample exactly once
    valid = [r for r in test if r["valid"]]
    assert len(valid) == 36
    assert {s: sum(r["sample"] == s for r in valid) for s in SAMPLES} == {s: 3 for s in SAMPLES}
    assert len(test) > 36                                                 # the invalid ones were repeated
    keys = [(r["phase"], r["trial"], r["attempt"]) for r in rows]
    assert len(keys) == len(set(keys))                                    # no duplicate attempt ids
    # phases strictly in order
    order = [r["phase"] for r in rows]
    assert order == sorted(order, key=["familiarization", "demonstration", "testing"].index)


def test_redraws_go_back_into_the_pool_and_land_later():
    sched = Schedule(SAMPLES, 3, seed=7, familiarization_sample=None)
    rows = drive(sched, invalid_every=4)
    redraws = sched.phases["testing"].redraws
    assert len(redraws) >= 9
    positions = {}
    for i, r in enumerate(rows):
        positions.setdefault((r["phase"], r["trial"]), []).append((r["attempt"], i))
    for rd in redraws:
        attempts = dict(positions[("testing", rd["trial"])])
        assert rd["attempt"] + 1 in attempts, "an invalid attempt must be repeated"
        assert attempts[rd["attempt"] + 1] > attempts[rd["attempt"]]
    # reinsertion is random: not always straight away, not always at the end
    spots = [rd["reinserted_at"] for rd in redraws]
    assert len(set(spots)) > 2


def test_same_seed_same_order_different_seed_different_order():
    a = drive(Schedule(SAMPLES, 3, 11, "wood"), invalid_every=6)
    b = drive(Schedule(SAMPLES, 3, 11, "wood"), invalid_every=6)
    c = drive(Schedule(SAMPLES, 3, 12, "wood"), invalid_every=6)
    seq = lambda rows: [(r["phase"], r["sample"]) for r in rows]  # noqa: E731
    assert seq(a) == seq(b)
    assert seq(a) != seq(c)
    # demonstration and testing orders differ from each other and from catalog order
    demo = [r["sample"] for r in a if r["phase"] == "demonstration"]
    assert demo != SAMPLES


def test_orders_are_not_biased_towards_catalog_order():
    first = [PhaseSchedule("testing", tuple(SAMPLES), 3, seed).slots[1].trial.sample for seed in range(600)]
    counts = np.array([first.count(s) for s in SAMPLES])
    assert counts.min() > 20 and counts.max() < 90                       # ~50 each if uniform


def test_replay_reproduces_the_state_exactly():
    full = Schedule(SAMPLES, 3, 5, "wood")
    rows = drive(full, invalid_every=3)
    for cut in (1, 2, 3, 10, 20, len(rows) - 1):
        replayed = Schedule(SAMPLES, 3, 5, "wood")
        replayed.replay(rows[:cut], familiarization_ended=cut >= 3)
        rest = drive(replayed, invalid_every=0)
        # the next attempt after the cut is the one the uninterrupted run did
        assert (rest[0]["phase"], rest[0]["trial"], rest[0]["attempt"], rest[0]["sample"]) == \
            (rows[cut]["phase"], rows[cut]["trial"], rows[cut]["attempt"], rows[cut]["sample"])


def test_replay_refuses_rows_from_another_seed():
    rows = drive(Schedule(SAMPLES, 3, 5, None))
    with pytest.raises(ValueError, match="row 2"):
        Schedule(SAMPLES, 3, 6, None).replay(rows[:5])


def test_bad_protocol_values_refused():
    with pytest.raises(ValueError, match="repetitions"):
        Schedule(SAMPLES, 0, 1, None)
    with pytest.raises(ValueError, match="duplicate"):
        Schedule(["a", "a"], 1, 1, None)
