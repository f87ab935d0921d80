"""Protocol and cross-site attacks on the views of a running session, with raw sockets and headless Chromium.

A keyboard session waits for the operator's first confirmation (so nothing is written meanwhile); each attack
must get its status within 2 s, the server must answer the next honest request, and the data folder must be
byte-for-byte unchanged. Cross-site posts are made by a real page on another origin in Chromium.
"""

import http.server
import json
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from playwright.sync_api import expect, sync_playwright

from study.session.webui import MAX_CONNECTIONS, REQUEST_DEADLINE_S

from tests.support.needs import chromium
from tests.support.study import QUICK_PROTOCOL, write

ROOT = Path(__file__).resolve().parents[3]
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


def snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("web")
    proto = write(tmp / "p.toml", QUICK_PROTOCOL)
    cmd = [sys.executable, "-m", "study", "run", "--device", "sim", "--subject", "W01", "--out", str(tmp / "DATA"),
           "--token", "s3cret-token", "--participant", "keyboard", "--seed", "5", "--protocol", str(proto),
           "--samples", "wood,firm", "--repetitions", "1", "--age", "30", "--gender", "female",
           "--handedness", "right", "--experience", "few"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = None
    while port is None:
        line = proc.stdout.readline()
        assert line, proc.stderr.read()
        m = re.match(r"operator view:\s+http://127.0.0.1:(\d+)/", line)
        port = m and int(m.group(1))
    folder = tmp / "DATA" / "W01"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # wait until the runner asks the operator to confirm the first placement
        status, body, _ = request(port, b"GET /api/operator HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n"
                                     b"X-Study-Token: s3cret-token\r\n\r\n" % port)
        if status == 200 and json.loads(body)["awaiting_confirm"]:
            break
        time.sleep(0.1)
    yield port, folder, proc
    proc.kill()
    proc.wait()


def request(port, data: bytes, drip_s: float = 0.0, timeout_s: float = 5.0):
    """Send raw bytes (optionally one byte every ``drip_s``); returns (status or None, body, seconds)."""
    t0 = time.monotonic()
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
    try:
        if drip_s:
            for b in data:
                try:
                    s.sendall(bytes([b]))
                except OSError:
                    break
                time.sleep(drip_s)
        else:
            s.sendall(data)
        out = b""
        while True:
            try:
                chunk = s.recv(65536)
            except (ConnectionResetError, TimeoutError):
                break
            if not chunk:
                break
            out += chunk
    finally:
        s.close()
    head, _, body = out.partition(b"\r\n\r\n")
    m = re.match(rb"HTTP/1\.[01] (\d{3})", head)
    return (int(m.group(1)) if m else None), body, time.monotonic() - t0


def honest(port):
    status, body, _ = request(port, b"GET /api/subject HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
    return status, json.loads(body) if status == 200 else None


def post(port, path: bytes, body: bytes, extra: bytes = b"", length: bytes | None = None) -> bytes:
    length = str(len(body)).encode() if length is None else length
    return (b"POST " + path + b" HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n" % port + extra +
            b"Content-Type: application/json\r\nContent-Length: " + length + b"\r\n\r\n" + body)


ATTACKS = [
    ("negative Content-Length", lambda p: post(p, b"/api/key", b"x" * 100000, length=b"-1"), 400),
    ("declared 1e9 body", lambda p: post(p, b"/api/key", b"", length=b"1000000000"), 413),
    ("Content-Length not a number", lambda p: post(p, b"/api/key", b"{}", length=b"12abc"), 400),
    # audit web_probe.txt: "\u00b2" (a header is decoded as Latin-1) passed str.isdigit(), then int() raised
    # in the server thread: a traceback and a dropped connection instead of a 400
    ("Content-Length superscript two", lambda p: post(p, b"/api/key", b"{}", length=b"\xb2"), 400),
    ("Content-Length Arabic-Indic digit", lambda p: post(p, b"/api/key", b"{}", length="\u0662".encode()), 400),
    ("chunked body", lambda p: (b"POST /api/key HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nTransfer-Encoding: chunked\r\n\r\n"
                                b"5\r\n{}{}{\r\n0\r\n\r\n" % p), 400),
    ("body shorter than declared (slow)", lambda p: post(p, b"/api/key", b"{", length=b"100"), 408),
    ("malformed JSON", lambda p: post(p, b"/api/key", b"{key: 5"), 400),
    ("non-UTF-8 JSON", lambda p: post(p, b"/api/key", b'{"key": "\xff"}'), 400),
    ("JSON array", lambda p: post(p, b"/api/key", b"[1, 2]"), 400),
    ("deeply nested JSON", lambda p: post(p, b"/api/key", b"[" * 2000 + b"]" * 2000), 400),
    ("missing field", lambda p: post(p, b"/api/key", b"{}"), 400),
    ("wrong type", lambda p: post(p, b"/api/key", b'{"key": 5}'), 400),
    ("long key", lambda p: post(p, b"/api/key", json.dumps({"key": "5" * 100}).encode()), 400),
    ("cross-origin key", lambda p: post(p, b"/api/key", b'{"key": "5"}', b"Origin: http://evil.example\r\n"), 403),
    ("cross-origin referer", lambda p: post(p, b"/api/key", b'{"key": "5"}',
                                            b"Referer: http://evil.example/page\r\n"), 403),
    ("cross-site fetch metadata", lambda p: post(p, b"/api/key", b'{"key": "5"}', b"Sec-Fetch-Site: cross-site\r\n"),
     403),
    ("DNS rebinding Host", lambda p: (b"POST /api/key HTTP/1.1\r\nHost: evil.example:%d\r\nContent-Length: 12\r\n\r\n"
                                      b'{"key": "5"}' % p), 400),
    ("no Host", lambda p: b"GET /api/subject HTTP/1.0\r\n\r\n", 400),
    ("wrong token", lambda p: post(p, b"/api/operator/abort?token=guess", b"{}"), 403),
    ("token with non-ASCII", lambda p: post(p, b"/api/operator/abort", b"{}", "X-Study-Token: \u00e9\r\n".encode()),
     403),
    ("cross-origin with the token", lambda p: post(p, b"/api/operator/abort?token=s3cret-token", b"{}",
                                                   b"Origin: http://evil.example\r\n"), 403),
    ("garbage request line", lambda p: b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + b"\x00" * 64 + b"\r\n\r\n",
     400),
    ("huge header line", lambda p: b"GET / HTTP/1.1\r\nX: " + b"a" * 70000 + b"\r\n\r\n", 431),
]


@pytest.mark.parametrize("name, make, expected", ATTACKS, ids=[a[0] for a in ATTACKS])
def test_attack_answered_quickly_server_stays_up_data_unchanged(session, name, make, expected):
    port, folder, proc = session
    before = snapshot(folder)
    status, body, seconds = request(port, make(port))
    assert status == expected, (name, status, body[:200])
    assert seconds < 2.0, (name, seconds)
    assert b"Traceback" not in body and b"s3cret-token" not in body
    assert honest(port)[0] == 200
    assert snapshot(folder) == before
    assert proc.poll() is None


def test_slowloris_gets_408_within_2_s_and_the_cap_holds(session):
    port, folder, proc = session
    before = snapshot(folder)
    status, _, seconds = request(port, b"GET /api/subject HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nX-Slow: " % port +
                                 b"a" * 40, drip_s=0.05)
    assert status == 408 and REQUEST_DEADLINE_S - 0.1 < seconds < 2.0, (status, seconds)
    # more idle connections than the cap: the extra ones get 503 at once, then all expire
    socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(MAX_CONNECTIONS + 8)]
    try:
        busy = [request(port, b"GET /api/subject HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
                for _ in range(2)]
        assert all(s[0] in (503, 200) and s[2] < 2.0 for s in busy), busy
    finally:
        for s in socks:
            s.close()
    time.sleep(REQUEST_DEADLINE_S + 0.3)
    assert honest(port)[0] == 200
    assert snapshot(folder) == before


def test_an_idle_kept_alive_connection_is_closed_without_an_answer(session):
    """No 408 on a connection that sent nothing: it could meet the browser's next request (a key) on its way."""
    port, folder, proc = session
    before = snapshot(folder)
    status, body, seconds = request(port, b"")   # connect, send nothing, read until the server closes
    assert status is None and body == b"" and REQUEST_DEADLINE_S - 0.1 < seconds < REQUEST_DEADLINE_S + 1.5, \
        (status, body, seconds)
    assert honest(port)[0] == 200 and snapshot(folder) == before


def test_headers_on_every_answer(session):
    port, _, _ = session
    for path in (b"/", b"/operator?token=s3cret-token", b"/api/subject", b"/static/operator.js", b"/nothing"):
        t0 = time.monotonic()
        s = socket.create_connection(("127.0.0.1", port))
        s.sendall(b"GET " + path + b" HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
        s.close()
        head = data.partition(b"\r\n\r\n")[0].decode().lower()
        assert "cache-control: no-store" in head and "x-frame-options: deny" in head, path
        assert "content-security-policy: default-src 'none'; script-src 'self'" in head, path
        assert "unsafe-inline" not in head and time.monotonic() - t0 < 2.0
    html = "".join((ROOT / "study" / "session" / "web" / name).read_text() for name in ("operator.html", "subject.html"))
    assert "<script>" not in html and "<style>" not in html  # no inline code or style: the CSP forbids them


def test_a_page_on_another_origin_cannot_post_keys_or_frame_the_views(session):
    """Real Chromium: a page served from another port posts to /api/key and tries to frame the operator view."""
    port, folder, proc = session
    before = snapshot(folder)
    evil = (f"<html><body><iframe id=f src='http://127.0.0.1:{port}/operator?token=s3cret-token'></iframe><script>"
            f"fetch('http://127.0.0.1:{port}/api/key', {{method: 'POST', mode: 'no-cors', "
            f"headers: {{'Content-Type': 'text/plain'}}, body: JSON.stringify({{key: '5'}})}})"
            f".then(() => document.title = 'sent', e => document.title = 'error');</script></body></html>").encode()

    class Evil(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.end_headers()
            self.wfile.write(evil)

        def log_message(self, *a):
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Evil)
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
            page = b.new_page()
            answers = []
            page.on("response", lambda r: answers.append((r.url, r.status)))
            page.goto(f"http://localhost:{srv.server_address[1]}/")
            expect(page).not_to_have_title("", timeout=5000)
            # the operator view refused to be framed (X-Frame-Options / frame-ancestors): its frame stays empty
            frame = page.frame_locator("#f")
            assert frame.locator("#place").count() == 0
            # the view itself works in the browser under its CSP (scripts are files, not inline)
            view = b.new_page()
            errors = []
            view.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            view.goto(f"http://127.0.0.1:{port}/operator?token=s3cret-token")
            expect(view.locator("#place")).to_contain_text("Place:", timeout=5000)  # no eval under the CSP
            assert not [e for e in errors if "Content Security Policy" in e], errors
            b.close()
    finally:
        srv.shutdown()
        srv.server_close()
    assert [s for u, s in answers if u.endswith("/api/key")] in ([403], [])
    assert honest(port)[1]["hint"] == ""          # the key was never accepted
    assert snapshot(folder) == before
