"""Live Foxglove / Lichtblick: the recorder's channels over ``foxglove-sdk``'s WebSocket server.

Optional (``pip install 'curio[foxglove]'``, ``foxglove.enabled = true``), bound to
``foxglove.host`` (127.0.0.1 by default: reach it through an SSH tunnel, or bind the LAN on
purpose). :class:`FoxgloveSink` is a recorder sink: the same JSON payloads the MCAP files get,
on the same channels and schemas, so Foxglove draws the scan, map, costmaps, plans, obstacles,
TF tree and logs natively. A client that subscribes to a latched channel (the map, the fixed
frames, the scene, the plan, ...) gets its last message again within a flush period.

**Teleop.** With ``foxglove.teleop``, Foxglove's Teleop panel may publish
``geometry_msgs/Twist`` JSON (``linear.x`` m/s, ``angular.z`` rad/s) on ``/cmd_vel_teleop``
(or ``/cmd_vel``): it goes on the bus as ``/cmd_vel_teleop`` — through the safety stage, like the
dashboard's joystick — but only from a client that has first set the parameter
``operator_token`` to a dashboard token of an operator or admin (Parameters panel). Everyone else's
commands are refused, counted and answered with a warning status. The token is never sent back
(it reads as empty).

The SDK calls the listener on its own threads: the listener only touches thread-safe state and
hands commands to the loop with :meth:`~curio.core.bus.Bus.publish_threadsafe`.
"""

from __future__ import annotations

import json
import logging
import math
import threading
from collections.abc import Callable
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.errors import SetupError
from curio.core.messages import Twist
from curio.core.topics import CMD_VEL_TELEOP
from curio.record.codec import ChannelSpec

try:
    import foxglove
    from foxglove.websocket import Capability, ChannelView, Client, ClientChannel, ServerListener

    HAVE_SDK = True
except ImportError:  # pragma: no cover - the optional extra is missing
    HAVE_SDK = False
    ServerListener = object  # type: ignore[misc,assignment]

__all__ = ["TOKEN_PARAMETER", "FoxgloveSink"]

log = logging.getLogger("curio.record.foxglove")

TOKEN_PARAMETER = "operator_token"
TELEOP_TOPICS = ("/cmd_vel_teleop", "/cmd_vel")
MAX_SPEED = 5.0  # reject absurd numbers outright; the safety stage limits the rest


class _Listener(ServerListener):  # type: ignore[misc]
    """The SDK's callbacks (on its threads): subscriptions, client channels, parameters."""

    def __init__(self, sink: FoxgloveSink) -> None:
        self.sink = sink

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.sink.resend(channel.topic)

    def on_client_advertise(self, client: Client, channel: ClientChannel) -> None:
        self.sink.client_channel(client.id, channel.id, channel.topic)

    def on_message_data(self, client: Client, client_channel_id: int, data: bytes) -> None:
        self.sink.client_message(client.id, client_channel_id, data)

    def on_get_parameters(self, client: Client, param_names: list[str],
                          request_id: str | None = None) -> list[Any]:
        return [foxglove.Parameter(TOKEN_PARAMETER, value="")]

    def on_set_parameters(self, client: Client, parameters: list[Any],
                          request_id: str | None = None) -> list[Any]:
        for p in parameters:
            if p.name == TOKEN_PARAMETER:
                self.sink.authorize(client.id, p.get_value())
        return [foxglove.Parameter(TOKEN_PARAMETER, value="")]


