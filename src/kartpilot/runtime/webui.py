"""The kart's web page, for a phone on the kart's hotspot: the thesis's phone control, done properly.

The page (``webui.html``) shows the live camera view and the supervisor's state and reason, and has
a large emergency-stop button, arm and disarm buttons, and steer, throttle and brake controls (keys
or touch). It posts its controls ten times a second; those posts are the link's heartbeat. The
server is the standard library's threading HTTP server: no framework is needed for five routes.

**Only its operator drives the kart.** A kart's hotspot is shared with a team's laptops and phones. When the
server starts, it makes a one-time pairing code and prints the pairing address (``/?pair=CODE``); the first
browser to open it becomes the operator (a session cookie) and the code is spent. Every control, request
(manual, autonomous, disarm, re-arm) and heartbeat from anyone else is refused (403) and logged; they see the
page, view only. The emergency stop is the exception: anyone on the page may stop the kart (stopping is always
safe; only the operator can re-arm it). Controls must be finite numbers.

:class:`WebOperator` is the page as an operator input for the supervisor. Its link counts as lost
when no post has arrived for ``link_timeout_s``, like any other watchdog. An emergency stop from
the page holds until a re-arm request.
"""

from __future__ import annotations

import json
import logging
import math
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

import cv2

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, Image, OperatorInput

__all__ = ["WebConfig", "WebOperator", "WebServer"]

log = logging.getLogger(__name__)

PAGE = Path(__file__).with_name("webui.html")
COOKIE = "kartpilot_session"
REQUESTS = ("manual", "autonomous", "disarm", "rearm")


@dataclass(frozen=True)
class WebConfig:
    """Attributes:
        host, port: where the page is served (0.0.0.0: every interface, the hotspot's too; port 0: any free).
        link_timeout_s: the page's link is lost when it has posted nothing for this long.
        max_steer_rad, throttle, brake: what the page's full left/right, up and down ask for.
        jpeg_quality: the camera view's quality.
        pair_code: the one-time pairing code (empty: a new random one each time the page is served, the
            default; a fixed one is for a team's own tooling, and tests).
    """

    host: str = "0.0.0.0"
    port: int = 8080
    link_timeout_s: float = 0.5
    max_steer_rad: float = 0.3
    throttle: float = 0.3
    brake: float = 1.0
    jpeg_quality: int = 70
    pair_code: str = ""

    def __post_init__(self) -> None:
        if self.link_timeout_s <= 0:
            raise ConfigError("web.link_timeout_s must be positive")


class WebOperator:
    """What the page asks for (operator side) and what the page shows (kart side)."""

    def __init__(self, config: WebConfig | None = None, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.config = config or WebConfig()
        self.clock = clock
        self._lock = threading.Lock()
        self._last_post_ns: int | None = None
        self._controls = {"steer": 0.0, "throttle": 0.0, "brake": 0.0, "hold": False}
        self._requests: deque[str] = deque(maxlen=8)  # one per loop step, in the order they were clicked
        self._estop = False
        self._view: dict[str, Any] = {"state": "disarmed", "reason": "", "transitions": []}
        self._jpeg: bytes | None = None
        self.posts = 0
        self.pair_code = self.config.pair_code or secrets.token_urlsafe(6)
        self._session: str | None = None
        self.refused = 0

    # pairing
    def pair(self, code: str) -> str | None:
        """A session for the browser that brings the pairing code, once; None after (or for a wrong code)."""
        with self._lock:
            if self._session is not None or not secrets.compare_digest(code, self.pair_code):
                log.warning("web page: a pairing attempt was refused")
                return None
            self._session = secrets.token_hex(16)
            log.info("web page: an operator is paired")
            return self._session

    def is_operator(self, session: str | None) -> bool:
        with self._lock:
            return self._session is not None and session is not None and secrets.compare_digest(session,
                                                                                                self._session)

    def refuse(self, what: str) -> None:
        with self._lock:
            self.refused += 1
        log.warning("web page: %s from a browser that is not the paired operator: refused", what)

    # page -> kart
    def on_input(self, data: dict[str, Any]) -> None:
        with self._lock:
            self._last_post_ns = self.clock()
            self.posts += 1
            values = {key: float(data.get(key, 0.0)) for key in ("steer", "throttle", "brake")}
            bad = [key for key, value in values.items() if not math.isfinite(value)]
            if bad:
                raise ValueError(f"{', '.join(bad)} must be a finite number")
            for key, value in values.items():
                self._controls[key] = min(max(value, -1.0 if key == "steer" else 0.0), 1.0)
            self._controls["hold"] = bool(data.get("hold", False))

    def on_request(self, request: str) -> None:
        if request not in REQUESTS:
            raise ValueError(f"unknown request {request!r}")
        with self._lock:
            self._last_post_ns = self.clock()
            self._requests.append(request)
            if request == "rearm":
                self._estop = False  # the person has seen the kart is safe
        log.info("web page: %s requested", request)

    def on_estop(self) -> None:
        with self._lock:
            self._last_post_ns = self.clock()
            self._estop = True
        log.error("web page: EMERGENCY STOP")

    def __call__(self, stamp_ns: int) -> OperatorInput:
        with self._lock:
            now = self.clock()
            connected = self._last_post_ns is not None and (now - self._last_post_ns) * 1e-9 <= \
                self.config.link_timeout_s
            request = self._requests.popleft() if self._requests else ""
            c = self._controls if connected else {"steer": 0.0, "throttle": 0.0, "brake": 1.0, "hold": False}
            manual = ActuatorCommand(stamp_ns, float(c["steer"]) * self.config.max_steer_rad,
                                     float(c["throttle"]) * self.config.throttle, float(c["brake"]) * self.config.brake)
            return OperatorInput(connected=connected, estop=self._estop, hold=bool(c["hold"]), request=request,
                                 manual=manual, source="web")

    # kart -> page
    def publish(self, state: str, reason: str, image: Image | None = None, **extra: Any) -> None:
        jpeg = None
        if image is not None:
            ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality])
            jpeg = buffer.tobytes() if ok else None
        with self._lock:
            self._view = {"state": state, "reason": reason, **extra}
            if jpeg is not None:
                self._jpeg = jpeg

    def view(self) -> dict[str, Any]:
        with self._lock:
            age = None if self._last_post_ns is None else round((self.clock() - self._last_post_ns) * 1e-9, 3)
            return {**self._view, "link_age_s": age}

    def jpeg(self) -> bytes | None:
        with self._lock:
            return self._jpeg


