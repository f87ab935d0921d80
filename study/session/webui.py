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
:class:`study.session.uistate.UiState`, a lock-protected state with condition waits. Keys are
validated by the server (the page's own check is only for the hint).

Hardening (the server faces a browser that may also visit other sites, and
anything on the lab network):

* every request must arrive within ``REQUEST_DEADLINE_S`` (request line,
  headers and body together; a slow sender gets 408 and the connection is
  closed; a kept-alive connection on which no byte came in that time is
  closed without an answer), at most ``MAX_CONNECTIONS`` connections are served at once (more
  get 503), bodies are at most ``MAX_BODY_BYTES`` (a larger declared length
  gets 413, a negative or non-numeric one 400, both without reading);
* malformed JSON, a body that is not an object, wrong types and missing
  fields get 400 with a one-line JSON error, never a traceback; two
  ``Content-Length`` headers that differ get 400;
* a key (``/api/key``) carries the ``trial_id`` of the presentation it answers
  (the subject view sends the one it shows): a key for another presentation
  (late, or replayed from an earlier trial) or for one already answered gets
  409 and is never taken as the current trial's rating;
* ``Host`` must name this server (an IP literal, ``localhost`` or the bound
  name, with our port: DNS rebinding is refused with 400); a POST whose
  ``Origin`` (or, without it, ``Referer``) is another origin is refused with
  403, so another site open in the browser cannot post keys or actions;
* every answer carries ``Cache-Control: no-store``, a Content-Security-Policy
  that allows only this server's own scripts, styles and API
  (``default-src 'none'``; no inline script), ``X-Frame-Options: DENY``,
  ``X-Content-Type-Options: nosniff`` and ``Referrer-Policy: no-referrer``;
* the token is compared with :func:`hmac.compare_digest` and never logged
  (the server logs nothing).
"""

from __future__ import annotations

import hmac
import io
import ipaddress
import json
import secrets
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlparse

from .uistate import UiState

MAX_BODY_BYTES = 4096
REQUEST_DEADLINE_S = 1.5
MAX_CONNECTIONS = 32
STATIC = {"operator.js": "text/javascript; charset=utf-8", "subject.js": "text/javascript; charset=utf-8",
          "operator.css": "text/css; charset=utf-8", "subject.css": "text/css; charset=utf-8"}
SECURITY_HEADERS = (
    ("Cache-Control", "no-store"),
    ("Content-Security-Policy", "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
                                "img-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"),
    ("X-Frame-Options", "DENY"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
)


def _asset(name: str) -> bytes:
    return resources.files("study.session").joinpath("web", name).read_bytes()


class BadRequest(Exception):
    """A request refused with ``status`` and a one-line reason (no traceback reaches the client)."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


class _DeadlineReader(io.RawIOBase):
    """The socket's input with one deadline for a whole request: a slowloris sender cannot hold a handler."""

    def __init__(self, handler: "_Handler") -> None:
        self.handler = handler

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:
        remaining = self.handler.deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError("request deadline passed")
        self.handler.connection.settimeout(remaining)
        n = self.handler.connection.recv_into(buf)
        if n:
            self.handler.idle = False
        return n


def _host_ok(host_header: str | None, server) -> bool:
    """True when ``Host`` names this server: an IP literal, localhost or the bound name, with our port."""
    if not host_header:
        return False
    host, _, port = host_header.rpartition(":") if not host_header.endswith("]") else (host_header, "", "")
    if not host:
        host, port = host_header, "80"
    if port != str(server.server_address[1]):
        return False
    host = host.strip("[]").lower()
    if host in ("localhost", server.bound_name):
        return True
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False  # a DNS name other than ours: DNS rebinding
    return True


class _Handler(BaseHTTPRequestHandler):
    server_version = "study/1"
    sys_version = ""

    def setup(self) -> None:
        super().setup()
        self.deadline = time.monotonic() + REQUEST_DEADLINE_S
        self.idle = True
        self.rfile = io.BufferedReader(_DeadlineReader(self), 8192)

    def log_message(self, fmt, *args) -> None:  # keep the console for the operator; never log the token
        pass

    def handle_one_request(self) -> None:
        self.deadline = time.monotonic() + REQUEST_DEADLINE_S
        self.idle = True  # no byte of this request yet: a kept-alive connection waiting for the browser
        try:
            super().handle_one_request()
        except (ConnectionError, OSError):
            self.close_connection = True

    def log_error(self, fmt, *args) -> None:
        # the stdlib catches a TimeoutError while reading a request and reports it only here: answer 408
        # -- unless not one byte of it came: that is an idle kept-alive connection, closed without an answer. A
        # 408 there could meet a request the browser sent on it at that moment (a subject's key), which then
        # fails; a connection closed without an answer makes the browser send that request again on a new one.
        if fmt.startswith("Request timed out"):
            if self.idle:
                self.close_connection = True
            else:
                self._late()

    def _late(self) -> None:
        self.close_connection = True
        try:
            self.connection.settimeout(0.5)
            self.connection.sendall(b"HTTP/1.0 408 Request Timeout\r\nContent-Length: 0\r\nConnection: close\r\n"
                                    b"Cache-Control: no-store\r\n\r\n")
        except OSError:
            pass

    def send_error(self, code, message=None, explain=None) -> None:  # the stdlib's parse errors, without detail
        self.close_connection = True
        self.request_version = "HTTP/1.0"  # the stdlib answers an unparsable request as HTTP/0.9: no status line
        try:
            self._send(code, f"{code}\n".encode(), "text/plain; charset=utf-8")
        except OSError:
            pass

    def _send(self, status: int, body: bytes, ctype: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        for k, v in SECURITY_HEADERS:
            self.send_header(k, v)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, obj, status: int = 200) -> None:
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json")

    def _token_ok(self, query: dict) -> bool:
        given = self.headers.get("X-Study-Token") or (query.get("token") or [""])[0]
        return hmac.compare_digest(given.encode("utf-8", "replace"), self.server.token.encode())

    def _check_host(self) -> None:
        if not _host_ok(self.headers.get("Host"), self.server):
            raise BadRequest(400, "Host does not name this server")

    def _check_origin(self) -> None:
        """A state-changing request from a browser must come from one of our own pages."""
        host = self.headers.get("Host", "")
        origin = self.headers.get("Origin")
        if origin is not None:
            if origin != f"http://{host}":
                raise BadRequest(403, "cross-origin request refused")
            return
        referer = self.headers.get("Referer")
        if referer is not None and not referer.startswith(f"http://{host}/"):
            raise BadRequest(403, "cross-origin request refused")
        if self.headers.get("Sec-Fetch-Site", "same-origin") not in ("same-origin", "none"):
            raise BadRequest(403, "cross-site request refused")

    def _read_json(self) -> dict:
        if self.headers.get("Transfer-Encoding"):
            raise BadRequest(400, "Transfer-Encoding is not supported; send Content-Length")
        given = self.headers.get_all("Content-Length") or []
        if len({v.strip() for v in given}) > 1:  # which one would the body follow? (request smuggling)
            raise BadRequest(400, "conflicting Content-Length headers")
        raw = self.headers.get("Content-Length")
        if raw is None:
            length = 0
        else:
            raw = raw.strip()
            if not (raw.isascii() and raw.isdigit()):  # str.isdigit() also takes "²", which int() refuses
                raise BadRequest(400, "Content-Length must be a non-negative integer")
            length = int(raw)
            if length > MAX_BODY_BYTES:
                raise BadRequest(413, f"body larger than {MAX_BODY_BYTES} bytes")
        data = self.rfile.read(length) if length else b""
        if len(data) != length:
            raise BadRequest(400, "body shorter than Content-Length")
        if not data:
            return {}
        try:
            body = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
            raise BadRequest(400, "body is not JSON") from None
        if not isinstance(body, dict):
            raise BadRequest(400, "body must be a JSON object")
        return body

    def _dispatch(self, method) -> None:
        try:
            self._check_host()
            method()
        except BadRequest as exc:
            self.close_connection = True
            self._json({"error": str(exc)}, exc.status)

    def do_GET(self) -> None:
        self._dispatch(self._get)

    def do_POST(self) -> None:
        self._dispatch(self._post)

    def _get(self) -> None:
        url = urlparse(self.path)
        query = parse_qs(url.query)
        ui: UiState = self.server.ui
        if url.path in ("/", "/subject"):
            return self._send(200, _asset("subject.html"), "text/html; charset=utf-8")
        if url.path.startswith("/static/") and url.path[8:] in STATIC:
            return self._send(200, _asset(url.path[8:]), STATIC[url.path[8:]])
        if url.path == "/api/subject":
            return self._json(ui.snapshot("subject"))
        if url.path in ("/operator", "/api/operator"):
            if not self._token_ok(query):
                return self._send(HTTPStatus.FORBIDDEN, b"403: the operator view needs its token (?token=...)",
                                  "text/plain; charset=utf-8")
            if url.path == "/operator":
                return self._send(200, _asset("operator.html"), "text/html; charset=utf-8")
            snap = ui.snapshot("operator")
            self._json(snap)
            self.server.operator_served(snap.get("seq", 0))
            return None
        self._send(404, b"not found", "text/plain")

    def _post(self) -> None:
        url = urlparse(self.path)
        query = parse_qs(url.query)
        ui: UiState = self.server.ui
        self._check_origin()
        if url.path == "/api/key":
            body = self._read_json()
            if "key" not in body:
                raise BadRequest(400, "missing field 'key'")
            key, trial_id = body["key"], body.get("trial_id")
            if not isinstance(key, str) or len(key) > 16:
                raise BadRequest(400, "key must be a short string")
            if not isinstance(trial_id, str) or len(trial_id) > 64:
                raise BadRequest(400, "trial_id must be the trial_id the subject view shows (a short string)")
            result = ui.subject_key(key, trial_id)
            return self._json(result, 409 if "refused" in result else 200)
        if url.path.startswith("/api/operator/"):
            if not self._token_ok(query):
                return self._json({"error": "operator token required"}, 403)
            self._read_json()
            result = ui.operator_action(url.path.rsplit("/", 1)[1])
            return self._json(result, 200 if result.get("ok") else 400)
        self._send(404, b"not found", "text/plain")


class _Server(ThreadingHTTPServer):
    """``ThreadingHTTPServer`` with a cap on concurrent connections (503 beyond it)."""

    daemon_threads = True

    def __init__(self, address, handler) -> None:
        super().__init__(address, handler)
        self.slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self.bound_name = str(address[0]).lower()
        self.refused_busy = 0
        self._seen = threading.Condition()
        self.operator_seq_served = None   # seq of the last operator state an operator page fetched (None: none yet)

    def operator_served(self, seq: int) -> None:
        """Record that an operator page fetched the operator state ``seq``."""
        with self._seen:
            self.operator_seq_served = max(seq, self.operator_seq_served or 0)
            self._seen.notify_all()

    def wait_operator_seen(self, seq: int, timeout_s: float) -> bool:
        """Wait until an operator page has fetched state ``seq`` or later (False at once if no page ever asked;
        False after ``timeout_s`` s: a page closed meanwhile must not hold the session's end)."""
        with self._seen:
            if self.operator_seq_served is None:
                return False
            return self._seen.wait_for(lambda: self.operator_seq_served >= seq, timeout=timeout_s)

    def process_request(self, request, client_address) -> None:
        if not self.slots.acquire(blocking=False):
            self.refused_busy += 1
            try:
                request.settimeout(0.2)
                request.sendall(b"HTTP/1.0 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n"
                                b"Retry-After: 1\r\n\r\n")
            except OSError:
                pass
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.slots.release()


class WebUI:
    """Serve :class:`UiState` on ``host:port`` (0 = any free port) in a daemon thread."""

    def __init__(self, ui: UiState, host: str = "127.0.0.1", port: int = 0, token: str | None = None) -> None:
        self.ui = ui
        self.token = token or secrets.token_urlsafe(16)
        self.httpd = _Server((host, port), _Handler)
        self.httpd.ui = ui
        self.httpd.token = self.token
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="study-webui", daemon=True)

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return self.httpd.server_address[1]

    @property
    def host(self) -> str:
        """The address the server listens on."""
        return self.httpd.server_address[0]

    @property
    def subject_url(self) -> str:
        """URL of the subject view."""
        return f"http://{self.host}:{self.port}/"

    @property
    def operator_url(self) -> str:
        """URL of the operator view, with its access token."""
        return f"http://{self.host}:{self.port}/operator?token={self.token}"

    def start(self) -> "WebUI":
        """Serve in a background thread; returns self."""
        self._thread.start()
        return self

    def stop_when_seen(self, timeout_s: float = 10.0) -> bool:
        """At a normal finish: if an operator page is open, wait until it has fetched the final operator state
        (the page then shows "session complete" and stops asking), at most ``timeout_s`` s; then stop. Without
        this the server was gone before the page's next poll, and the page showed a red "RUNNER STOPPED: no
        answer from the runner" over stale state. Returns True if the page saw the final state."""
        seen = self.httpd.wait_operator_seen(self.ui.snapshot("operator").get("seq", 0), timeout_s)
        self.stop()
        return seen

    def stop(self) -> None:
        """Stop serving (if started) and close the socket (the pages then show the runner stopped)."""
        if self._thread.is_alive():  # shutdown() waits for serve_forever, which a server never started lacks
            self.httpd.shutdown()
        self.httpd.server_close()
