"""Dashboard security: who a request is, what it may do, and the guards in front of that.

* **Identity** — a request presents a token (``Authorization: Bearer``, ``X-Curio-Token``,
  ``?token=``, or for a browser WebSocket the subprotocol ``curio.token.<token>`` next to
  ``curio.v1``); the :class:`~curio.web.tokens.TokenStore` turns it into a name and a role.
  No token is a viewer. A token that is not ASCII is refused like any wrong token.
* **Roles** — :data:`~curio.web.tokens.PERMISSIONS`; :meth:`Gate.require` refuses what the
  role may not do with 403 and a sentence.
* **Origin** — a browser's request that changes something must come from the rover's own
  origin or ``web.allowed_origins`` (CSRF).
* **Host** — every request's ``Host`` must be an IP address, ``localhost``, this machine's
  name (also ``<name>.local``) or in ``web.allowed_hosts`` (DNS rebinding).
* **Rates** — changes are limited to ``web.max_messages_per_s`` per address; the e-stop never
  is. Wrong tokens from one address beyond ``web.wrong_token_limit`` in
  ``web.wrong_token_window_s`` throttle that address (429, logged once per burst) — except an
  e-stop with a right token, which is always let through.
* **Logs** — no token is ever logged; :class:`RedactTokens` scrubs aiohttp's own messages.

Time comes from the injected clock.
"""

from __future__ import annotations

import ipaddress
import logging
import re
import socket
from collections import Counter, deque
from urllib.parse import urlsplit

from aiohttp import hdrs, web

from curio.core.clock import Clock
from curio.core.config import WebConfig
from curio.web.inputs import http_error
from curio.web.tokens import PERMISSION_WORDS, VIEWER, Identity, TokenStore

__all__ = [
    "WS_PROTOCOL",
    "Gate",
    "RateLimiter",
    "RedactTokens",
    "check_origin",
    "host_allowed",
    "request_token",
]

log = logging.getLogger("curio.web.auth")

# The subprotocol the page speaks; it offers ``curio.token.<token>`` next to it.
WS_PROTOCOL = "curio.v1"
WS_TOKEN_PREFIX = "curio.token."
_WRONG_TOKEN = ("the token is wrong (or was revoked): use the link from the rover's start-up "
                "log or from 'curio token create'")
_NOT_ASCII = ("the token is wrong: tokens are plain letters, digits, '-' and '_' (this one has "
              "other characters)")


