"""Issue 40: the analysis report lists per session whether the servo met the timing thresholds (from session.json)."""

import json
import warnings

from analysis.load import read_session, servo_timing_text
from analysis.synthetic import write_synthetic_study

FAILED_CHECK = {"verdict": {"met": False, "failed": ["period error p99 31.0 us > 20 us"], "thresholds": {}},
                "accepted_override": True}
PASSED_CHECK = {"verdict": {"met": True, "failed": [], "thresholds": {}}, "accepted_override": False}


def test_servo_timing_text_reads_the_check_and_the_windows():
    assert servo_timing_text({}).startswith("not judged")
    assert servo_timing_text({"timing_check": PASSED_CHECK,
                              "servo_timing": {"windows": 12, "met": 12, "all_met": True}}) == \
        "met (check passed, 12 of 12 windows)"
    text = servo_timing_text({"timing_check": FAILED_CHECK, "servo_timing": {"windows": 12, "met": 9, "all_met": False}})
    assert text == ("NOT met (check failed, run with --accept-timing: period error p99 31.0 us > 20 us; 3 of 12 "
                    "tapping windows missed the thresholds)")
    # a resumed session: every part's check counts
    assert servo_timing_text({"timing_checks": [PASSED_CHECK, FAILED_CHECK]}).startswith("NOT met (check failed")


def test_report_provenance_lists_each_sessions_servo_timing(tmp_path):
    from analysis.pipeline import analyse
    from analysis.report import provenance

    write_synthetic_study(tmp_path, 3, seed=5)
    folders = sorted(p.parent for p in tmp_path.glob("*/session.json"))
    for folder, extra in zip(folders, ({"timing_check": FAILED_CHECK, "servo_timing": {"windows": 4, "met": 4, "all_met": True}},
                                       {"timing_check": PASSED_CHECK, "servo_timing": {"windows": 4, "met": 4, "all_met": True}},
                                       {})):
        path = folder / "session.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), **extra}))
    assert read_session(folders[1] / "session.json")["servo_timing"] == "met (check passed, 4 of 4 windows)"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = analyse(tmp_path)
    row = dict(provenance(res, tmp_path / "out"))["servo timing"]
    names = [f.name for f in folders]
    assert row == (f"{names[0]}: NOT met (check failed, run with --accept-timing: period error p99 31.0 us > 20 us); "
                   f"{names[1]}: met (check passed, 4 of 4 windows); {names[2]}: not judged (no paced servo timing "
                   "recorded: a simulated session, or one older than the check)")
