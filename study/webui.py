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
:class:`study.uistate.UiState`, a lock-protected state with condition waits. Keys are
validated by the server (the page's own check is only for the hint).
"""

from __future__ import annotations

import hmac
import json
import secrets
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlparse

from .uistate import UiState


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
