"""Dashboard security: the control token, Origin checks and message-rate limits.

Viewing is open; anything that moves the rover or changes its data needs the control token.
:class:`ControlGate` applies these rules to a request (REST or the WebSocket upgrade).
The token is generated with :mod:`secrets` on first start and stored (mode 0600, written
atomically) with the rover's data; the start-up log prints a ready-to-open URL carrying it.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from urllib.parse import urlsplit

from aiohttp import web

from curio.core.clock import Clock
from curio.core.config import WebConfig
from curio.core.fileio import atomic_write_text
from curio.web.inputs import http_error

__all__ = [
    "ControlGate",
    "RateLimiter",
    "check_origin",
    "load_or_create_token",
    "request_token",
    "token_matches",
]

_WRONG_TOKEN = "the token is wrong: use the URL from the rover's start-up log"

_TOKEN_BYTES = 24


def load_or_create_token(path: Path) -> str:
    """Return the token stored at ``path``, creating it (0600, atomically) if missing or empty.

    Raises:
        PermissionError / OSError: the file exists but cannot be read or written.
    """
    if path.is_file():
        token = path.read_text(encoding="utf-8").strip()
        if len(token) >= 16:
            if os.stat(path).st_mode & 0o077:
                os.chmod(path, 0o600)
            return token
    token = secrets.token_urlsafe(_TOKEN_BYTES)
    atomic_write_text(path, token + "\n", private=True)
    return token


def request_token(request: web.Request) -> str | None:
    """The token a request presents: ``Authorization: Bearer``, ``X-Curio-Token`` or ``?token=``."""
    auth = request.headers.get("Authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    header = request.headers.get("X-Curio-Token")
    if header:
        return header.strip()
    query = request.query.get("token")
    return query.strip() if query else None


def token_matches(presented: str | None, expected: str) -> bool:
    """Constant-time comparison of the presented token with the expected one."""
    if not presented:
        return False
    return secrets.compare_digest(presented.encode(), expected.encode())


def check_origin(request: web.Request, allowed_origins: list[str]) -> str | None:
    """Return why the request's ``Origin`` is not acceptable, or None when it is.

    A missing Origin (a non-browser client) is accepted: the token still guards control. A
    browser's Origin must name the same host and port the request was sent to, or be listed in
    ``web.allowed_origins``.
    """
    origin = request.headers.get("Origin")
    if origin is None:
        return None
    if origin in allowed_origins or "*" in allowed_origins:
        return None
    parts = urlsplit(origin)
    host = request.headers.get("Host", request.host)
    if parts.netloc and parts.netloc.lower() == host.lower():
        return None
    return (
        f"origin {origin!r} is not allowed: pages must be served by this rover ({host}) "
        "or the origin must be listed in web.allowed_origins"
    )


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


class ControlGate:
    """Who may control the rover: a request from an allowed Origin that carries the token.

    Changes (anything but ``GET``) are also limited to ``web.max_messages_per_s`` per remote
    address. Refusals are JSON HTTP errors (:func:`~curio.web.inputs.http_error`).

    Args:
        cfg: the ``[web]`` section (``require_token``, ``allowed_origins``, the rate limit).
        token: the control token.
        clock: the injected clock (rate limits).
    """

    def __init__(self, cfg: WebConfig, token: str, clock: Clock) -> None:
        self.cfg = cfg
        self.token = token
        self.clock = clock
        self._limiters: dict[str, RateLimiter] = {}

    def require_control(self, request: web.Request) -> None:
        """Raise 403 (foreign Origin, wrong token), 401 (no token) or 429 (too many changes)."""
        cfg = self.cfg
        why = check_origin(request, cfg.allowed_origins)
        if why is not None:
            raise http_error(web.HTTPForbidden, why)
        if cfg.require_token:
            presented = request_token(request)
            if not presented:
                raise http_error(
                    web.HTTPUnauthorized,
                    "control needs the token: open the URL printed in the rover's start-up log "
                    "(http://…/?token=…) or send 'Authorization: Bearer <token>'")
            if not token_matches(presented, self.token):
                raise http_error(web.HTTPForbidden, _WRONG_TOKEN)
        if request.method != "GET":
            remote = request.remote or "?"
            limiter = self._limiters.setdefault(
                remote, RateLimiter(cfg.max_messages_per_s, burst=cfg.max_messages_per_s))
            if not limiter.allow(self.clock.now()):
                raise http_error(
                    web.HTTPTooManyRequests,
                    f"too many requests: at most {cfg.max_messages_per_s:g} per second")

    def has_control(self, request: web.Request) -> bool:
        """Whether :meth:`require_control` would let ``request`` through."""
        try:
            self.require_control(request)
        except web.HTTPException:
            return False
        return True

    def socket_control(self, request: web.Request) -> bool:
        """For a WebSocket upgrade: True to control, False to view only.

        Raises:
            web.HTTPForbidden: a foreign Origin, or a token that is presented but wrong.
        """
        why = check_origin(request, self.cfg.allowed_origins)
        if why is not None:
            raise http_error(web.HTTPForbidden, why)
        presented = request_token(request)
        control = not self.cfg.require_token or token_matches(presented, self.token)
        if presented and not control:
            raise http_error(web.HTTPForbidden, _WRONG_TOKEN)
        return control
