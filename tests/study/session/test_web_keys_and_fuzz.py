"""Issue 38, item 11 (web) and the web API fuzz test: a rating carries its trial's id and is taken once, two
different Content-Length headers are refused, and seeded random requests (loopback only, bounded) never get a
500 or a traceback, never rate a trial they do not name and never act for the operator without the token."""

import json
import random
import re
import socket

import pytest

from study.session.uistate import RATING_KEYS, UiState
from study.session.webui import MAX_BODY_BYTES, WebUI

TOKEN = "fuzz-t0ken"


@pytest.fixture
def served():
    ui = UiState()
    web = WebUI(ui, token=TOKEN).start()
    yield ui, web
    web.stop()


def request(port: int, data: bytes) -> tuple[int | None, bytes]:
    """Send raw bytes to the server on loopback and read the answer to the end: (status or None, body)."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:  # a guard: answers take milliseconds
        s.sendall(data)
        out = b""
        while True:
            try:
                chunk = s.recv(65536)
            except ConnectionResetError:
                break
            if not chunk:
                break
            out += chunk
    head, _, body = out.partition(b"\r\n\r\n")
    m = re.match(rb"HTTP/1\.[01] (\d{3})", head)
    return (int(m.group(1)) if m else None), body


def post(port: int, path: bytes, body: bytes, headers: bytes = b"", length=None) -> bytes:
    lengths = [str(len(body)).encode()] if length is None else length
    return (b"POST " + path + b" HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n" % port + headers
            + b"".join(b"Content-Length: " + v + b"\r\n" for v in lengths) + b"\r\n" + body)


def key(port: int, k: str, trial_id) -> tuple[int, dict]:
    body = {"key": k} if trial_id is None else {"key": k, "trial_id": trial_id}
    status, raw = request(port, post(port, b"/api/key", json.dumps(body).encode(),
                                     b"Content-Type: application/json\r\n"))
    return status, json.loads(raw)


def test_a_rating_is_taken_once_and_only_for_the_trial_it_names(served):
    """Before: a replayed ``/api/key`` POST (``{"key": "7"}``) was taken as the current trial's rating."""
    ui, web = served
    ui.set_subject("rate", "rate", "testing:3:1")
    first = ui.snapshot("subject")["trial_id"]
    assert first.startswith("testing:3:1:") and len(first) == len("testing:3:1:") + 8
    status, body = key(web.port, "5", first)
    assert status == 200 and body["accepted"] and ui.rating() == "5"
    status, body = key(web.port, "7", first)                 # the same request again
    assert status == 409 and not body["accepted"] and "already taken" in body["refused"]
    assert ui.rating() == "5"
    ui.set_subject("rate", "rate", "testing:4:1")             # the next trial
    status, body = key(web.port, "7", first)                  # replayed from the last one
    assert status == 409 and "not the current trial" in body["refused"] and ui.rating() is None
    assert ui.keys_refused == 1
    status, body = key(web.port, "7", None)                   # without an id: refused as malformed
    assert status == 400 and "trial_id" in body["error"] and ui.rating() is None
    ui.set_subject("rate", "rate", "testing:4:1")             # the same trial presented again: a new id
    assert ui.snapshot("subject")["trial_id"] != first
    status, body = key(web.port, "2", ui.snapshot("subject")["trial_id"])
    assert status == 200 and ui.rating() == "2"


def test_familiarization_enter_is_bound_to_its_window(served):
    ui, web = served
    ui.set_subject("tap", "familiarization", "familiarization:2:1")
    old = ui.snapshot("subject")["trial_id"]
    ui.set_subject("tap", "familiarization", "familiarization:3:1")
    assert key(web.port, "Enter", old)[0] == 409 and not ui.familiarization_ended()
    assert key(web.port, "Enter", ui.snapshot("subject")["trial_id"])[0] == 200 and ui.familiarization_ended()


