"""The kart's web page, for a phone on the kart's hotspot: the thesis's phone control, done properly.

The page (``webui.html``) shows the live camera view and the supervisor's state and reason, and has
a large emergency-stop button, arm and disarm buttons, and steer, throttle and brake controls (keys
or touch). It posts its controls ten times a second.

**The heartbeat is a valid control from the holder.** The link counts as lost when no valid control (a JSON object
of ``steer`` in [-1, 1], ``throttle`` and ``brake`` in [0, 1], all JSON numbers, and ``hold`` a boolean) has come
from the holder's session for ``link_timeout_s`` (0.5 s; the page sends one every 100 ms). A refused, malformed or
out-of-range post, or a request, does not extend it: a page whose controls stop making sense is a lost link.

**Only the holder drives.** A kart's hotspot is shared with a team's laptops and phones. The kart's terminal prints
a pairing address (``/?pair=CODE``); opening it shows the page with a button that pairs (a POST: a chat app's link
preview, which only opens the address, pairs nothing). Each code pairs once, and a fresh one is printed for the
next client. The first paired client holds the controls; a later one is paired to watch and stop, unless the
holder's link is lost (a phone that died: the kart has stopped, and whoever pairs with the fresh code holds the
controls). The holder may hand the controls to another paired client. Controls and requests (manual, autonomous,
disarm, re-arm) from anyone else are refused (403). The emergency stop is the exception: any page of the kart's own
origin may stop the kart (stopping is always safe; only the holder re-arms it), but no other web site may, through a
team member's browser: every POST must be JSON (``Content-Type: application/json``, which a cross-site form cannot
send without the browser asking first) from the page's own origin (``Origin``, where a browser sends it).

**A crowd cannot stall it.** The standard library's threading server, bounded: at most ``max_connections``
connections are served at once (one thread each), and ``holder_connections`` more are kept for the holder's
address; any further connection is answered 503 and closed at once. A request's line, headers and body must arrive
within ``read_timeout_s`` (a watchdog closes a connection that trickles), an idle kept-alive connection closes
after it, and a body is refused on its ``Content-Length`` (missing, malformed, or over ``max_body_bytes``) before
a byte of it is read; the client is checked before the body is parsed. The holder's page keeps its connection
alive between posts, so a flood of new connections does not come between it and the kart. Every refused request is
logged once with its address, path and reason, then at most once per ``log_every_s`` per address (with a count);
pairing attempts are limited per address.

Why the standard library: the page has six routes and one client that matters. An async framework (aiohttp,
Starlette on uvicorn) would bring the same bounds as settings, and 5 to 10 packages, 0.2 to 0.4 s of start-up and
a few tens of MB; the threading server costs nothing to import, and its few bounds are written out here and tested
against the attacks of issue 55.

:class:`WebOperator` is the page as an operator input for the supervisor. An emergency stop from the page holds
until the holder's re-arm request.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import secrets
import socket
import sys
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from kartpilot.core.errors import ConfigError
from kartpilot.core.types import ActuatorCommand, Image, OperatorInput

__all__ = ["RefusedPost", "WebConfig", "WebOperator", "WebServer", "parse_controls", "parse_request", "terminal_qr"]

log = logging.getLogger(__name__)

PAGE = Path(__file__).with_name("webui.html")
COOKIE = "kartpilot_session"
REQUESTS = ("manual", "autonomous", "disarm", "rearm")
CONTROL_RANGES = {"steer": (-1.0, 1.0), "throttle": (0.0, 1.0), "brake": (0.0, 1.0)}


@dataclass(frozen=True)
class WebConfig:
    """Attributes:
        host: the address the page listens on (127.0.0.1 by default: this machine only; the hotspot's own
            address, ``--web-host``, to serve the phones on it; 0.0.0.0 for every interface).
        port: the port (0: any free one).
        link_timeout_s: the page's link is lost when no valid control has come from the holder for this long.
        max_steer_rad, throttle, brake: what the page's full left/right, up and down ask for.
        jpeg_quality: the camera view's quality.
        pair_code: the first pairing code (empty: a random one, the default; a fixed one is for a team's own
            tooling, and tests). Each code pairs once; the next is random.
        max_connections, holder_connections: connections served at once, and more kept for the holder's address.
        read_timeout_s: a request must arrive whole within this; an idle kept-alive connection closes after it.
        max_body_bytes: the largest body a POST may announce (the page's are under 100 bytes).
        pair_attempts, pair_window_s: pairing attempts allowed per address in the window.
        log_every_s: a refused address is logged again at most this often, with the count since.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    link_timeout_s: float = 0.5
    max_steer_rad: float = 0.3
    throttle: float = 0.3
    brake: float = 1.0
    jpeg_quality: int = 70
    pair_code: str = ""
    max_connections: int = 24
    holder_connections: int = 4
    read_timeout_s: float = 2.0
    max_body_bytes: int = 1024
    pair_attempts: int = 5
    pair_window_s: float = 60.0
    log_every_s: float = 10.0

    def __post_init__(self) -> None:
        if not (self.link_timeout_s > 0 and self.read_timeout_s > 0 and self.pair_window_s > 0):
            raise ConfigError("web.link_timeout_s, read_timeout_s and pair_window_s must be positive")
        if not (1 <= self.max_connections <= 1000 and 1 <= self.holder_connections <= 100):
            raise ConfigError("web.max_connections must be 1 to 1000 and web.holder_connections 1 to 100")
        if not (16 <= self.max_body_bytes <= 65536 and self.pair_attempts >= 1):
            raise ConfigError("web.max_body_bytes must be 16 to 65536 and web.pair_attempts at least 1")


class RefusedPost(ValueError):  # noqa: N818 - a refusal, not an error of ours
    """A post that is refused: its HTTP status and a one-line reason."""

    def __init__(self, status: HTTPStatus, reason: str) -> None:
        super().__init__(reason)
        self.status = status


def _json_object(body: bytes) -> dict[str, Any]:
    def no_constant(name: str) -> None:
        raise RefusedPost(HTTPStatus.BAD_REQUEST, f"{name} is not a number JSON allows")

    try:
        data = json.loads(body.decode("utf-8"), parse_constant=no_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise RefusedPost(HTTPStatus.BAD_REQUEST, f"the body is not JSON ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise RefusedPost(HTTPStatus.BAD_REQUEST, "a JSON object is expected")
    return data


def parse_controls(body: bytes) -> dict[str, float | bool]:
    """The page's controls from a post's body, strictly: a JSON object of ``steer``, ``throttle``, ``brake``
    (JSON numbers, finite, in range; missing: 0) and ``hold`` (a boolean; missing: false), nothing else."""
    data = _json_object(body)
    unknown = sorted(set(data) - {*CONTROL_RANGES, "hold"})
    if unknown:
        raise RefusedPost(HTTPStatus.BAD_REQUEST, f"unknown control {unknown[0]!r}")
    out: dict[str, float | bool] = {}
    for key, (low, high) in CONTROL_RANGES.items():
        value = data.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RefusedPost(HTTPStatus.BAD_REQUEST, f"{key} must be a JSON number, got {type(value).__name__}")
        if isinstance(value, float) and not math.isfinite(value):
            raise RefusedPost(HTTPStatus.BAD_REQUEST, f"{key} must be a finite number")
        if not low <= value <= high:  # compared as given: a 400-digit integer is out of range, not an overflow
            raise RefusedPost(HTTPStatus.BAD_REQUEST, f"{key} must be within [{low:g}, {high:g}]")
        out[key] = float(value)
    hold = data.get("hold", False)
    if not isinstance(hold, bool):
        raise RefusedPost(HTTPStatus.BAD_REQUEST, "hold must be true or false")
    out["hold"] = hold
    return out


def parse_request(body: bytes) -> str:
    """A request (manual, autonomous, disarm, re-arm) from a post's body: ``{"request": NAME}``."""
    data = _json_object(body)
    request = data.get("request")
    if set(data) != {"request"} or request not in REQUESTS:
        raise RefusedPost(HTTPStatus.BAD_REQUEST, f"a request is {{\"request\": one of {', '.join(REQUESTS)}}}")
    return str(request)


def _same(a: str, b: str) -> bool:
    """Constant-time comparison of two strings of any characters (``secrets.compare_digest`` refuses non-ASCII
    text)."""
    return secrets.compare_digest(a.encode("utf-8", "surrogatepass"), b.encode("utf-8", "surrogatepass"))


class _Refusals:
    """Each refused request logged once with its address, path and reason, then at most once per ``every_s`` per
    address with a count; the addresses kept are bounded (a flood from many addresses forgets the oldest)."""

    def __init__(self, every_s: float, clock: Callable[[], float], most: int = 512) -> None:
        self.every_s, self.clock, self.most = every_s, clock, most
        self._seen: OrderedDict[str, tuple[float, int]] = OrderedDict()
        self._lock = threading.Lock()
        self.count = 0

    def __call__(self, address: str, path: str, reason: str) -> None:
        with self._lock:
            self.count += 1
            now = self.clock()
            last, quiet = self._seen.pop(address, (-math.inf, 0))
            if now - last >= self.every_s:
                more = f" ({quiet} more refused since)" if quiet else ""
                log.warning("web page: refused %s %s: %s%s", address, path, reason, more)
                self._seen[address] = (now, 0)
            else:
                self._seen[address] = (last, quiet + 1)
            while len(self._seen) > self.most:
                self._seen.popitem(last=False)


class WebOperator:
    """What the page asks for (operator side) and what the page shows (kart side), and who may ask."""

    def __init__(self, config: WebConfig | None = None, clock: Callable[[], int] = time.monotonic_ns,
                 on_code: Callable[[str], None] | None = None) -> None:
        self.config = config or WebConfig()
        self.clock = clock
        self.on_code = on_code  # told each fresh pairing code (the kart's terminal prints it)
        self._lock = threading.Lock()
        self._last_control_ns: int | None = None
        self._controls: dict[str, float | bool] = {"steer": 0.0, "throttle": 0.0, "brake": 0.0, "hold": False}
        self._requests: deque[str] = deque(maxlen=8)  # one per loop step, in the order they were clicked
        self._estop = False
        self._view: dict[str, Any] = {"state": "disarmed", "reason": "", "transitions": []}
        self._jpeg: bytes | None = None
        self.posts = 0
        self.pair_code = self.config.pair_code or secrets.token_urlsafe(6)
        self._sessions: dict[str, str] = {}  # session -> the client's label
        self._addresses: dict[str, str] = {}  # session -> the address it paired from
        self._holder: str | None = None
        self._held_since_ns = 0
        self._attempts: dict[str, deque[float]] = {}
        self.refusals = _Refusals(self.config.log_every_s, lambda: self.clock() * 1e-9)

    @property
    def refused(self) -> int:
        return self.refusals.count

    # pairing and holding
    def pair(self, code: str, address: str = "?") -> str:
        """A session for the client that brings the current pairing code (then a fresh code is made); the holder's
        if there is none or the holder's link is lost. Raises :class:`RefusedPost` for a wrong code or too many
        attempts from the address."""
        with self._lock:
            now = self.clock() * 1e-9
            attempts = self._attempts.setdefault(address, deque())
            while attempts and now - attempts[0] > self.config.pair_window_s:
                attempts.popleft()
            if len(attempts) >= self.config.pair_attempts:
                raise RefusedPost(HTTPStatus.TOO_MANY_REQUESTS, "too many pairing attempts from this address")
            attempts.append(now)
            if len(self._attempts) > 4096:  # a flood of addresses: forget the oldest
                self._attempts.pop(next(iter(self._attempts)))
            if not _same(code, self.pair_code):
                raise RefusedPost(HTTPStatus.FORBIDDEN, "wrong or spent pairing code")
            session = secrets.token_hex(16)
            self._sessions[session] = f"client {len(self._sessions) + 1}"
            self._addresses[session] = address
            took = self._holder is None or not self._present_locked()
            if took:
                self._holder, self._last_control_ns, self._held_since_ns = session, None, self.clock()
            self.pair_code = secrets.token_urlsafe(6)
            fresh = self.pair_code
        log.info("web page: %s paired from %s%s", self._sessions[session], address,
                 ", and holds the controls" if took else " (the controls stay with the holder)")
        if self.on_code is not None:
            try:  # the terminal's printer: its failure must not lose the pairing's reply
                self.on_code(fresh)
            except Exception:
                log.exception("web page: the fresh pairing code could not be told")
        return session

    def role(self, session: str | None) -> str:
        """``holder``, ``paired`` or ``viewer``."""
        with self._lock:
            return self._role_locked(session)

    def _role_locked(self, session: str | None) -> str:
        if session is None:
            return "viewer"
        if self._holder is not None and _same(session, self._holder):
            return "holder"
        return "paired" if any(_same(session, s) for s in self._sessions) else "viewer"

    def is_operator(self, session: str | None) -> bool:
        return self.role(session) == "holder"

    def holder_address(self) -> str | None:
        with self._lock:
            return None if self._holder is None else self._addresses.get(self._holder)

    def hand_over(self, session: str | None, label: str) -> str:
        """The holder gives the controls to the paired client ``label``; the link starts again from its first
        control."""
        with self._lock:
            if self._role_locked(session) != "holder":
                raise RefusedPost(HTTPStatus.FORBIDDEN, "only the holder hands the controls over")
            target = next((s for s, name in self._sessions.items() if name == label and s != self._holder), None)
            if target is None:
                raise RefusedPost(HTTPStatus.BAD_REQUEST, f"no other paired client is called {label!r}")
            self._holder, self._last_control_ns, self._held_since_ns = target, None, self.clock()
            self._controls = {"steer": 0.0, "throttle": 0.0, "brake": 0.0, "hold": False}
        log.warning("web page: the controls were handed over to %s", label)
        return label

    def clients(self) -> list[str]:
        with self._lock:
            return [name for s, name in self._sessions.items() if s != self._holder]

    # page -> kart
    def on_controls(self, controls: dict[str, float | bool]) -> None:
        """A valid control from the holder (checked by the caller): used, and the link's heartbeat."""
        with self._lock:
            self._last_control_ns = self.clock()
            self.posts += 1
            self._controls = dict(controls)

    def on_input(self, data: dict[str, Any]) -> None:
        """A control as a mapping (tests, tools): checked as a post's body is."""
        self.on_controls(parse_controls(json.dumps(data, allow_nan=True).encode()))

    def on_request(self, request: str) -> None:
        if request not in REQUESTS:
            raise RefusedPost(HTTPStatus.BAD_REQUEST, f"unknown request {request!r}")
        with self._lock:
            self._requests.append(request)
            if request == "rearm":
                self._estop = False  # the person has seen the kart is safe
        log.info("web page: %s requested", request)

    def on_estop(self, address: str = "?") -> None:
        with self._lock:
            self._estop = True
        log.error("web page: EMERGENCY STOP (from %s)", address)

    def _present_locked(self) -> bool:
        """The holder is there: a valid control, or the controls taken, within the link's timeout."""
        last = max(self._last_control_ns or 0, self._held_since_ns)
        return (self.clock() - last) * 1e-9 <= self.config.link_timeout_s

    def _connected_locked(self) -> bool:
        return self._last_control_ns is not None and (self.clock() - self._last_control_ns) * 1e-9 <= \
            self.config.link_timeout_s

    def __call__(self, stamp_ns: int) -> OperatorInput:
        with self._lock:
            connected = self._connected_locked()
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
            age = None if self._last_control_ns is None else round((self.clock() - self._last_control_ns) * 1e-9, 3)
            return {**self._view, "link_age_s": age}

    def jpeg(self) -> bytes | None:
        with self._lock:
            return self._jpeg


class _Handler(BaseHTTPRequestHandler):
    """The page's routes; ``operator`` and ``server`` (a :class:`_Server`) are set for one server."""

    operator: WebOperator
    protocol_version = "HTTP/1.1"  # the holder's page keeps its connection between posts

    def setup(self) -> None:
        super().setup()
        self.connection.settimeout(self.operator.config.read_timeout_s)

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("web %s: " + format, self.client_address[0], *args)

    def log_error(self, format: str, *args: Any) -> None:  # a malformed request line or headers, a timeout
        self.operator.refusals(self.client_address[0], getattr(self, "path", "?"), format % args)

    def handle_one_request(self) -> None:
        server: _Server = self.server  # type: ignore[assignment]
        server.watch(self.connection)  # the request must arrive whole within the read timeout
        try:
            super().handle_one_request()
        finally:
            server.unwatch(self.connection)

    def _reply(self, status: HTTPStatus, body: bytes, kind: str, cookie: str | None = None,
               close: bool = False) -> None:
        self.send_response(status)
        if cookie is not None:
            self.send_header("Set-Cookie", f"{COOKIE}={cookie}; Path=/; HttpOnly; SameSite=Strict")
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        self.wfile.write(body)

    def _refuse(self, error: RefusedPost) -> None:
        self.operator.refusals(self.client_address[0], self.path, str(error))
        # the body may be unread: the connection cannot carry another request
        self._reply(error.status, (str(error) + "\n").encode(), "text/plain; charset=utf-8", close=True)

    def _session(self) -> str | None:
        for part in (self.headers.get("Cookie") or "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == COOKIE:
                return value
        return None

    def do_GET(self) -> None:
        operator = self.operator
        path = self.path.partition("?")[0]
        if path == "/":
            self._reply(HTTPStatus.OK, PAGE.read_bytes(), "text/html; charset=utf-8")
        elif path == "/state":
            session = self._session()
            role = operator.role(session)
            view = {**operator.view(), "operator": role == "holder", "role": role,
                    **({"clients": operator.clients()} if role == "holder" else {})}
            self._reply(HTTPStatus.OK, json.dumps(view).encode(), "application/json")
        elif path == "/camera.jpg":
            jpeg = operator.jpeg()
            self._reply(HTTPStatus.NO_CONTENT if jpeg is None else HTTPStatus.OK, jpeg or b"", "image/jpeg")
        else:
            self._reply(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    def _checked_body(self) -> bytes:
        """The body, after the checks that need none of it: JSON from the page's own origin, of a stated length
        within the limit."""
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":
            raise RefusedPost(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "a post must be application/json")
        origin = self.headers.get("Origin")
        host = self.headers.get("Host") or ""
        if origin is not None and origin != f"http://{host}":
            raise RefusedPost(HTTPStatus.FORBIDDEN, f"cross-origin post from {origin[:80]!r}")
        if (self.headers.get("Sec-Fetch-Site") or "same-origin") not in ("same-origin", "none"):
            raise RefusedPost(HTTPStatus.FORBIDDEN, "cross-site post")
        if self.headers.get("Transfer-Encoding"):
            raise RefusedPost(HTTPStatus.LENGTH_REQUIRED, "a post must state its Content-Length")
        length_text = self.headers.get("Content-Length")
        if length_text is None or not length_text.isascii() or not length_text.isdigit():
            raise RefusedPost(HTTPStatus.LENGTH_REQUIRED, "a post must state its Content-Length as a whole number")
        if len(length_text) > 6 or int(length_text) > self.operator.config.max_body_bytes:
            raise RefusedPost(HTTPStatus.REQUEST_ENTITY_TOO_LARGE,
                          f"a post's body may be at most {self.operator.config.max_body_bytes} bytes")
        body = self.rfile.read(int(length_text))
        self.server.unwatch(self.connection)  # type: ignore[attr-defined]
        return body

    def do_POST(self) -> None:
        operator = self.operator
        address = self.client_address[0]
        try:
            if self.path not in ("/input", "/request", "/estop", "/pair", "/handover"):
                raise RefusedPost(HTTPStatus.NOT_FOUND, "not found")
            role = operator.role(self._session())
            if self.path in ("/input", "/request", "/handover") and role != "holder":
                raise RefusedPost(HTTPStatus.FORBIDDEN, "not the holder of the controls: view only")
            body = self._checked_body()  # the client was checked before the body is read and parsed
            if self.path == "/estop":  # any page of the kart's own origin may stop it; only the holder re-arms
                operator.on_estop(address)
                reply: dict[str, Any] = {}
            elif self.path == "/input":
                operator.on_controls(parse_controls(body))
                reply = {}
            elif self.path == "/request":
                operator.on_request(parse_request(body))
                reply = {}
            elif self.path == "/pair":
                code = _json_object(body).get("code")
                if not isinstance(code, str) or len(code) > 64:
                    raise RefusedPost(HTTPStatus.BAD_REQUEST, "a pairing is {\"code\": CODE}")
                session = operator.pair(code, address)
                self._reply(HTTPStatus.OK, json.dumps({"role": operator.role(session)}).encode(),
                            "application/json", cookie=session)
                return
            else:
                label = _json_object(body).get("to")
                reply = {"holder": operator.hand_over(self._session(), str(label))}
        except RefusedPost as error:
            self._refuse(error)
            return
        self._reply(HTTPStatus.OK, json.dumps(reply).encode(), "application/json")


class _Server(ThreadingHTTPServer):
    """The threading server, bounded: a slot per connection (more for the holder's address), a watchdog on every
    request's arrival."""

    request_queue_size = 128
    daemon_threads = True

    def __init__(self, operator: WebOperator) -> None:
        self.operator = operator
        config = operator.config
        self._slots = threading.BoundedSemaphore(config.max_connections)
        self._holder_slots = threading.BoundedSemaphore(config.holder_connections)
        self._watched: dict[socket.socket, float] = {}
        self._watch_lock = threading.Lock()
        self._stop = threading.Event()
        handler = type("Handler", (_Handler,), {"operator": operator})
        super().__init__((config.host, config.port), handler)
        self._reaper = threading.Thread(target=self._reap, name="webui-reaper", daemon=True)
        self._reaper.start()

    def process_request(self, request: Any, client_address: Any) -> None:
        address = client_address[0]
        slot = self._slot(address)
        if slot is None:
            self.operator.refusals(address, "(connection)", "too many connections: 503")
            with contextlib.suppress(OSError):
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
            self.shutdown_request(request)
            return
        try:
            threading.Thread(target=self._serve, args=(request, client_address, slot), daemon=True).start()
        except RuntimeError:  # no thread to be had: the connection is refused, the slot given back
            slot.release()
            self.shutdown_request(request)

    def _slot(self, address: str) -> threading.BoundedSemaphore | None:
        """A free slot: the holder's own first, for the holder's address; None when all are taken."""
        if address == self.operator.holder_address() and self._holder_slots.acquire(blocking=False):
            return self._holder_slots
        return self._slots if self._slots.acquire(blocking=False) else None

    def _serve(self, request: Any, client_address: Any, slot: threading.BoundedSemaphore) -> None:
        try:
            self.process_request_thread(request, client_address)
        finally:
            slot.release()

    def watch(self, connection: socket.socket) -> None:
        with self._watch_lock:
            self._watched[connection] = time.monotonic() + self.operator.config.read_timeout_s

    def unwatch(self, connection: socket.socket) -> None:
        with self._watch_lock:
            self._watched.pop(connection, None)

    def _reap(self) -> None:
        """Close every connection whose request has not arrived whole in time (one byte at a time is no
        longer a way to hold a thread)."""
        while not self._stop.wait(0.25):
            now = time.monotonic()
            with self._watch_lock:
                late = [c for c, deadline in self._watched.items() if deadline < now]
                for connection in late:
                    self._watched.pop(connection, None)
            for connection in late:
                with contextlib.suppress(OSError):
                    connection.shutdown(socket.SHUT_RDWR)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that went away before its answer was written (a broken pipe, a reset: a crowd closing its
        connections while refused) is no error of the server's and prints no traceback; anything else is logged
        with its traceback, once, through the log."""
        error = sys.exc_info()[1]
        if isinstance(error, ConnectionError | TimeoutError):
            log.debug("web page: %s went away before its answer: %s", client_address[0], error)
            return
        log.exception("web page: a request from %s failed", client_address[0])

    def server_close(self) -> None:
        self._stop.set()
        super().server_close()


def terminal_qr(text: str) -> str:
    """``text`` as a QR code drawn in a terminal (OpenCV's encoder, with its quiet zone): two rows of modules per
    line in half blocks, a light module drawn and a dark one left blank, as ``qrencode -t UTF8`` does for a terminal
    with a dark background. A phone's camera reads it off the kart's screen: the pairing URL without typing it."""
    modules = cv2.QRCodeEncoder.create().encode(text)
    if modules is None or modules.size == 0:
        raise ConfigError(f"cannot draw {text!r} as a QR code")
    light = modules > 127
    if len(light) % 2:
        light = np.vstack([light, np.ones((1, light.shape[1]), bool)])
    blocks = {(True, True): "\u2588", (True, False): "\u2580", (False, True): "\u2584", (False, False): " "}
    return "\n".join("".join(blocks[bool(top), bool(bottom)] for top, bottom in zip(light[row], light[row + 1],
                                                                                    strict=True))
                     for row in range(0, len(light), 2))


class WebServer:
    """Serves the page for ``operator`` in a background thread."""

    def __init__(self, operator: WebOperator) -> None:
        self.operator = operator
        try:
            self.server = _Server(operator)
        except (OSError, OverflowError) as exc:
            raise ConfigError(f"cannot serve the web page on {operator.config.host}:{operator.config.port}: "
                              f"{exc}") from exc
        # the loop looks for a shutdown every 50 ms (the library's default, 0.5 s, was how long a drive's end waited)
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, name="webui",
                                        daemon=True)

    @property
    def host(self) -> str:
        return str(self.server.server_address[0])

    @property
    def port(self) -> int:
        return int(self.server.server_address[1])

    @property
    def url(self) -> str:
        """The page's address as it listens (on every interface: this machine's name)."""
        host = self.host if self.host not in ("0.0.0.0", "") else socket.gethostname()
        return f"http://{host}:{self.port}/"

    def urls(self) -> list[str]:
        """Every address the page is reachable at: the one it listens on, or each of this machine's."""
        if self.host not in ("0.0.0.0", ""):
            return [self.url]
        try:
            found = {info[4][0] for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)}
        except OSError:
            found = set()
        return [f"http://{address}:{self.port}/" for address in sorted(found | {"127.0.0.1"})]

    @property
    def pairing_url(self) -> str:
        """The address a client opens to pair (the page's button pairs; opening it alone pairs nothing)."""
        return f"{self.url}?pair={self.operator.pair_code}"

    def start(self) -> WebServer:
        self._thread.start()
        log.info("web page at %s", ", ".join(self.urls()))
        return self

    def close(self) -> None:
        if self._thread.is_alive():  # shutdown() waits for serve_forever, which a server never started lacks
            self.server.shutdown()
        self.server.server_close()