def request_token(request: web.Request) -> str | None:
    """The token a request presents (header, query or WebSocket subprotocol), or None."""
    auth = request.headers.get(hdrs.AUTHORIZATION, "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip() or None
    header = request.headers.get("X-Curio-Token")
    if header:
        return header.strip()
    query = request.query.get("token")
    if query:
        return query.strip()
    for proto in request.headers.get(hdrs.SEC_WEBSOCKET_PROTOCOL, "").split(","):
        proto = proto.strip()
        if proto.startswith(WS_TOKEN_PREFIX):
            return proto[len(WS_TOKEN_PREFIX):] or None
    return None


def check_origin(request: web.Request, allowed_origins: list[str]) -> str | None:
    """Return why the request's ``Origin`` is not acceptable, or None when it is.

    A missing Origin (a non-browser client) is accepted: the token still guards control. A
    browser's Origin must name the same host and port the request was sent to, or be listed in
    ``web.allowed_origins``.
    """
    origin = request.headers.get(hdrs.ORIGIN)
    if origin is None:
        return None
    if origin in allowed_origins or "*" in allowed_origins:
        return None
    parts = urlsplit(origin)
    host = request.headers.get(hdrs.HOST, request.host)
    if parts.netloc and parts.netloc.lower() == host.lower():
        return None
    return (
        f"origin {origin!r} is not allowed: pages must be served by this rover ({host}) "
        "or the origin must be listed in web.allowed_origins"
    )


def _host_name(host_header: str) -> str:
    """``name:port`` / ``[v6]:port`` / ``v4`` → the name or address, lower case."""
    host = host_header.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    if host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.rstrip(".")


def host_allowed(host_header: str, allowed_hosts: list[str], machine_names: set[str]) -> bool:
    """Whether a ``Host`` header names this rover: an IP address, ``localhost``, one of
    ``machine_names`` or of ``allowed_hosts`` (``*`` allows any)."""
    if "*" in allowed_hosts:
        return True
    name = _host_name(host_header)
    if not name:
        return False
    try:
        ipaddress.ip_address(name)
        return True  # an address cannot be rebound by DNS
    except ValueError:
        pass
    allowed = {h.lower().rstrip(".") for h in allowed_hosts} | machine_names
    return name in allowed or name == "localhost" or name.endswith(".localhost")


def machine_names() -> set[str]:
    """This machine's host names (``curio``, ``curio.local``, its FQDN), lower case."""
    names = set()
    for name in (socket.gethostname(), socket.getfqdn()):
        name = name.lower().rstrip(".")
        if name:
            names.add(name)
            names.add(name.split(".")[0] + ".local")
    return names


class RateLimiter:
    """A token bucket: ``rate_per_s`` messages per second, bursts of up to ``burst``.

    Time comes from the caller (the injected clock's ``now()``).
    """

    def __init__(self, rate_per_s: float, burst: float | None = None) -> None:
        if rate_per_s <= 0:
            raise ValueError(f"rate_per_s must be > 0, got {rate_per_s}")
        self.rate_per_s = rate_per_s
        self.burst = burst if burst is not None else max(1.0, rate_per_s)
        self._tokens = self.burst
        self._last_s: float | None = None
        self.rejected = 0

    def allow(self, now_s: float) -> bool:
        """Take one token if available; return False (and count it) when over the limit."""
        if self._last_s is not None:
            self._tokens = min(self.burst, self._tokens + (now_s - self._last_s) * self.rate_per_s)
        self._last_s = now_s
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self.rejected += 1
        return False


class _WrongTokens:
    """Wrong-token attempts per address; an address over the limit is throttled."""

    def __init__(self, limit: int, window_s: float) -> None:
        self.limit = limit
        self.window_s = window_s
        self._times: dict[str, deque[float]] = {}
        self._until: dict[str, float] = {}
        self.total = 0
        self.throttled_total = 0

    def throttled(self, remote: str, now: float) -> float:
        """Seconds ``remote`` stays throttled (0 when it is not)."""
        until = self._until.get(remote, 0.0)
        if until <= now:
            self._until.pop(remote, None)
            return 0.0
        return until - now

    def record(self, remote: str, now: float) -> None:
        """Count one wrong token from ``remote``; log it, or the start of a throttle."""
        self.total += 1
        times = self._times.setdefault(remote, deque())
        times.append(now)
        while times and times[0] < now - self.window_s:
            times.popleft()
        if len(times) >= self.limit:
            self._until[remote] = now + self.window_s
            times.clear()
            self.throttled_total += 1
            log.warning("dashboard: %d wrong tokens from %s within %.0f s; its tokens are "
                        "refused for %.0f s (except an e-stop with a right token)",
                        self.limit, remote, self.window_s, self.window_s)
        else:
            log.warning("dashboard: wrong token from %s (%d of %d allowed in %.0f s)",
                        remote, len(times), self.limit, self.window_s)
        if len(self._times) > 4096:  # forget the oldest addresses (a spray of addresses)
            for old in list(self._times)[:1024]:
                self._times.pop(old, None)


class Gate:
    """Who may do what: identity, role, Origin, Host, rate limits and socket caps.

    Refusals are JSON HTTP errors (:func:`~curio.web.inputs.http_error`) whose message says
    what to do.

    Args:
        cfg: the ``[web]`` section.
        tokens: the named tokens.
        clock: the injected clock (rate limits, throttles).
    """

    def __init__(self, cfg: WebConfig, tokens: TokenStore, clock: Clock) -> None:
        self.cfg = cfg
        self.tokens = tokens
        self.clock = clock
        self.machine_names = machine_names()
        self._limiters: dict[str, RateLimiter] = {}
        self.wrong = _WrongTokens(cfg.wrong_token_limit, cfg.wrong_token_window_s)
        self.viewer_sockets: Counter[str] = Counter()
        self.rate_limited = 0
        self.hosts_refused = 0
        self.sockets_refused = 0

    # --- identity -------------------------------------------------------------------------------

    def identify(self, request: web.Request, *, estop: bool = False) -> Identity:
        """The request's identity (a viewer without a token).

        Raises:
            403: a wrong, revoked or non-ASCII token; 429: the address is throttled for wrong
            tokens (an ``estop`` with a right token still passes).
        """
        presented = request_token(request)
        if not self.cfg.require_token:
            entry = self.tokens.identify(presented) if presented else None
            return entry.identity() if entry else Identity("anyone", "admin")
        if presented is None:
            return VIEWER
        remote = request.remote or "?"
        now = self.clock.now()
        wait_s = self.wrong.throttled(remote, now)
        entry = self.tokens.identify(presented) if presented.isascii() else None
        if wait_s > 0 and not (estop and entry is not None):
            raise http_error(web.HTTPTooManyRequests,
                             f"too many wrong tokens from {remote}: try again in "
                             f"{wait_s:.0f} s", headers={"Retry-After": f"{wait_s:.0f}"})
        if entry is None:
            self.wrong.record(remote, now)
            raise http_error(web.HTTPForbidden,
                             _WRONG_TOKEN if presented.isascii() else _NOT_ASCII)
        return entry.identity()

    def peek(self, request: web.Request) -> Identity:
        """Who a reading request is; a wrong or missing token is simply a viewer (not counted
        as a wrong-token attempt: reading is open anyway)."""
        if not self.cfg.require_token:
            return Identity("anyone", "admin")
        presented = request_token(request)
        entry = self.tokens.identify(presented) if presented and presented.isascii() else None
        return entry.identity() if entry is not None else VIEWER

    # --- permission -----------------------------------------------------------------------------

    def require(self, request: web.Request, permission: str) -> Identity:
        """The identity of a request that changes something and needs ``permission``.

        Raises:
            403 (foreign Origin, wrong token, a role without the permission), 401 (no token),
            429 (too many changes from this address; never for ``estop``).
        """
        why = check_origin(request, self.cfg.allowed_origins)
        if why is not None:
            raise http_error(web.HTTPForbidden, why)
        who = self.identify(request, estop=permission == "estop")
        if not who.may(permission):
            if who.role == "viewer":
                raise http_error(
                    web.HTTPUnauthorized,
                    f"to {PERMISSION_WORDS.get(permission, permission)} you need a token: open "
                    "the link from the rover's start-up log (http://…/?token=…) or send "
                    "'Authorization: Bearer <token>'")
            raise http_error(web.HTTPForbidden, refusal(who, permission))
        if permission != "estop" and request.method != "GET":
            remote = request.remote or "?"
            limiter = self._limiters.setdefault(
                remote, RateLimiter(self.cfg.max_messages_per_s,
                                    burst=self.cfg.max_messages_per_s))
            if not limiter.allow(self.clock.now()):
                self.rate_limited += 1
                raise http_error(
                    web.HTTPTooManyRequests,
                    f"too many requests: at most {self.cfg.max_messages_per_s:g} per second "
                    "(the e-stop is never limited)")
        return who

    # --- guards ---------------------------------------------------------------------------------

    def check_host(self, request: web.Request) -> None:
        """Refuse a request whose ``Host`` does not name this rover (DNS rebinding).

        Raises:
            403 with a sentence naming the host and the setting to change.
        """
        host = request.headers.get(hdrs.HOST, "")
        if not host_allowed(host, self.cfg.allowed_hosts, self.machine_names):
            self.hosts_refused += 1
            shown = host.encode("ascii", "replace").decode()[:80]
            raise http_error(web.HTTPForbidden,
                             f"host {shown!r} is not allowed: open the dashboard by the rover's "
                             "address or name, or add the name to web.allowed_hosts")

    def open_viewer_socket(self, remote: str) -> None:
        """Count one more socket without a token from ``remote``.

        Raises:
            503: over ``web.max_viewer_sockets_per_ip`` or ``web.max_viewer_sockets``.
        """
        cfg = self.cfg
        if self.viewer_sockets[remote] >= cfg.max_viewer_sockets_per_ip:
            self.sockets_refused += 1
            raise http_error(web.HTTPServiceUnavailable,
                             f"too many open dashboards from {remote} without a token (at most "
                             f"{cfg.max_viewer_sockets_per_ip}); close some tabs")
        if sum(self.viewer_sockets.values()) >= cfg.max_viewer_sockets:
            self.sockets_refused += 1
            raise http_error(web.HTTPServiceUnavailable,
                             f"too many open dashboards without a token (at most "
                             f"{cfg.max_viewer_sockets}); try again later or use a token")
        self.viewer_sockets[remote] += 1

    def close_viewer_socket(self, remote: str) -> None:
        """A socket counted by :meth:`open_viewer_socket` closed."""
        self.viewer_sockets[remote] -= 1
        if self.viewer_sockets[remote] <= 0:
            del self.viewer_sockets[remote]


def refusal(who: Identity, permission: str) -> str:
    """Why ``who`` may not do what needs ``permission``, in a sentence."""
    if who.role == "kiosk":
        return (f"the kiosk token '{who.name}' may only start and stop tours, not "
                f"{PERMISSION_WORDS.get(permission, permission)}")
    return (f"'{who.name}' ({who.role}) may not {PERMISSION_WORDS.get(permission, permission)}; "
            "ask an admin")


class RedactTokens(logging.Filter):
    """Scrub tokens from log records (aiohttp logs refused WebSocket subprotocols verbatim).

    Replaces ``curio.token.<x>``, ``token=<x>`` and ``Bearer <x>`` and every token of the store.
    """

    _PATTERNS = (re.compile(r"(curio\.token\.)[^\s'\",\]]+"),
                 re.compile(r"(token=)[^\s&'\",\]]+"),
                 re.compile(r"(Bearer )[^\s'\",\]]+", re.IGNORECASE))

    def __init__(self, tokens: TokenStore) -> None:
        super().__init__()
        self.tokens = tokens

    def redact(self, text: str) -> str:
        """``text`` without any token."""
        for pattern in self._PATTERNS:
            text = pattern.sub(r"\1<redacted>", text)
        for entry in self.tokens.entries():
            if entry.token in text:
                text = text.replace(entry.token, "<redacted>")
        return text

    def filter(self, record: logging.LogRecord) -> bool:
        """Rewrite the record's message without tokens (always keeps the record)."""
        try:
            message = record.getMessage()
        except Exception:  # a malformed record: leave it to logging's own error path
            return True
        clean = self.redact(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True
