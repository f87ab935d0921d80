"""The subject and operator views in Debian's headless Chromium (playwright, no downloaded browsers)."""

import itertools
import json
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from http.client import HTTPException
from pathlib import Path

import pytest
from playwright.sync_api import Error as PlaywrightError
from playwright.sync_api import TimeoutError as PlaywrightTimeoutError
from playwright.sync_api import sync_playwright

from study.session.uistate import KEY_HINT, UiState
from study.session.webui import WebUI

from tests.support.needs import chromium
from tests.support.study import read_rows, write, QUICK_PROTOCOL

ROOT = Path(__file__).resolve().parents[3]
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="module")
def browser():
    exe = chromium()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def served():
    ui = UiState()
    web = WebUI(ui, token="t0ken-123").start()
    yield ui, web
    web.stop()


def http(method, url, body=None, headers=None):
    req = urllib.request.Request(url, method=method, data=None if body is None else json.dumps(body).encode(),
                                 headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def test_operator_page_and_api_need_the_token(served):
    ui, web = served
    base = f"http://127.0.0.1:{web.port}"
    assert web.host == "127.0.0.1"
    assert http("GET", base + "/operator")[0] == 403
    assert http("GET", base + "/operator?token=wrong")[0] == 403
    assert http("GET", base + "/api/operator")[0] == 403
    assert http("POST", base + "/api/operator/abort", {})[0] == 403
    assert not ui.snapshot("operator")["aborted"]
    status, body = http("GET", base + "/operator?token=t0ken-123")
    assert status == 200 and b"Operator" in body
    assert http("GET", base + "/api/operator", headers={"X-Study-Token": "t0ken-123"})[0] == 200
    # the subject view needs no token but never sees what is placed
    ui.request_confirm("placeholder A")
    status, body = http("GET", base + "/api/subject")
    assert status == 200 and b"placeholder" not in body


def test_subject_keys_in_chromium(browser, served):
    ui, web = served
    page = browser.new_page(bypass_csp=True)  # eval for wait_for_function; CSP: test_web_attacks
    page.goto(web.subject_url)
    ui.set_subject("How well did this sample represent tapping on the real wood?", "rate")
    page.wait_for_function("document.getElementById('message').textContent.startsWith('How well')")
    assert page.is_visible("#scale")
    for key in ("9", "a", "0", "Space"):
        page.keyboard.press(key)
        page.wait_for_function(f"document.getElementById('hint').textContent === {json.dumps(KEY_HINT)}")
        assert ui.rating() is None
    page.keyboard.press("5")
    page.wait_for_function("document.getElementById('message').textContent === 'Thank you.'")
    assert ui.rating() == "5"
    # keys are sent in order, so every ignored key was handled before the rating's answer came back
    assert ui.keys_ignored == 4
    # keys pressed faster than the runner answers still count in the order pressed: the first one wins
    ui.set_subject("rate quickly", "rate")
    page.wait_for_function("document.getElementById('message').textContent === 'rate quickly'")
    for key in ("3", "6", "q"):
        page.keyboard.press(key)
    page.wait_for_function("document.getElementById('message').textContent === 'Thank you.'")
    deadline = time.monotonic() + 5
    while ui.keys_ignored < 6 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ui.rating() == "3"
    assert ui.keys_ignored == 6
    # x rejects
    ui.set_subject("rate again", "rate")
    page.wait_for_function("document.getElementById('message').textContent === 'rate again'")
    page.keyboard.press("x")
    page.wait_for_function("document.getElementById('message').textContent === 'Thank you.'")
    assert ui.rating() == "x"
    page.close()


def test_an_answer_older_than_the_state_shown_never_replaces_it(browser, served):
    """A busy server can write a key's answer after a newer poll's: the page must not go back to the answered
    trial (it would send the next key with that trial's id, which the runner refuses: the key was lost)."""
    ui, web = served
    page = browser.new_page(bypass_csp=True)
    page.goto(web.subject_url)
    ui.set_subject("first", "rate", "testing:1:1")
    page.wait_for_function("document.getElementById('message').textContent === 'first'")
    old = ui.snapshot("subject")
    ui.set_subject("second", "rate", "testing:2:1")
    page.wait_for_function("document.getElementById('message').textContent === 'second'")
    # the late answer arrives; the message is read in the same step (a poll between would hide the outcome)
    shown = "state => { show(state); return document.getElementById('message').textContent; }"
    assert page.evaluate(shown, old) == "second"
    page.keyboard.press("4")
    page.wait_for_function("document.getElementById('message').textContent === 'Thank you.'")
    assert ui.rating() == "4" and ui.keys_refused == 0
    # a resumed session's runner is a new state lifetime whose seq starts again: its states are taken
    fresh = UiState().snapshot("subject")
    assert fresh["seq"] < old["seq"] and fresh["instance"] != old["instance"]
    assert page.evaluate(shown, fresh) == "Please wait."
    page.close()


def test_operator_page_in_chromium(browser, served):
    ui, web = served
    page = browser.new_page(bypass_csp=True)  # eval for wait_for_function; CSP: test_web_attacks
    page.goto(web.operator_url)
    ui.set_operator(phase="testing", trial=4, attempt=2, progress={"testing": {"total": 36, "attempts": 5, "valid": 4}},
                    last_attempt={"sample": "hfam_firm", "kind": "virtual", "n_taps": 2,
                                  "incoming_velocities_m_s": [0.1, 0.12], "penetration_depths_m": [0.0012, 0.0014],
                                  "saturated": True, "overpowered": False, "rejected": False, "rating": 5})
    ui.request_confirm("placeholder B")
    page.wait_for_function("document.getElementById('place').textContent === 'Place: placeholder B'")
    text = page.inner_text("body")
    assert "0.100, 0.120" in text and "1.20, 1.40" in text and "yes (repeat)" in text and "4 / 36 valid" in text
    assert not ui.confirmed()
    page.click("#confirm")
    page.wait_for_function("document.getElementById('confirm').disabled")
    assert ui.confirmed()
    page.click("#pause")
    page.wait_for_function("document.getElementById('status').textContent.includes('PAUSED')")
    assert ui.snapshot("operator")["paused"]
    page.close()


def test_operator_page_fits_a_390_px_phone(browser, served):
    """At 390 px (a phone) the operator page is no wider than the screen, with a long last attempt shown."""
    ui, web = served
    page = browser.new_page(viewport={"width": 390, "height": 844}, bypass_csp=True)
    page.goto(web.operator_url)
    ui.set_operator(subject="P07-long-subject-name", phase="testing", trial=12, attempt=3,
                    progress={"demonstration": {"total": 12, "attempts": 14, "valid": 12},
                              "testing": {"total": 36, "attempts": 15, "valid": 12}},
                    last_attempt={"sample": "hfam_mine_with_a_long_name", "kind": "virtual", "n_taps": 6,
                                  "incoming_velocities_m_s": [0.101, 0.122, 0.093, 0.154, 0.111, 0.131],
                                  "penetration_depths_m": [0.0012, 0.0014, 0.0011, 0.0016, 0.0013, 0.0015],
                                  "saturated": True, "overpowered": True, "rejected": False, "rating": 5},
                    redraws=[{"phase": "testing", "trial": 4, "sample": "hfam_mine_with_a_long_name", "attempt": 2,
                              "reason": "clipped transient (the amplifier's limit) and an overpowered homing"}])
    ui.request_confirm("placeholder B (virtual samples alternate placeholders)")
    page.wait_for_function("document.getElementById('place').textContent.startsWith('Place: placeholder B')")
    page.wait_for_function("document.getElementById('last').rows.length > 0")
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, width
    page.close()


def step(op, subj, keys, places, typed):
    """One look at both views, acting like the operator and the subject would."""
    if op.is_enabled("#confirm"):
        places.append(op.inner_text("#place"))
        op.click("#confirm")
        op.evaluate("document.activeElement.blur()")
        op.wait_for_function("document.getElementById('confirm').disabled")
    state = json.loads(subj.evaluate("fetch('/api/subject').then(r => r.text())"))
    if state["prompt"] == "familiarization":
        subj.keyboard.press("Enter")
    elif state["prompt"] == "rate":
        # the page sends a key with the presentation it shows (subject.js polls every 150 ms): wait until it shows
        # this one, or the key answers the previous presentation and the runner rightly drops it (a loaded
        # fresh-clone run typed a '4' that was never recorded)
        try:
            subj.wait_for_function(f"trialId === {json.dumps(state['trial_id'])}", polling=50, timeout=10_000)
        except PlaywrightTimeoutError:
            return  # the runner moved on first: look again
        key = next(keys)
        subj.keyboard.press(key)
        typed.append(key)
        if key == "9":
            subj.wait_for_function("document.getElementById('hint').textContent.includes('1 to 7')")
        else:
            subj.wait_for_function("fetch('/api/subject').then(r => r.json()).then(s => s.prompt !== 'rate')",
                                   polling=50)


def test_keyboard_session_driven_through_both_views(browser, tmp_path):
    """A person's session (sim device, simulated hand): operator confirms placements, subject types ratings."""
    proto = write(tmp_path / "p.toml", QUICK_PROTOCOL)
    cmd = [sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "keyboard", "--subject", "P01",
           "--seed", "3", "--out", str(tmp_path / "DATA"), "--protocol", str(proto), "--samples", "wood,firm,hfam_soft",
           "--repetitions", "1", "--age", "30", "--gender", "female", "--handedness", "left", "--experience", "none",
           "--token", "tok", "--servo-process", "on"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        urls = {}
        while len(urls) < 2:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            m = re.match(r"(subject|operator) view:\s+(\S+)", line)
            if m:
                urls[m.group(1)] = m.group(2)
        assert urls["operator"].endswith("/operator?token=tok") and urls["subject"].startswith("http://127.0.0.1:")
        op = browser.new_page(bypass_csp=True)  # eval for wait_for_function; CSP: test_web_attacks
        op.goto(urls["operator"])
        subj = browser.new_page(bypass_csp=True)
        subj.goto(urls["subject"])
        places, typed = [], []
        # 9: ignored with a hint; x: rejected (repeated later); then ratings for whatever attempts remain
        keys = itertools.chain("9x3x67", itertools.cycle("45"))
        deadline = time.monotonic() + 90
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                step(op, subj, keys, places, typed)
            except PlaywrightError:
                try:
                    proc.wait(timeout=20)   # the session ended (and stopped its server) between two steps
                except subprocess.TimeoutExpired:
                    raise AssertionError("the views stopped answering while the session still runs") from None
                break
            time.sleep(0.05)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()
        # a normal finish: the runner waited for the open operator page to fetch the final state, which it
        # shows as complete (no red "RUNNER STOPPED: no answer from the runner" over stale state)
        runner_text = op.inner_text("#runner")
        assert runner_text.startswith("SESSION COMPLETE: ") and "trials valid" in runner_text, runner_text
        assert op.inner_text("#place") == "Session complete"
        assert all(op.is_disabled(f"#{b}") for b in ("confirm", "pause", "resume", "endfam", "abort"))
    finally:
        if proc.poll() is None:
            proc.kill()
    rows = read_rows(tmp_path / "DATA" / "P01")
    rated = [r for r in rows if r["phase"] != "familiarization"]
    assert [r["rating"] or "x" for r in rated] == [k for k in typed if k != "9"]
    assert sum(r["rejected"] == "true" for r in rated) == 2
    valid = [r for r in rated if r["valid"] == "true"]
    assert sorted(r["sample"] for r in valid if r["phase"] == "testing") == ["firm", "hfam_soft", "wood"]
    # an item is moved every trial: virtual samples alternate placeholders, real ones are named
    assert places[0] == "Place: real sample 'wood'"
    shown = [p.removeprefix("Place: ") for p in places[1:]]
    for a, b in zip(shown, shown[1:]):
        assert a != b or a.startswith("real sample")
    session = json.loads((tmp_path / "DATA" / "P01" / "session.json").read_text())
    assert session["experience"] == "none" and session["handedness"] == "left" and session["finished_at"]


def test_operator_abort_keeps_data_and_resume_continues(tmp_path):
    """Abort from the operator API mid-session: exit code 3, rows kept, session unfinished, resumable."""
    proto = write(tmp_path / "p.toml", QUICK_PROTOCOL + 'familiarization_sample = ""\n')
    base = ["--device", "sim", "--subject", "P02", "--out", str(tmp_path / "DATA"), "--token", "tok"]
    cmd = [sys.executable, "-m", "study", "run", *base, "--participant", "keyboard", "--seed", "5",
           "--protocol", str(proto), "--samples", "firm,soft", "--repetitions", "1", "--age", "40",
           "--gender", "male", "--handedness", "right", "--experience", "regular"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = None
        while port is None:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            m = re.match(r"operator view:\s+http://127.0.0.1:(\d+)/", line)
            port = m and int(m.group(1))
        api = f"http://127.0.0.1:{port}"
        hdr = {"X-Study-Token": "tok", "Content-Type": "application/json"}
        done = 0
        deadline = time.monotonic() + 60
        while done < 2 and time.monotonic() < deadline:   # two attempts: confirm placement, then rate
            op = json.loads(http("GET", api + "/api/operator", headers=hdr)[1])
            subj = json.loads(http("GET", api + "/api/subject")[1])
            if op["awaiting_confirm"]:
                http("POST", api + "/api/operator/confirm", {}, hdr)
            elif subj["prompt"] == "rate":
                assert json.loads(http("POST", api + "/api/key", {"key": "4", "trial_id": subj["trial_id"]},
                                              {"Content-Type": "application/json"})[1])["accepted"]
                done += 1
            time.sleep(0.03)
        while not json.loads(http("GET", api + "/api/operator", headers=hdr)[1])["awaiting_confirm"]:
            time.sleep(0.03)
        assert http("POST", api + "/api/operator/abort", {}, hdr)[0] == 200
        assert proc.wait(timeout=30) == 3
        assert "resume" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    folder = tmp_path / "DATA" / "P02"
    rows = read_rows(folder)
    assert [r["rating"] for r in rows] == ["4", "4"]
    assert json.loads((folder / "session.json").read_text())["finished_at"] is None
    # resume: the simulated rater cannot take over a person's session
    from study.__main__ import main

    assert main(["run", "--subject", "P02", "--out", str(tmp_path / "DATA"), "--resume",
                 "--participant", "simulated"]) == 2
    cmd = [sys.executable, "-m", "study", "run", *base, "--resume"]   # device and participant from session.json
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = None
        while port is None:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            m = re.match(r"operator view:\s+http://127.0.0.1:(\d+)/", line)
            port = m and int(m.group(1))
        api = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                op = json.loads(http("GET", api + "/api/operator", headers=hdr)[1])
                subj = json.loads(http("GET", api + "/api/subject")[1])
            except (urllib.error.URLError, ConnectionError, HTTPException):  # the session ended:
                # its server is gone, or the process exited while a response was being sent
                break
            if op["awaiting_confirm"]:
                http("POST", api + "/api/operator/confirm", {}, hdr)
            elif subj["prompt"] == "rate":
                http("POST", api + "/api/key", {"key": "6", "trial_id": subj["trial_id"]},
                     {"Content-Type": "application/json"})
            time.sleep(0.03)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    rows = read_rows(folder)
    assert [r["rating"] for r in rows][:2] == ["4", "4"] and set(r["rating"] for r in rows[2:]) <= {"6"}
    assert sorted(r["sample"] for r in rows if r["phase"] == "testing" and r["valid"] == "true") == ["firm", "soft"]
    assert json.loads((folder / "session.json").read_text())["finished_at"] is not None


def test_attempt_without_taps_keeps_the_operator_api_valid_json(served):
    ui, web = served
    ui.set_operator(last_attempt={"sample": "firm", "n_taps": 0, "incoming_velocity_mean_m_s": float("nan"),
                                  "incoming_velocities_m_s": []})
    status, body = http("GET", f"http://127.0.0.1:{web.port}/api/operator", headers={"X-Study-Token": "t0ken-123"})
    assert status == 200
    assert json.loads(body, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))[
        "last_attempt"]["incoming_velocity_mean_m_s"] is None