@pytest.mark.parametrize("lengths, expected", [
    ([b"12", b"2"], 400), ([b"2", b"12"], 400),    # before: accepted, the first one won
    ([b"12", b"12"], 200),                           # the same value twice is one length
])
def test_conflicting_content_length_headers_are_refused(served, lengths, expected):
    ui, web = served
    ui.set_subject("rate", "rate", "testing:1:1")
    body = json.dumps({"key": "3", "trial_id": ui.snapshot("subject")["trial_id"]}).encode()
    lengths = [str(len(body)).encode() if v == b"12" else v for v in lengths]
    status, raw = request(web.port, post(web.port, b"/api/key", body, length=lengths))
    assert status == expected, raw
    assert (ui.rating() == "3") == (expected == 200)
    if expected == 400:
        assert json.loads(raw) == {"error": "conflicting Content-Length headers"}


# -- the fuzz test ---------------------------------------------------------------------------------------------
PATHS = [b"/", b"/subject", b"/api/key", b"/api/subject", b"/api/operator", b"/operator", b"/api/operator/confirm",
         b"/api/operator/abort", b"/api/operator/pause", b"/api/operator/end_familiarization", b"/static/subject.js",
         b"/static/../webui.py", b"/api/key/../operator", b"//api/key", b"/api/key?key=5", b"/%00", b"/" + b"a" * 3000]
METHODS = [b"GET", b"POST", b"PUT", b"HEAD", b"DELETE", b"OPTIONS", b"G\x00T", b"POST /x HTTP/1.1\r\nPOST"]
ALLOWED = {200, 400, 403, 404, 409, 413, 414, 431, 501}


def _fuzz_body(rng: random.Random, ui: UiState, seen_ids: list) -> bytes:
    current = ui.snapshot("subject")["trial_id"]
    if current not in seen_ids:
        seen_ids.append(current)
    choice = rng.randrange(8)
    if choice == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 64)))
    if choice == 1:
        return b"[" * rng.randrange(1, 3000) + b"]" * rng.randrange(0, 3000)
    values = [current, current[:-1] + "0", "testing:1:1:00000000", "", None, 5, [], {}, "x" * 100, "\u0000",
              float("nan")]
    body = {}
    if rng.random() < 0.9:
        body["key"] = rng.choice(list(RATING_KEYS) + ["Enter", "9", "", "q", 7, None, "5" * 40, ["5"]])
    if rng.random() < 0.8:
        r = rng.random()  # this presentation's id, an earlier one (a replay), or anything
        body["trial_id"] = current if r < 0.35 else rng.choice(seen_ids) if r < 0.6 else rng.choice(values)
    for _ in range(rng.randrange(3)):
        body["".join(rng.choice("abc_") for _ in range(4))] = rng.choice(values)
    text = json.dumps(body)  # NaN as the JSON extension NaN: the server must refuse or ignore it, not crash
    if choice == 2 and text:
        cut = rng.randrange(len(text))
        text = text[:cut]
    return text.encode("utf-8", "surrogatepass")


