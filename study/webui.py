"""The study's two views, served by the runner over a small local web server.

* Subject view ``/``: large, simple instructions; keyboard only (1-7 rate,
  ``x`` reject, Enter ends familiarization). Other keys are ignored with a
  hint. It never shows which sample is under the stylus (blind study).
* Operator view ``/operator?token=T``: what to place next (the real sample,
  or placeholder A/B alternating for virtual samples so an item is moved every
  trial), progress, the last attempt's velocities, penetrations and clipping,
  and confirm / pause / abort buttons. Every operator page and API call needs
  the token (a 403 without it); the token is printed on the console.

The server (``ThreadingHTTPServer``) binds to 127.0.0.1 unless asked
otherwise and runs in daemon threads; the runner talks to it through
:class:`UiState`, a lock-protected state with condition waits. Keys are
validated by the server (the page's own check is only for the hint).
"""

from __future__ import annotations

import hmac
import json
import math
import secrets
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlparse

RATING_KEYS = ("1", "2", "3", "4", "5", "6", "7", "x")
KEY_HINT = "Please use the keys 1 to 7 to rate, or x to reject this trial."
FAM_HINT = "Keep tapping on the wood. Press Enter when you are done."


class Aborted(RuntimeError):
    """The operator aborted the session (data written so far is kept; resume with --resume)."""