class FoxgloveSink:
    """The live server, as a recorder sink (see the module docstring).

    Args:
        may_drive: whether a presented token may drive (an operator's or admin's token of the
            dashboard's named tokens).

    Raises:
        SetupError: the extra is not installed, or the port cannot be bound.
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock,
                 may_drive: Callable[[str], bool]) -> None:
        if not HAVE_SDK:
            raise SetupError("foxglove.enabled = true needs the optional extra: "
                             "pip install 'curio[foxglove]'")
        self.bus = bus
        self.clock = clock
        fc = cfg.foxglove
        self.teleop = fc.teleop
        self._may_drive = may_drive
        self._lock = threading.Lock()
        self._authorized: set[int] = set()
        self._client_topics: dict[tuple[int, int], str] = {}
        self._warned: set[int] = set()
        self._pending: set[str] = set()
        self._latched: dict[ChannelSpec, bytes] = {}
        self._channels: dict[str, Any] = {}
        self.accepted = 0
        self.refused = 0
        self.context = foxglove.Context()
        caps = [Capability.ClientPublish, Capability.Parameters] if fc.teleop else []
        try:
            self.server = foxglove.start_server(
                name="curio", host=fc.host, port=fc.port, capabilities=caps,
                server_listener=_Listener(self), supported_encodings=["json"],
                context=self.context)
        except Exception as exc:  # the SDK raises RuntimeError (or its own) for a busy port
            raise SetupError(f"foxglove.port = {fc.port} on {fc.host}: cannot listen ({exc}); "
                             "choose another port (0 picks a free one)") from None
        self.port = self.server.port
        log.info("Foxglove server on ws://%s:%d (subprotocol foxglove.sdk.v1)", fc.host,
                 self.port)

    # --- the sink interface (the recorder's writer thread) ----------------------------------
    def _channel(self, spec: ChannelSpec) -> Any:
        ch = self._channels.get(spec.topic)
        if ch is None:
            schema = foxglove.Schema(name=spec.schema_name, encoding="jsonschema",
                                     data=spec.schema)
            ch = foxglove.Channel(spec.topic, schema=schema, message_encoding="json",
                                  context=self.context)
            self._channels[spec.topic] = ch
        return ch

    def write(self, spec: ChannelSpec, log_ns: int, publish_ns: int, seq: int,
              data: bytes) -> None:
        """Send one message to the subscribed clients."""
        self._channel(spec).log(data, log_time=log_ns)
        if spec.latched:
            self._latched[spec] = data

    def flush(self) -> None:
        """Send the last message of latched channels someone subscribed to since."""
        with self._lock:
            topics, self._pending = self._pending, set()
        for spec, data in list(self._latched.items()):
            if spec.topic in topics:
                self._channel(spec).log(data)

    def close(self) -> None:
        """Stop the server."""
        self.server.stop()

    def describe(self) -> dict[str, Any]:
        """Counters for the recorder's health."""
        return {"foxglove_teleop_accepted": self.accepted,
                "foxglove_teleop_refused": self.refused}

    # --- the listener's side (SDK threads) --------------------------------------------------
    def resend(self, topic: str) -> None:
        """A client subscribed to ``topic``: send its latched message again at the next flush."""
        with self._lock:
            self._pending.add(topic)

    def client_channel(self, client_id: int, channel_id: int, topic: str) -> None:
        """A client advertised a channel it will publish on."""
        with self._lock:
            self._client_topics[(client_id, channel_id)] = topic

    def authorize(self, client_id: int, presented: Any) -> None:
        """The client set ``operator_token``: allow its teleop if the token matches."""
        ok = self.teleop and isinstance(presented, str) and self._may_drive(presented)
        with self._lock:
            if ok:
                self._authorized.add(client_id)
            else:
                self._authorized.discard(client_id)
        log.info("Foxglove client %d %s teleop", client_id,
                 "may" if ok else "presented a wrong operator_token: no")

    def client_message(self, client_id: int, channel_id: int, data: bytes) -> None:
        """A client published a message: teleop, if it may; anything else is ignored."""
        with self._lock:
            topic = self._client_topics.get((client_id, channel_id))
            allowed = client_id in self._authorized
        if topic not in TELEOP_TOPICS:
            return
        twist = _parse_twist(data) if allowed and self.teleop else None
        if twist is None:
            self._refuse(client_id, "set the parameter operator_token to the dashboard's token "
                         "first" if not allowed else "send geometry_msgs/Twist JSON")
            return
        try:
            self.bus.publish_threadsafe(CMD_VEL_TELEOP, Twist(self.clock.now(), twist[0],
                                                              twist[1], source="foxglove"))
            self.accepted += 1
        except RuntimeError:  # the application has not started yet
            self._refuse(client_id, "the rover is not running yet")

    def _refuse(self, client_id: int, why: str) -> None:
        self.refused += 1
        if client_id not in self._warned:
            self._warned.add(client_id)
            log.warning("Foxglove teleop refused: %s", why)
            self.server.publish_status(f"Curio refused teleop: {why}",
                                       foxglove.StatusLevel.Warning)


def _parse_twist(data: bytes) -> tuple[float, float] | None:
    """``(linear.x m/s, angular.z rad/s)`` of a Twist in JSON, or None if it is not one."""
    try:
        body = json.loads(data)
        lin = float(body["linear"]["x"])
        ang = float(body["angular"]["z"])
    except (ValueError, KeyError, TypeError):
        return None
    if not (math.isfinite(lin) and math.isfinite(ang)):
        return None
    if abs(lin) > MAX_SPEED or abs(ang) > MAX_SPEED:
        return None
    return lin, ang