def _fuzz_request(rng: random.Random, port: int, ui: UiState, seen_ids: list) -> tuple[bytes, dict]:
    method = rng.choice(METHODS) if rng.random() < 0.15 else rng.choice([b"GET", b"POST"])
    path = b"/api/key" if rng.random() < 0.3 else rng.choice(PATHS)
    token = rng.choice([None, TOKEN, "guess", TOKEN + "x", ""])
    if token is not None and rng.random() < 0.5:
        path += (b"&" if b"?" in path else b"?") + b"token=" + token.encode()
    headers = []
    host = rng.choice([b"127.0.0.1:%d" % port] * 4 + [b"localhost:%d" % port, b"evil.example:%d" % port,
                                                    b"127.0.0.1", None, b"[::1]:%d" % port])
    if host is not None:
        headers.append(b"Host: " + host)
    if token is not None and rng.random() < 0.3:
        headers.append(b"X-Study-Token: " + token.encode())
    origin = rng.choice([None, None, b"http://127.0.0.1:%d" % port, b"http://evil.example", b"null"])
    if origin is not None:
        headers.append(b"Origin: " + origin)
    if rng.random() < 0.1:
        headers.append(b"Sec-Fetch-Site: " + rng.choice([b"cross-site", b"same-origin", b"none"]))
    if rng.random() < 0.05:
        headers.append(b"Transfer-Encoding: chunked")
    if rng.random() < 0.1:
        headers.append(b"X-" + bytes(rng.randrange(65, 91) for _ in range(5)) + b": "
                       + bytes(rng.randrange(32, 127) for _ in range(rng.randrange(80))))
    body = _fuzz_body(rng, ui, seen_ids) if method == b"POST" or rng.random() < 0.1 else b""
    n = len(body)
    declared = rng.choice([[n], [n], [n], [max(0, n - 3)], [n, n + 1], [n, n], [-1], ["12x"], [MAX_BODY_BYTES + 1],
                           [10 ** 12], [], ["\u0662"]])
    for v in declared:
        headers.append(b"Content-Length: " + str(v).encode())
    data = method + b" " + path + b" HTTP/1.0\r\n" + b"".join(h + b"\r\n" for h in headers) + b"\r\n" + body
    meta = {"method": method, "path": path, "host": host, "token": token, "origin": origin, "declared": declared,
            "body": body}
    return data, meta


def test_web_api_fuzz(served):
    """400 seeded random requests over loopback (never a body shorter than declared: each would wait for the
    request deadline): each gets an HTTP status from the allowed set, never a 500 or a traceback or the
    token; a rating changes only for a well-formed key naming the current trial; the operator's state changes
    only with the token; the server answers an honest request at the end."""
    ui, web = served
    rng = random.Random(38)
    port = web.port
    statuses, seen_ids = {}, []
    for i in range(400):
        if rng.random() < 0.1:  # the runner moves on: a new presentation (rating or other prompt)
            ui.set_subject("msg", rng.choice(["rate", "wait", "familiarization"]), f"testing:{i}:1")
        before_subject, before_operator = ui.snapshot("subject"), ui.snapshot("operator")
        rating_before = ui._rating
        data, meta = _fuzz_request(rng, port, ui, seen_ids)
        status, body = request(port, data)
        statuses[status] = statuses.get(status, 0) + 1
        assert status in ALLOWED, (i, status, data[:300], body[:300])
        assert b"Traceback" not in body and TOKEN.encode() not in body, (i, data[:300])
        if ui._rating != rating_before:   # a rating was taken: only by a well-formed key for this presentation
            sent = json.loads(meta["body"])
            assert meta["method"] == b"POST" and meta["path"] == b"/api/key" and status == 200, (i, meta)
            assert sent["trial_id"] == before_subject["trial_id"] and before_subject["prompt"] == "rate", (i, sent)
            assert sent["key"] in RATING_KEYS and rating_before is None and ui._rating == sent["key"]
            assert len(meta["declared"]) == 1 or len(set(meta["declared"])) == 1
        after_operator = ui.snapshot("operator")
        changed = {k for k in ("paused", "aborted", "awaiting_confirm") if after_operator[k] != before_operator[k]}
        if changed:
            assert meta["token"] == TOKEN and meta["path"].startswith(b"/api/operator/"), (i, meta, changed)
            assert meta["origin"] in (None, b"http://%s" % meta["host"]), (i, meta)
        if after_operator["aborted"]:     # reset the state the fuzzing reached, to keep every path reachable
            ui.operator["aborted"] = False
    status, body = request(port, b"GET /api/subject HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
    assert status == 200 and "trial_id" in json.loads(body)
    # the run reached the interesting answers, not only one kind of refusal
    assert statuses.get(200, 0) >= 10 and statuses.get(400, 0) >= 20 and statuses.get(403, 0) >= 5, statuses
    assert statuses.get(409, 0) >= 1 and statuses.get(413, 0) >= 1, statuses
