"""``study run`` validates ports, hosts, numbers and paths before it makes the subject folder (issue 38,
items 6 and 12): one ``error:`` line, exit 2, no folder, and the rerun with good values starts afresh."""

from __future__ import annotations

import socket

import pytest

from tests.support.study import quick_args, run_study, write


@pytest.fixture
def busy_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


def _refused(tmp_path, capsys, *extra) -> str:
    code = run_study(*quick_args(tmp_path, "S1", 3, "--serve", "--samples", "wood", "--repetitions", "1", *extra))
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "DATA" / "S1").exists()          # no subject folder: nothing to --resume
    return err.strip()


def test_a_busy_port_is_refused_before_the_subject_folder(tmp_path, capsys, busy_port):
    err = _refused(tmp_path, capsys, "--port", busy_port)
    assert err == (f"error: --host 127.0.0.1 --port {busy_port}: cannot serve the views there (Address already in "
                   "use); nothing was written")
    # the rerun on a free port is a new session, not "already has data ... use --resume"
    assert run_study(*quick_args(tmp_path, "S1", 3, "--serve", "--samples", "wood", "--repetitions", "1")) == 0
    assert (tmp_path / "DATA" / "S1" / "session.json").is_file()


@pytest.mark.parametrize("extra, message", [
    (("--port", "70000"), "error: --port must be 0..65535 (0: any free port), got 70000"),
    (("--port", "-1"), "error: --port must be 0..65535 (0: any free port), got -1"),
    (("--host", "192.0.2.1"), "error: --host 192.0.2.1 --port 0: cannot serve the views there (Cannot assign "
                              "requested address); nothing was written"),
    (("--tap-window-s", "1e308"), "command line: tap_window_s must be <= 60.0, got 1e+308"),  # no OverflowError
    (("--repetitions", "1000000"), "command line: repetitions must be an integer 1..100, got 1000000"),
])
def test_bad_addresses_and_numbers_are_refused_before_the_subject_folder(tmp_path, capsys, extra, message):
    err = _refused(tmp_path, capsys, *extra)
    assert err == message if message.startswith("error: ") else (err.startswith("error: ") and err.endswith(message))


@pytest.mark.parametrize("line, message", [
    ("repetitions = 1000000", "repetitions must be an integer 1..100, got 1000000"),
    ("tap_window_s = 1e308", "tap_window_s must be <= 60.0, got 1e+308"),
    ("home_height_m = 10", "home_height_m must be <= 0.1, got 10"),   # was blamed on the "synthetic rater"
])
def test_protocol_values_are_bounded_and_blamed_on_their_key(tmp_path, capsys, line, message):
    proto = write(tmp_path / "p.toml", line + "\n")
    code = run_study("--subject", "S1", "--seed", 1, "--out", tmp_path / "DATA", "--protocol", proto)
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == f"error: {proto}: {message}"
    assert not (tmp_path / "DATA" / "S1").exists()


def test_protocol_dev_null_is_not_called_missing(tmp_path, capsys):
    code = run_study("--subject", "S1", "--seed", 1, "--out", tmp_path / "DATA", "--protocol", "/dev/null")
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip() == ("error: protocol file /dev/null is not a regular file (a device or pipe); give a TOML or "
                           "JSON file")


def test_the_disconnect_message_says_output_zeroed_once():
    from study.session.apparatus import ServoStopped
    from study.session.run import servo_stopped_message

    told = ServoStopped("serial:/dev/ttyACM0: disconnected (read failed); output zeroed by the device watchdog")
    assert servo_stopped_message(told) == str(told)
    assert servo_stopped_message(ServoStopped("watchdog: a servo period of 30 ms")) == \
        "watchdog: a servo period of 30 ms; the output was zeroed"