class _Handler(BaseHTTPRequestHandler):
    """The page's routes; ``operator`` is set on the subclass :func:`_handler` makes for one server."""

    operator: WebOperator

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("web: " + format, *args)

    def _reply(self, status: HTTPStatus, body: bytes, kind: str, cookie: str | None = None) -> None:
        self.send_response(status)
        if cookie is not None:
            self.send_header("Set-Cookie", f"{COOKIE}={cookie}; Path=/; HttpOnly; SameSite=Strict")
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _session(self) -> str | None:
        for part in (self.headers.get("Cookie") or "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == COOKIE:
                return value
        return None

    def do_GET(self) -> None:
        operator = self.operator
        path, _, query = self.path.partition("?")
        if path == "/":
            code = parse_qs(query).get("pair", [""])[0]
            session = operator.pair(code) if code else None
            self._reply(HTTPStatus.OK, PAGE.read_bytes(), "text/html; charset=utf-8", session)
        elif path == "/state":
            view = {**operator.view(), "operator": operator.is_operator(self._session())}
            self._reply(HTTPStatus.OK, json.dumps(view).encode(), "application/json")
        elif path == "/camera.jpg":
            jpeg = operator.jpeg()
            if jpeg is None:
                self._reply(HTTPStatus.NO_CONTENT, b"", "image/jpeg")
            else:
                self._reply(HTTPStatus.OK, jpeg, "image/jpeg")
        else:
            self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

    def do_POST(self) -> None:
        operator = self.operator
        length = int(self.headers.get("Content-Length") or 0)
        try:
            data = json.loads(self.rfile.read(length) or b"{}")
            if not isinstance(data, dict):
                raise ValueError("a JSON object is expected")
            if self.path == "/estop":  # anyone may stop the kart; only the operator re-arms it
                operator.on_estop()
            elif self.path not in ("/input", "/request"):
                self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")
                return
            elif not operator.is_operator(self._session()):
                operator.refuse(self.path[1:])
                self._reply(HTTPStatus.FORBIDDEN, b"not the paired operator: view only", "text/plain")
                return
            elif self.path == "/input":
                operator.on_input(data)
            else:
                operator.on_request(str(data.get("request", "")))
        except (ValueError, TypeError) as exc:
            self._reply(HTTPStatus.BAD_REQUEST, str(exc).encode(), "text/plain")
            return
        self._reply(HTTPStatus.OK, b"{}", "application/json")


def _handler(operator: WebOperator) -> type[BaseHTTPRequestHandler]:
    return type("Handler", (_Handler,), {"operator": operator})


class WebServer:
    """Serves the page for ``operator`` in a background thread."""

    def __init__(self, operator: WebOperator) -> None:
        self.operator = operator
        try:
            self.server = ThreadingHTTPServer((operator.config.host, operator.config.port), _handler(operator))
        except OSError as exc:
            raise ConfigError(f"cannot serve the web page on {operator.config.host}:{operator.config.port}: "
                              f"{exc}") from exc
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, name="webui", daemon=True)

    @property
    def url(self) -> str:
        host, port = str(self.server.server_address[0]), int(self.server.server_address[1])
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{port}/"

    @property
    def pairing_url(self) -> str:
        """The address the operator opens, once, to become the one who drives."""
        return f"{self.url}?pair={self.operator.pair_code}"

    def start(self) -> WebServer:
        self._thread.start()
        log.info("web page at %s", self.url)
        return self

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
