"""What a verified fleet command does on the rover — through the same channels as the
dashboard's buttons.

A command from the network has passed :class:`~curio.fleet.auth.CommandVerifier` (signature,
freshness, replay, role) before it gets here; :class:`CommandExecutor` then validates its
fields and turns it into what the dashboard would send: an
:class:`~curio.core.messages.OperatorCommand` on the reliable ``/operator`` topic (the safety
stage latches an e-stop from there, the behaviour tree and the navigator take the rest), or a
call of the tour service (``start_tour`` checks the tour like the dashboard's Start does).
Nothing bypasses the tree's own refusals (e-stop, pause, low battery): their answer comes back
as ``bt.command_accepted`` / ``bt.command_rejected`` events with the command's request id.

Actions: ``goto`` (``x``, ``y``, ``yaw`` (default 0) in ``map``), ``start_tour`` (``tour_id``, and
``tour``: a tour definition the rover keeps first — the fleet manager distributes its shared
tours this way; it needs the ``command`` permission), ``stop_tour``, ``pause``, ``resume``,
``go_home``, ``dock`` (on a rover with a dock fitted — ``dock.enabled`` — Go Home *is* docking:
the tree's ``RequestDock`` drives the docker's staging, approach and retries; ``dock`` is refused
on a rover without one, so the sender knows it will not charge), ``cancel``, ``estop``,
``release_estop`` (only by the key that set it or an ``admin`` key, as on the dashboard),
``set_zones`` (``map``, ``zones``: the whole set of a map's keep-out and speed zones, from the
fleet manager — ``curio/fleet/zones_sync.py``; checked and applied by the rover's zone
service, refused on a rover without zones or on another map), ``set_map`` (``map``, ``grid``,
``sha``: a new revision of the map the rover drives on, from the fleet manager —
``curio/fleet/maps_sync.py``; taken only on a rover run by ``curio run``'s map host, parked,
when the map has free space at its home; it restarts on it).
A ``request_id`` (up to 64 characters) is echoed in the reply; a repeated one is acknowledged
without running again.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.messages import OperatorAction, OperatorCommand
from curio.core.topics import ESTOP, OPERATOR
from curio.fleet.auth import Verified
from curio.fleet.codec import grid_digest
from curio.fleet.maps_sync import decode_pushed_map
from curio.maps.control import MapsAccess
from curio.maps.library import MapLibraryError
from curio.tours.model import TourError, tour_from_json
from curio.tours.service import TourService
from curio.tours.store import TourStore
from curio.zones.model import ZoneError

__all__ = ["ACTIONS", "CommandExecutor", "Outcome"]

ACTIONS: tuple[str, ...] = ("goto", "start_tour", "stop_tour", "pause", "resume", "go_home",
                            "dock", "cancel", "estop", "release_estop", "set_zones",
                            "set_map")
# ``dock`` becomes Go Home: with a dock fitted the tree docks on it (curio/bt/unattended.py).
_PLAIN: dict[str, OperatorAction] = {"pause": "pause", "resume": "resume", "go_home": "go_home",
                                     "dock": "go_home", "cancel": "cancel", "estop": "estop",
                                     "release_estop": "release_estop"}
RECENT = 512


@dataclass(frozen=True)
class Outcome:
    """What became of a command: done or refused (``reason``), and its request id."""

    ok: bool
    reason: str = ""
    request_id: str = ""
    duplicate: bool = False


class CommandExecutor:
    """Runs verified fleet commands (see the module docstring).

    Args:
        bus, clock: injected.
        service: the tour service (None: tours are not available on this rover).
        store: the tour store that distributed tours are kept in.
        has_dock: a dock is fitted (``dock.enabled``): ``dock`` is accepted.
        zones: the rover's zone service (``ZoneService``; None: zones are off).
        maps: the map library and its host (None, or without a host: ``set_map`` is refused).
        busy: why the rover cannot change its map now (None: it is parked and may).
        home: the rover's home in ``map`` (a pushed map must have free space there).
    """

    def __init__(self, bus: Bus, clock: Clock, service: TourService | None = None,
                 store: TourStore | None = None, *, has_dock: bool = False,
                 zones: Any = None, maps: MapsAccess | None = None,
                 busy: Callable[[], str | None] = lambda: None,
                 home: Callable[[], Pose2D] = Pose2D) -> None:
        self.bus = bus
        self.clock = clock
        self.service = service
        self.store = store
        self.has_dock = has_dock
        self.zones = zones
        self.maps = maps
        self.busy = busy
        self.home = home
        self._recent: OrderedDict[str, Outcome] = OrderedDict()
        self.executed = 0

    def execute(self, v: Verified) -> Outcome:
        """Validate and run ``v``; never raises for bad input (the outcome says why)."""
        cmd = v.cmd
        rid = cmd.get("request_id", "")
        if not isinstance(rid, str) or len(rid) > 64:
            return Outcome(False, "request_id must be text of at most 64 characters")
        if rid and rid in self._recent:
            old = self._recent[rid]
            return Outcome(old.ok, old.reason, rid, duplicate=True)
        action = cmd.get("action")
        if action not in ACTIONS:
            return self._remember(Outcome(False, f"unknown action {action!r}; allowed: "
                                                 f"{', '.join(ACTIONS)}", rid))
        try:
            outcome = self._run(str(action), v, rid)
        except (TourError, ValueError) as exc:
            outcome = Outcome(False, str(exc), rid)
        if outcome.ok:
            self.executed += 1
        return self._remember(outcome)

    def _remember(self, outcome: Outcome) -> Outcome:
        if outcome.request_id:
            self._recent[outcome.request_id] = outcome
            while len(self._recent) > RECENT:
                self._recent.popitem(last=False)
        return outcome

    def _publish(self, action: OperatorAction, v: Verified, rid: str, **kwargs: Any) -> Outcome:
        self.bus.publish(OPERATOR, OperatorCommand(self.clock.now(), action, source=v.source,
                                                   request_id=rid or "", **kwargs))
        return Outcome(True, "", rid)

    def _run(self, action: str, v: Verified, rid: str) -> Outcome:
        cmd = v.cmd
        if action == "goto":
            return self._publish("goto", v, rid, goal=_goal(cmd))
        if action == "start_tour":
            return self._start_tour(v, rid)
        if action == "set_zones":
            return self._set_zones(v, rid)
        if action == "set_map":
            return self._set_map(v, rid)
        if action == "stop_tour":
            if self.service is None:
                return Outcome(False, "this rover has no tour service", rid)
            self.service.stop_tour(source="fleet", actor=v.key)
            return Outcome(True, "", rid)
        if action == "dock" and not self.has_dock:
            return Outcome(False, "this rover has no dock (dock.enabled is off): send go_home "
                                  "to drive it home", rid)
        if action == "release_estop":
            estop = self.bus.latest(ESTOP)
            setter = estop.source if estop is not None else ""
            if not v.may("release_any_estop") and setter not in (v.source, ""):
                return Outcome(False, f"the e-stop was set by {setter or 'someone else'}: only "
                                      "that key or an admin key may release it", rid)
        return self._publish(_PLAIN[action], v, rid)

    def _start_tour(self, v: Verified, rid: str) -> Outcome:
        if self.service is None or self.store is None:
            return Outcome(False, "this rover has no tour service", rid)
        cmd = v.cmd
        tour_id = cmd.get("tour_id")
        if isinstance(tour_id, bool) or not isinstance(tour_id, int | type(None)):
            return Outcome(False, f"tour_id must be a whole number, got {tour_id!r}", rid)
        definition = cmd.get("tour")
        if definition is not None:
            if not v.may("command"):
                return Outcome(False, f"the key {v.key!r} (role {v.role}) may start tours but "
                                      "not send tour definitions", rid)
            tour = tour_from_json(definition)
            if tour_id is not None and tour.id != tour_id:
                return Outcome(False, f"tour_id {tour_id} and the tour sent ({tour.id}) differ",
                               rid)
            self.store.upsert(tour, actor=v.source)
            tour_id = tour.id
        request = self.service.start_tour(tour_id, source="fleet", actor=v.key,
                                          request_id=rid)
        return Outcome(True, "", request)


    def _set_zones(self, v: Verified, rid: str) -> Outcome:
        if self.zones is None:
            return Outcome(False, "this rover keeps no zones (zones.enabled is off)", rid)
        try:
            changed = self.zones.replace(str(v.cmd.get("map", "")), v.cmd.get("zones"),
                                         actor=v.source)
        except ZoneError as exc:
            return Outcome(False, str(exc), rid)
        return Outcome(True, "" if changed else "the zones were already these", rid)

    def _set_map(self, v: Verified, rid: str) -> Outcome:
        maps = self.maps
        if maps is None or maps.control is None:
            return Outcome(False, "this rover cannot take a map from the fleet: only a rover "
                                  "run by `curio run` with maps.enabled keeps a map library",
                           rid)
        name = v.cmd.get("map")
        if name != maps.active:
            return Outcome(False, f"this rover drives on {maps.active!r}, not {name!r}: a "
                                  "rover is moved to another map on its own dashboard", rid)
        grid = decode_pushed_map(v.cmd.get("grid"), v.cmd.get("sha"), maps.active)
        if grid_digest(maps.library.grid(maps.active).data) == v.cmd.get("sha"):
            return Outcome(True, "the map was already this one", rid)
        why = self.busy()
        if why is not None:
            return Outcome(False, f"busy ({why}): the map is taken when the rover is parked",
                           rid)
        home = self.home()
        row, col = grid.world_to_cell(home.x, home.y)
        if not grid.in_bounds(row, col) or not grid.free_mask()[row, col]:
            return Outcome(False, f"the map has no free space at the rover's home "
                                  f"({home.x:.2f}, {home.y:.2f}): not taken", rid)
        try:
            revision = maps.library.save_revision(maps.active, grid)
            maps.control.reload(v.source, f"revision {revision} from the fleet manager")
        except MapLibraryError as exc:
            return Outcome(False, str(exc), rid)
        return Outcome(True, f"kept as revision {revision}; the rover restarts on it", rid)


def _goal(cmd: dict[str, Any]) -> Pose2D:
    values = []
    for key in ("x", "y"):
        value = cmd.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or \
                not math.isfinite(value):
            raise ValueError(f"goto needs a finite number {key} (metres in map), got {value!r}")
        values.append(float(value))
    yaw = cmd.get("yaw")
    if yaw is None:  # as on the dashboard: no heading given means 0
        return Pose2D(values[0], values[1], 0.0)
    if isinstance(yaw, bool) or not isinstance(yaw, int | float) or not math.isfinite(yaw):
        raise ValueError(f"goto's yaw must be a finite number of radians, got {yaw!r}")
    return Pose2D(values[0], values[1], float(yaw))