def _json_safe(obj):
    """Replace NaN/inf (e.g. the mean velocity of an attempt without taps) by None: browsers reject NaN in JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


class UiState:
    """State shared between the runner thread and the HTTP handler threads."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.subject = {"message": "Please wait.", "prompt": "wait", "hint": "", "seq": 0}
        self.operator = {"phase": "", "trial": None, "attempt": None, "place": "", "awaiting_confirm": False,
                         "progress": {}, "last_attempt": None, "paused": False, "aborted": False,
                         "message": "", "redraws": [], "seq": 0}
        self._rating = None
        self._end_familiarization = False
        self._confirmed = False
        self.keys_ignored = 0

    # -- runner side ---------------------------------------------------------
    def set_subject(self, message: str, prompt: str) -> None:
        with self._cond:
            self.subject.update(message=message, prompt=prompt, hint="")
            self.subject["seq"] += 1
            if prompt == "rate":
                self._rating = None
            self._cond.notify_all()

    def set_operator(self, **fields) -> None:
        with self._cond:
            self.operator.update(_json_safe(fields))
            self.operator["seq"] += 1
            self._cond.notify_all()

    def request_confirm(self, place: str) -> None:
        with self._cond:
            self._confirmed = False
            self.operator.update(place=place, awaiting_confirm=True)
            self.operator["seq"] += 1
            self._cond.notify_all()

    def confirmed(self) -> bool:
        with self._cond:
            self._check_abort()
            return self._confirmed and not self.operator["paused"]

    def rating(self):
        """The key the subject gave ('1'..'7' or 'x'), or None yet."""
        with self._cond:
            self._check_abort()
            return self._rating

    def familiarization_ended(self) -> bool:
        with self._cond:
            return self._end_familiarization

    def wait(self, predicate, timeout_s: float | None = None) -> bool:
        """Block until ``predicate()`` (called under the lock) is true; raises :class:`Aborted`."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._check_abort()
                if predicate():
                    return True
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(0.1 if remaining is None else min(0.1, remaining))

    def _check_abort(self) -> None:
        if self.operator["aborted"]:
            raise Aborted("the operator aborted the session")

    # -- handler side --------------------------------------------------------
    def subject_key(self, key: str) -> dict:
        with self._cond:
            prompt = self.subject["prompt"]
            accepted = False
            if prompt == "rate" and key in RATING_KEYS and self._rating is None:
                self._rating = key
                accepted = True
                self.subject.update(message="Thank you.", prompt="wait", hint="")
            elif prompt == "familiarization" and key == "Enter":
                self._end_familiarization = True
                accepted = True
                self.subject.update(message="Familiarization ends after this round. Please wait.", prompt="wait",
                                    hint="")
            else:
                self.keys_ignored += 1
                self.subject["hint"] = KEY_HINT if prompt == "rate" else (
                    FAM_HINT if prompt == "familiarization" else "No key is needed now; please wait.")
            self.subject["seq"] += 1
            self._cond.notify_all()
            return {"accepted": accepted, **self.subject}

    def operator_action(self, action: str) -> dict:
        with self._cond:
            if action == "confirm":
                if not self.operator["awaiting_confirm"]:
                    return {"ok": False, "error": "nothing to confirm"}
                self._confirmed = True
                self.operator["awaiting_confirm"] = False
            elif action == "pause":
                self.operator["paused"] = True
            elif action == "resume":
                self.operator["paused"] = False
            elif action == "abort":
                self.operator["aborted"] = True
            elif action == "end_familiarization":
                self._end_familiarization = True
            else:
                return {"ok": False, "error": f"unknown action {action!r}"}
            self.operator["seq"] += 1
            self._cond.notify_all()
            return {"ok": True}

    def snapshot(self, which: str) -> dict:
        with self._cond:
            return json.loads(json.dumps(self.subject if which == "subject" else self.operator))


def _asset(name: str) -> bytes:
    return resources.files("study").joinpath("web", name).read_bytes()


class _Handler(BaseHTTPRequestHandler):
    server_version = "study/1"

    def log_message(self, fmt, *args) -> None:  # keep the console for the operator
        pass

    def _send(self, status: int, body: bytes, ctype: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, obj, status: int = 200) -> None:
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json")

    def _token_ok(self, query: dict) -> bool:
        given = self.headers.get("X-Study-Token") or (query.get("token") or [""])[0]
        return hmac.compare_digest(given.encode(), self.server.token.encode())

    def do_GET(self) -> None:
        url = urlparse(self.path)
        query = parse_qs(url.query)
        ui: UiState = self.server.ui
        if url.path in ("/", "/subject"):
            return self._send(200, _asset("subject.html"), "text/html; charset=utf-8")
        if url.path == "/api/subject":
            return self._json(ui.snapshot("subject"))
        if url.path in ("/operator", "/api/operator"):
            if not self._token_ok(query):
                return self._send(HTTPStatus.FORBIDDEN, b"403: the operator view needs its token (?token=...)",
                                  "text/plain; charset=utf-8")
            if url.path == "/operator":
                return self._send(200, _asset("operator.html"), "text/html; charset=utf-8")
            return self._json(ui.snapshot("operator"))
        self._send(404, b"not found", "text/plain")

    def do_POST(self) -> None:
        url = urlparse(self.path)
        query = parse_qs(url.query)
        ui: UiState = self.server.ui
        length = min(int(self.headers.get("Content-Length") or 0), 4096)
        try:
            body = json.loads(self.rfile.read(length) or b"{}")
        except json.JSONDecodeError:
            return self._json({"error": "body is not JSON"}, 400)
        if url.path == "/api/key":
            key = body.get("key")
            if not isinstance(key, str) or len(key) > 16:
                return self._json({"error": "key must be a short string"}, 400)
            return self._json(ui.subject_key(key))
        if url.path.startswith("/api/operator/"):
            if not self._token_ok(query):
                return self._json({"error": "operator token required"}, 403)
            result = ui.operator_action(url.path.rsplit("/", 1)[1])
            return self._json(result, 200 if result.get("ok") else 400)
        self._send(404, b"not found", "text/plain")


class WebUI:
    """Serve :class:`UiState` on ``host:port`` (0 = any free port) in a daemon thread."""

    def __init__(self, ui: UiState, host: str = "127.0.0.1", port: int = 0, token: str | None = None) -> None:
        self.ui = ui
        self.token = token or secrets.token_urlsafe(16)
        self.httpd = ThreadingHTTPServer((host, port), _Handler)
        self.httpd.daemon_threads = True
        self.httpd.ui = ui
        self.httpd.token = self.token
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="study-webui", daemon=True)

    @property
    def port(self) -> int:
        return self.httpd.server_address[1]

    @property
    def host(self) -> str:
        return self.httpd.server_address[0]

    @property
    def subject_url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    @property
    def operator_url(self) -> str:
        return f"http://{self.host}:{self.port}/operator?token={self.token}"

    def start(self) -> "WebUI":
        self._thread.start()
        return self

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
