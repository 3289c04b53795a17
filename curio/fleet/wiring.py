"""Fleet wiring: the rover's bridge, its traffic part and its ROS 2 publisher.

``build_fleet`` returns None unless ``fleet.enabled``; then it checks that Zenoh is installed
(the ``curio[fleet]`` extra: a :class:`~curio.core.errors.SetupError` otherwise, so ``curio
run`` stops with one line), and registers:

* ``fleet.bridge`` (publish loop, link check) and ``fleet.pump`` (received samples to the
  loop) — :class:`~curio.fleet.bridge.FleetBridge`;
* ``fleet.traffic`` — :class:`~curio.fleet.traffic.TrafficNode`, whose hold is added to the
  navigator's ``holds`` (``fleet.traffic.enabled``); with ``fleet.traffic.predict_peers`` (off
  by default) and
  the people-aware controller's stage, the other rovers reach that stage as moving obstacles
  predicted along their plans (:class:`~curio.fleet.intent.RoverIntent`);
* ``fleet.keys`` — re-reads the keyring (and the dashboard's tokens) when ``curio fleet key``
  (``curio token``) changed them; a command may be signed with either;
* ``fleet.ros2`` — :class:`~curio.fleet.ros2.publisher.Ros2Publisher` (``fleet.ros2.enabled``);
* with ``fleet.share_sim_truth`` in the simulator, the other rovers' true poses become bodies
  in this rover's world (:class:`~curio.fleet.simworld.PeerBodies`).

A transport can be passed in (the fleet simulator passes one per rover; tests an in-process
one); by default it is a Zenoh session with ``fleet.mode``, ``fleet.connect``,
``fleet.listen``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock, SimClock
from curio.core.config import Config
from curio.core.errors import SetupError
from curio.core.parts import Part, Parts
from curio.estimation.maps import OccupancyGrid
from curio.estimation.wiring import map_name
from curio.fleet.auth import (
    ChainedKeys,
    CommandVerifier,
    FleetKeyring,
    KeyLookup,
    TokenStoreKeys,
)
from curio.fleet.bridge import FleetBridge
from curio.fleet.commands import CommandExecutor
from curio.fleet.intent import RoverIntent, known_rovers
from curio.fleet.keys import check_rover_name
from curio.fleet.maps_sync import map_name_status
from curio.fleet.simworld import PeerBodies
from curio.fleet.traffic import PassageFinder, TrafficNode
from curio.fleet.transport import Transport
from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, load_zenoh
from curio.fleet.zones_sync import zones_status
from curio.maps.control import MapsAccess
from curio.nav.navigator import NavigatorNode
from curio.robot import RobotModel
from curio.sim.world import World
from curio.tours.wiring import Tours

__all__ = ["Fleet", "build_fleet", "dashboard_address", "rover_name", "zenoh_settings"]


@dataclass(frozen=True)
class Fleet:
    """The fleet subsystem's objects on a rover."""

    rover: str
    transport: Transport
    bridge: FleetBridge
    traffic: TrafficNode | None
    keys: FleetKeyring
    ros2: Any | None
    bodies: PeerBodies | None = None


def rover_name(cfg: Config) -> str:
    """This rover's fleet name: ``fleet.rover``, else ``robot.name``.

    Raises:
        SetupError: the name cannot be a key chunk.
    """
    name = cfg.fleet.rover or cfg.robot.name
    try:
        return check_rover_name(name)
    except ValueError as exc:
        raise SetupError(f"fleet.rover / robot.name: {exc}") from None


def dashboard_address(cfg: Config, port: int) -> str:
    """Where operators reach this rover's dashboard, for the fleet page's link:
    ``fleet.dashboard_url`` when set; '' when the dashboard listens on the loopback only (a
    link nobody else could open); ``web.host`` when it is one address; else (``0.0.0.0``)
    the address of this machine on the network towards the fleet — the local end of a route
    to the first numeric ``fleet.connect`` endpoint (a UDP socket's connect: nothing is sent,
    no name is looked up) — or, without one, the machine's ``<hostname>.local`` (mDNS)."""
    if cfg.fleet.dashboard_url:
        return cfg.fleet.dashboard_url
    host = cfg.web.host
    with contextlib.suppress(ValueError):
        address = ipaddress.ip_address(host)
        if address.is_loopback:
            return ""
        if not address.is_unspecified:
            return f"http://{_url_host(address)}:{port}/"
    if host not in ("0.0.0.0", "::", ""):
        return f"http://{host}:{port}/"  # a name the operator chose
    for endpoint in cfg.fleet.connect:
        local = _local_address_towards(endpoint)
        if local is not None:
            return f"http://{_url_host(local)}:{port}/"
    return f"http://{socket.gethostname().split('.')[0].lower()}.local:{port}/"


def _url_host(address: ipaddress.IPv4Address | ipaddress.IPv6Address) -> str:
    return f"[{address}]" if address.version == 6 else str(address)


