"""One connected browser: a :class:`ClientSession` per WebSocket.

**Out** (filled by the :class:`~curio.web.hub.Hub`, drained by :meth:`ClientSession.send_loop`,
the session's own task): an ordered queue of reliable messages (status, progress, events,
e-stop, lease, acks) that is never dropped, and a conflating slot per stream key (scan, pose,
plans, tree, health, ...) flushed at most ``rate_hz`` times a second. A slow browser only
delays its own sender.

**In** (:meth:`ClientSession.receive_loop`): JSON objects with an ``op``, each checked against
``web.max_message_bytes`` first:

* ``{"op": "estop", "id"?}`` or ``{"op": "command", "action": "estop"}`` → the e-stop, handled
  before the rate limit (never limited, never counted towards a disconnect)
* ``{"op": "ping", "id"?}`` → ``{"t": "pong"}``
* ``{"op": "rate", "hz": N}`` → lower this client's stream rate (≤ ``web.client_rate_hz``)
* ``{"op": "teleop", "seq": n, "linear_mps": v, "angular_radps": w, "take_over"?: true}``
  (needs ``drive``; refused with code ``lease_held`` and the driver's name while another
  operator drives, unless ``take_over``)
* ``{"op": "command", "id"?, "action": ..., "path_id"?, "goal"?, "request_id"?}`` (the action's
  permission: ``tour`` for a kiosk, ``command``/``estop`` for operators)
* ``{"op": "initial_pose", "x_m", "y_m", "yaw_rad"}`` (needs ``initial_pose``)

Every other message counts against ``web.max_messages_per_s``. Replies: ``{"t": "ack", "id",
...}`` or ``{"t": "error", "id", "code", "message"}``. A message over the size limit closes the
socket (1009); 100 rate-limited messages in a row close it (1008). Teleop messages older than
the client's last ``seq`` are ignored; what is accepted goes to the shared
:class:`~curio.web.control.RoverControl` (which also holds the lease and the deadman).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import deque
from collections.abc import Callable, Coroutine
from typing import Any

from aiohttp import WSCloseCode, WSMsgType, web

from curio.core.config import WebConfig
from curio.core.jsonable import to_json
from curio.web.auth import RateLimiter, refusal
from curio.web.control import LeaseHeld, RoverControl, action_permission
from curio.web.inputs import REQUEST_ID, CommandError, parse_json_object, parse_teleop
from curio.web.tokens import Identity

__all__ = ["CLIENT_OPS", "ClientSession"]

log = logging.getLogger("curio.web.session")

CLIENT_OPS = ("ping", "rate", "estop", "teleop", "command", "initial_pose")
# The permission each op needs (``command`` depends on its action).
OP_PERMISSIONS = {"estop": "estop", "teleop": "drive", "initial_pose": "initial_pose"}
# Consecutive rate-limited messages after which a client is disconnected (code 1008).
MAX_REJECTED_IN_A_ROW = 100


class ClientSession:
    """One connected browser: its queues and sender, its receive loop, its rate and teleop state.

    Args:
        id: the client number (sent in ``hello``).
        ws: the prepared WebSocket.
        who: the token's name and role (a viewer without a token).
        cfg: the ``[web]`` section (message size and rate limits, the stream rate).
        rover: publishes what the client is allowed to send in.
        remote: the peer's address (for logs).
    """

    def __init__(self, id: int, ws: web.WebSocketResponse, who: Identity, cfg: WebConfig,
                 rover: RoverControl, remote: str = "") -> None:
        self.id = id
        self.ws = ws
        self.who = who
        self.cfg = cfg
        self.rover = rover
        self.clock = rover.clock
        self.remote = remote
        self.rate_hz = cfg.client_rate_hz
        self.limiter = RateLimiter(cfg.max_messages_per_s, burst=cfg.max_messages_per_s)
        self.pending: dict[str, str | bytes] = {}
        self.reliable: deque[str] = deque()
        self.wake = asyncio.Event()
        self.closed = False
        self.rejected_in_a_row = 0
        self.last_teleop_seq = -1
        self.token_entry: Any = None  # the TokenEntry it authenticated with (None: viewer)
        self.sent_frames = 0
        self.sent_bytes = 0
        self._command_order = asyncio.Lock()
        self._commands: set[asyncio.Future[None]] = set()

    # --- out ----------------------------------------------------------------------------------

    def queue(self, text: str) -> None:
        """Queue a reliable message (JSON text)."""
        self.reliable.append(text)
        self.wake.set()

    def offer(self, key: str, frame: str | bytes) -> None:
        """Put ``frame`` in the stream slot ``key`` (replacing one not yet sent)."""
        idle = not self.pending
        self.pending[key] = frame
        if idle:  # the sender waits for the next stream slot already when something is pending
            self.wake.set()

    def reply(self, payload: dict[str, Any]) -> None:
        """Queue a reliable reply to this client."""
        self.queue(to_json(payload))

    def mark_closed(self) -> None:
        """Stop the sender (the hub has forgotten this client)."""
        self.closed = True
        self.wake.set()

    def close_soon(self, code: int, message: bytes) -> None:
        """Close the socket in the background (from code that cannot await)."""
        task = asyncio.ensure_future(self.ws.close(code=code, message=message))
        task.add_done_callback(lambda t: t.exception() if not t.cancelled() else None)

    async def send_loop(self) -> None:
        """Send the queued messages until the client closes (the session's own task)."""
        ws = self.ws
        next_stream_s = self.clock.now()
        while not self.closed and not ws.closed:
            while self.reliable:
                text = self.reliable.popleft()
                await ws.send_str(text)
                self.sent_frames += 1
                self.sent_bytes += len(text)
            now = self.clock.now()
            if self.pending and now >= next_stream_s:
                await self._flush_streams()
                next_stream_s = max(now, next_stream_s) + 1.0 / self.rate_hz
                continue
            self.wake.clear()
            if self.reliable or self.closed:
                continue
            if self.pending:  # streams wait for their slot; a reliable message does not
                with contextlib.suppress(TimeoutError):
                    await self.clock.wait_for(self.wake.wait(), next_stream_s - now)
            else:
                await self.wake.wait()

    async def _flush_streams(self) -> None:
        frames, self.pending = self.pending, {}
        for frame in frames.values():
            if isinstance(frame, bytes):
                await self.ws.send_bytes(frame)
            else:
                await self.ws.send_str(frame)
            self.sent_frames += 1
            self.sent_bytes += len(frame)

    # --- in -----------------------------------------------------------------------------------

    async def serve(self, release: Callable[[ClientSession], None]) -> None:
        """Run the sender and the receive loop until the socket closes; then ``release(self)``
        (the hub forgets the client), stop the sender and close the socket."""
        sender = asyncio.ensure_future(self.send_loop())
        sender.add_done_callback(_log_failure)
        try:
            await self.receive_loop()
        finally:
            release(self)
            sender.cancel()
            with contextlib.suppress(BaseException):
                await sender
            if not self.ws.closed:
                with contextlib.suppress(Exception):
                    await self.ws.close()

    async def receive_loop(self) -> None:
        """Handle the client's messages until it closes or must be closed."""
        async for msg in self.ws:
            if msg.type == WSMsgType.TEXT:
                if not await self._on_text(msg.data):
                    break
            elif msg.type == WSMsgType.BINARY:
                self.reply({"t": "error", "code": "bad_message",
                            "message": "binary messages are not accepted; send JSON"})
            elif msg.type == WSMsgType.ERROR:
                break

    async def _on_text(self, text: str) -> bool:
        """Handle one message; return False when the socket must close."""
        size = len(text.encode("utf-8"))
        if size > self.cfg.max_message_bytes:
            message = (f"message of {size} bytes exceeds "
                       f"web.max_message_bytes={self.cfg.max_message_bytes}")
            await self.ws.send_str(json.dumps({"t": "error", "code": "too_big",
                                               "message": message}))
            await self.ws.close(code=WSCloseCode.MESSAGE_TOO_BIG, message=b"message too big")
            return False
        try:
            body = parse_json_object(text)
        except CommandError as exc:
            self.rover.rejected_messages += 1
            self.reply({"t": "error", "id": None, "code": "rejected", "message": str(exc)})
            return True
        msg_id = body.get("id")
        if _is_estop(body):  # before the rate limit: the e-stop is never refused for speed
            await self._answering(self._op_estop(body, msg_id), msg_id)
            return True
        if not self.limiter.allow(self.clock.now()):
            return await self._on_too_fast()
        self.rejected_in_a_row = 0
        if body.get("op") == "command":
            # Written ahead before it is published: meanwhile this loop goes on, so an e-stop
            # or a teleop message never waits behind a command's commit; commands keep order.
            task = asyncio.ensure_future(self._command_in_order(body, msg_id))
            self._commands.add(task)
            task.add_done_callback(self._commands.discard)
        else:
            await self._answering(self._handle_op(body, msg_id), msg_id)
        return True

    async def _command_in_order(self, body: dict[str, Any], msg_id: Any) -> None:
        async with self._command_order:
            await self._answering(self._handle_op(body, msg_id), msg_id)

    async def _answering(self, handling: Coroutine[Any, Any, None], msg_id: Any) -> None:
        """Run ``handling``; a refusal becomes the client's ``error`` reply."""
        try:
            await handling
        except LeaseHeld as exc:
            self.reply({"t": "error", "id": msg_id, "code": "lease_held", "holder": exc.holder,
                        "message": str(exc)})
        except CommandError as exc:
            self.rover.rejected_messages += 1
            self.reply({"t": "error", "id": msg_id, "code": "rejected", "message": str(exc)})

    async def _on_too_fast(self) -> bool:
        """A message over the rate limit: dropped, said once; False when the client must go."""
        self.rover.rejected_messages += 1
        self.rejected_in_a_row += 1
        if self.rejected_in_a_row == 1:
            self.reply({"t": "error", "code": "rate_limited",
                        "message": f"too many messages: at most "
                                   f"{self.cfg.max_messages_per_s:g} per second; "
                                   "this one was dropped"})
        if self.rejected_in_a_row >= MAX_REJECTED_IN_A_ROW:
            await self.ws.close(code=WSCloseCode.POLICY_VIOLATION,
                                message=b"too many messages per second")
            return False
        return True

    async def _handle_op(self, body: dict[str, Any], msg_id: Any) -> None:
        op = body.get("op")
        if op not in CLIENT_OPS:
            raise CommandError(f"unknown op {op!r}; allowed: {', '.join(CLIENT_OPS)}")
        permission = (action_permission(body.get("action")) if op == "command"
                      else OP_PERMISSIONS.get(str(op)))
        if permission is not None and not self.who.may(permission):
            raise CommandError(self._refusal(permission))
        if op == "ping":
            self.reply({"t": "pong", "id": msg_id, "server_time": self.clock.now()})
        elif op == "rate":
            self._op_rate(body, msg_id)
        elif op == "teleop":
            self._op_teleop(body)
        elif op == "command":
            cmd, published = await self.rover.command(body, self.who)
            self.reply({"t": "ack", "id": msg_id, "request_id": cmd.request_id,
                        "action": cmd.action, "duplicate": not published})
        elif op == "initial_pose":
            pose = self.rover.initial_pose(body, self.who)
            self.reply({"t": "ack", "id": msg_id, "pose": [pose.x, pose.y, pose.yaw]})

    def _refusal(self, permission: str) -> str:
        if self.who.role == "viewer":
            return ("viewing only: this needs a token (open the link from the rover's "
                    "start-up log)")
        return refusal(self.who, permission)

    async def _op_estop(self, body: dict[str, Any], msg_id: Any) -> None:
        if not self.who.may("estop"):
            raise CommandError(self._refusal("estop"))
        request_id = body.get("request_id")
        cmd = await self.rover.estop(self.who, request_id if isinstance(request_id, str)
                               and REQUEST_ID.match(request_id) else "")
        self.reply({"t": "ack", "id": msg_id, "request_id": cmd.request_id, "action": "estop",
                    "duplicate": False})

    def _op_rate(self, body: dict[str, Any], msg_id: Any) -> None:
        hz = body.get("hz")
        if not isinstance(hz, int | float) or isinstance(hz, bool) or not hz > 0:
            raise CommandError(f"rate needs 'hz' > 0, got {hz!r}")
        self.rate_hz = min(float(hz), self.cfg.client_rate_hz)
        self.reply({"t": "ack", "id": msg_id, "rate_hz": self.rate_hz})

    def _op_teleop(self, body: dict[str, Any]) -> None:
        lin, ang, seq = parse_teleop(body)
        if seq is not None:
            if seq <= self.last_teleop_seq:
                return  # an older message overtaken by a newer one
            self.last_teleop_seq = seq
        self.rover.teleop(self.id, self.who, lin, ang, take_over=body.get("take_over") is True)


def _is_estop(body: dict[str, Any]) -> bool:
    """``{"op": "estop"}`` or ``{"op": "command", "action": "estop"}``."""
    op = body.get("op")
    return op == "estop" or (op == "command" and body.get("action") == "estop")


def _log_failure(task: asyncio.Task[None]) -> None:
    if not task.cancelled() and task.exception() is not None:
        log.debug("web task ended: %r", task.exception())
