"""plumbing.rtpolicy.realtime: the policy asked for inside the block and given back after it, read from the
kernel (SCHED_FIFO where this user may have it, refused and reported where not); and the commands that use it."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from devices.cli_hardware import realtime_priority

ROOT = Path(__file__).resolve().parents[2]


def test_the_policy_is_given_back_after_the_block():
    code = ("import json, os, gc\nfrom plumbing import rtpolicy\n"
            "before = os.sched_getscheduler(0)\n"
            "with rtpolicy.realtime(50, lock_memory=False) as rec:\n"
            "    inside = os.sched_getscheduler(0) == os.SCHED_FIFO\n"
            "after = os.sched_getscheduler(0)\n"
            "rtpolicy.freeze_startup_objects()\n"
            "print(json.dumps({'policy': rec['policy'], 'inside': inside, 'restored': after == before,"
            " 'other': after == os.SCHED_OTHER, 'frozen': gc.get_freeze_count() > 0, 'gc': gc.isenabled()}))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["inside"] == (got["policy"] == "SCHED_FIFO")       # what the record says is what the kernel did
    assert got["restored"] and got["other"]
    assert got["frozen"] and got["gc"]                            # frozen out of collections, the collector on


def test_the_commands_note_and_a_bad_priority():
    with realtime_priority(None) as note:
        assert note == "default scheduling"
    with pytest.raises(ValueError, match="--rt-priority must be within 1..99, got 120"):
        with realtime_priority(120):
            pass
    with realtime_priority(10) as note:
        assert note == "SCHED_FIFO priority 10" or note.startswith("SCHED_FIFO refused (SCHED_FIFO priority 10: ")
