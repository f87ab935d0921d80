"""A forced-choice session runs the one session path every experiment kind shares: its views bound once on the
port asked for, its timing check recorded, a damaged trials.csv refused in one error line, and its end waiting
for the operator page to see it (each once broken for this kind only)."""

import json
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

from devices.firmware.emulator import start_emulator
from study.__main__ import main
from study.session.webui import WebUI

from tests.support.study import write

ROOT = Path(__file__).resolve().parents[3]
QUICK = "tap_window_s = 0.6\nhoming_after_s = 0.3\nhoming_before_max_s = 0.1\n"
DISCRIMINATION = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 700.0
levels = [500.0, 950.0]
trials_per_level = 1
"""


def _run(tmp: Path, subject: str, *extra) -> int:
    proto = write(tmp / f"{subject}.toml", DISCRIMINATION)
    return main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject,
                 "--seed", "2", "--out", str(tmp / "DATA"), "--protocol", str(proto), *map(str, extra)])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_views_on_a_chosen_port_are_bound_once(tmp_path, capsys):
    """Once: the session bound --port N before making the subject folder, then again for the experiment, and
    stopped with "Address already in use" after the folder was made."""
    port = _free_port()
    assert _run(tmp_path, "V1", "--serve", "--port", port, "--token", "tok") == 0
    out = capsys.readouterr().out
    assert f"subject view:  http://127.0.0.1:{port}/" in out
    assert f"operator view: http://127.0.0.1:{port}/operator?token=tok" in out
    assert json.loads((tmp_path / "DATA" / "V1" / "session.json").read_text())["finished_at"]


def test_the_end_waits_for_the_operator_page_to_see_it(tmp_path, monkeypatch):
    """Once: a forced-choice session stopped its views at once, and the operator page showed "RUNNER STOPPED"
    over the last trial instead of "session complete"."""
    ends = []
    seen, stop = WebUI.stop_when_seen, WebUI.stop

    def stop_when_seen(self, *args, **kwargs):
        ends.append(("stop_when_seen", self.ui.snapshot("operator")))
        return seen(self, *args, **kwargs)

    monkeypatch.setattr(WebUI, "stop_when_seen", stop_when_seen)
    monkeypatch.setattr(WebUI, "stop", lambda self: (ends.append(("stop", None)), stop(self))[1])
    assert _run(tmp_path, "E1", "--serve") == 0
    assert ends and ends[0][0] == "stop_when_seen", ends
    final = ends[0][1]
    assert final["phase"] == "done" and final["finished"] is True and final["message"] == "session complete"


def test_a_damaged_trials_csv_is_one_error_line(tmp_path, capsys):
    """Once: a line the csv module cannot read (a field over its size limit) gave a _csv.Error traceback on
    --resume, where the rating study gave one line naming the file, the line and the repair."""
    assert _run(tmp_path, "D1") == 0
    folder = tmp_path / "DATA" / "D1"
    session = json.loads((folder / "session.json").read_text())
    session["finished_at"] = None
    (folder / "session.json").write_text(json.dumps(session))
    trials = folder / "trials.csv"
    lines = trials.read_text().splitlines(keepends=True)
    trials.write_text(lines[0] + lines[1] + "D1,2," + "x" * 200_000 + "\n")
    capsys.readouterr()
    assert main(["run", "--quiet", "--subject", "D1", "--out", str(tmp_path / "DATA"), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"error: {trials} line 3: not CSV (field larger than field limit (131072))"), err
    assert 'Repair (docs/study.md, "A damaged trials.csv")' in err


def test_the_timing_check_before_a_hardware_session_is_recorded(tmp_path):
    """Once: the forced-choice session started before the check's record was written (the rating study's
    code path wrote it after its own start), so session.json held no ``timing_check``."""
    port, handle = start_emulator("streaming", process=True, taps_m_s=(0.1,), watchdog_ms=250)
    proto = write(tmp_path / "p.toml", DISCRIMINATION.replace(QUICK, 'tap_window_s = 2.0\nservo_watchdog_s = 0.25\n'
                                                              'timing_check_s = 1.5\ntiming_link_rtt_p99_ms = 1e-6\n'))
    session = tmp_path / "DATA" / "T1" / "session.json"
    cmd = [sys.executable, "-m", "study", "run", "--device", f"serial:{port}?loss_timeout_s=0.02", "--participant",
           "keyboard", "--subject", "T1", "--out", str(tmp_path / "DATA"), "--age", "30", "--gender", "male",
           "--handedness", "right", "--experience", "few", "--audio", "off", "--token", "tok", "--protocol",
           str(proto), "--accept-timing"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        views = []
        for line in proc.stdout:   # the views' addresses are printed once session.json holds the check
            views.append(line)
            if line.startswith("operator view:"):
                break
        else:
            raise AssertionError(proc.stderr.read())
        data = json.loads(session.read_text())
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    finally:
        if proc.poll() is None:
            proc.kill()
        handle.stop()
    assert len([v for v in views if v.startswith("subject view:")]) == 1
    check = data["timing_check"]
    assert check["accepted_override"] is True and check["verdict"]["met"] is False
    assert any("link round trip p99" in f for f in check["verdict"]["failed"])
    assert data["experiment"]["kind"] == "discrimination" and data["servo_policy"]
    events = [json.loads(ln) for ln in (session.parent / "schedule.jsonl").read_text().splitlines()]
    assert any(e.get("event") == "timing_check" and e["accepted_override"] is True for e in events)
    assert re.search(r"running anyway as --accept-timing asks", proc.stderr.read())