def _local_address_towards(endpoint: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """This machine's address on the route to a Zenoh endpoint ``proto/host:port`` with a
    numeric host (None: a name, unreachable, or the loopback)."""
    _, _, where = endpoint.partition("/")
    host, _, port = where.rpartition(":")
    host = host.strip("[]")
    try:
        remote = ipaddress.ip_address(host)
        family = socket.AF_INET6 if remote.version == 6 else socket.AF_INET
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect((str(remote), int(port.split("#")[0])))
            local = ipaddress.ip_address(probe.getsockname()[0])
    except (ValueError, OSError):
        return None
    return None if local.is_loopback or local.is_unspecified else local


def zenoh_settings(cfg: Config) -> ZenohSettings:
    """The Zenoh session settings of ``[fleet]``."""
    f = cfg.fleet
    return ZenohSettings(f.mode, tuple(f.connect), tuple(f.listen), f.multicast_scouting,
                         str(cfg.resolve(f.zenoh_config)) if f.zenoh_config else "")


def build_fleet(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel, *,
                navigator: NavigatorNode, grid: Callable[[], OccupancyGrid], tours: Tours,
                paths: Any = None, world: World | None = None, tokens: Any = None,
                transport: Transport | None = None, people_stage: Any = None,
                zones: Any = None, maps: MapsAccess | None = None) -> Fleet | None:
    """Construct and register the rover's fleet parts (None when ``fleet.enabled`` is off).

    ``tokens`` is the dashboard's token store (``curio.web.tokens.TokenStore``): its named
    tokens sign fleet commands too, with their roles, after the fleet's own keyring.
    ``people_stage`` is the people-aware controller's stage (``PeopleStage``, None without
    ``people.aware``): it gets the other rovers as movers with known intent. ``zones`` is the
    zone service (None: zones off): the fleet manager's ``set_zones`` goes to it, and its
    map and digest go into the status. ``maps`` is the map library and ``curio run``'s host
    (None in the fleet simulator and tests): the manager's ``set_map`` needs it.
    """
    f = cfg.fleet
    if not f.enabled:
        return None
    rover = rover_name(cfg)
    if transport is None:
        load_zenoh()
        transport = ZenohTransport(rover, zenoh_settings(cfg),
                                   threaded_puts=not isinstance(clock, SimClock))
    keys = FleetKeyring(cfg.data_path(f.keys_file))
    sources: list[KeyLookup] = [keys] if tokens is None else [keys, TokenStoreKeys(tokens)]
    verifier = CommandVerifier(rover, ChainedKeys(sources), clock.wall_time, f.command_max_age_s)

    def goal_active() -> bool:
        return navigator.active is not None

    def busy() -> str | None:  # the map host's own rule (a tour, a change) and a goal
        if goal_active():
            return "it is driving to a goal"
        state = maps.control.state() if maps is not None and maps.control is not None else {}
        return state.get("busy") or None

    executor = CommandExecutor(bus, clock, tours.service, tours.store,
                               has_dock=cfg.dock.enabled, zones=zones, maps=maps, busy=busy,
                               home=lambda: robot.home)

    traffic = None
    if f.traffic.enabled:
        width = float(robot.footprint[:, 1].max() - robot.footprint[:, 1].min())
        traffic = TrafficNode(f.traffic, rover, bus, clock,
                              PassageFinder(grid, f.traffic.narrow_width_m), width,
                              robot.circumscribed_radius_m, goal_active)
        navigator.holds.append(traffic.hold)
        navigator.controller.speed_limits["giving way"] = traffic.speed_limit
        parts.add(Part("fleet.traffic", run=traffic.run))
        if people_stage is not None:
            people_stage.rovers = known_rovers(traffic.peers, clock.wall_time,
                                               f.traffic.peer_timeout_s)
            if f.traffic.predict_peers:
                people_stage.movers = RoverIntent(traffic.peers, clock.wall_time,
                                                  f.traffic.peer_timeout_s)
    snapshots: dict[str, Callable[[], Any]] = {"tours": lambda: [
        t.to_json() for t in tours.store.list_tours()]}
    if paths is not None:
        snapshots["paths"] = lambda: [p.to_json() for p in paths.list_paths()]
    bridge = FleetBridge(cfg, rover, bus, clock, transport, robot, verifier, executor, traffic,
                         goal_active, snapshots)
    bridge.status_extras.append(zones_status(zones))
    bridge.status_extras.append(map_name_status(map_name(cfg)))
    if traffic is not None:
        bridge.on_peer("traffic", traffic.on_peer)
    bodies = None
    if f.share_sim_truth and world is not None:
        bodies = PeerBodies(world, robot)
        bridge.on_peer("sim/truth", bodies.on_truth)
    ros2 = None
    if f.ros2.enabled:
        from curio.fleet.ros2.publisher import Ros2Publisher

        ros2 = Ros2Publisher(f.ros2, rover, bus, clock, transport, robot)
        parts.add(Part("fleet.ros2", run=ros2.run))
    bridge.declare()
    if ros2 is not None:
        ros2.declare()
    parts.add(Part("fleet.bridge", run=bridge.run, close=bridge.close))
    parts.add(Part("fleet.pump", run=bridge.run_pump))

    async def watch_keys() -> None:
        reload_tokens = getattr(tokens, "reload_if_changed", None)
        async for _ in clock.every(1.0, phase_s=0.5):
            keys.reload_if_changed()
            if reload_tokens is not None:
                reload_tokens()

    parts.add(Part("fleet.keys", run=watch_keys))
    return Fleet(rover, transport, bridge, traffic, keys, ros2, bodies)
