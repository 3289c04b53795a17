"""The zone service: the zones of the navigation map, applied to the costmap, the controller
and the safety stage, and what the dashboard and the CLI call.

:class:`ZoneService` owns the :class:`~curio.zones.store.ZoneStore` of the map and, after
every change (and at start-up):

* makes the keep-out zones, grown by ``zones.keepout_margin_m``, lethal in the costmap
  (:meth:`curio.nav.costmap.Costmap.set_keepout`): the planner never plans through them, the
  controller's footprint check never drives into them;
* gives the controller the speed limit of the speed zones (``LocalController.speed_limits``)
  and the safety stage the keep-out check and the speed limit (``SafetyStage.zone_guard``),
  both through one :class:`~curio.zones.guard.ZoneGuard`;
* publishes the zones on ``/zones`` (latched; ``detail``: ``map``, ``revision``, ``zones``)
  and an event ``zones.changed`` (``change``, ``zone_id``, ``actor``).

Edits are checked against where the rover stands: a keep-out zone over the rover, or over its
home (the dock), is refused with the reason (the planner could not start or end there).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event
from curio.core.topics import EVENTS, POSE, ZONES
from curio.estimation.maps import OccupancyGrid

from .geometry import polygons_overlap
from .guard import ZoneGuard
from .masks import export_nav2_masks, keepout_mask
from .model import Zone, ZoneError, make_zone
from .store import ZoneStore

__all__ = ["ZoneService"]

log = logging.getLogger("curio.zones")


class ZoneService:
    """See the module docstring.

    Args:
        cfg: the whole configuration (``[zones]``, the robot's top speed).
        bus, clock: injected.
        store: the zones of the map.
        grid: the navigation map (the geometry of the masks).
        guard: the controller's and the safety stage's view of the zones.
        costmap: has ``set_keepout(mask)``, ``resolution_m``, ``origin``, ``shape`` (None:
            no costmap, e.g. in tests).
        home: returns the home (dock) pose in ``map`` (None: not checked).
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock, store: ZoneStore,
                 grid: OccupancyGrid, guard: ZoneGuard, costmap: Any = None,
                 home: Callable[[], Pose2D] | None = None) -> None:
        self.cfg = cfg
        self.bus = bus
        self.clock = clock
        self.store = store
        self.grid = grid
        self.guard = guard
        self.costmap = costmap
        self.home = home
        self.apply()

    # --- reading ------------------------------------------------------------------------------
    def list_zones(self) -> dict[str, Any]:
        """``{map, revision, zones}`` for the dashboard."""
        return {"map": self.store.map_name, "revision": self.store.revision,
                "zones": [z.to_json() for z in self.store.list_zones()]}

    # --- editing ------------------------------------------------------------------------------
    def add(self, body: dict[str, Any], actor: str = "") -> Zone:
        """Create a zone from ``{name, kind, polygon, speed_limit_mps?, revision?}``."""
        draft = make_zone(0, body.get("name"), body.get("kind"), body.get("polygon"),
                          body.get("speed_limit_mps"), self.store.max_speed_mps)
        self._check_placement(draft)
        zone = self.store.add(draft.name, draft.kind, list(draft.polygon),
                              draft.speed_limit_mps, expect_revision=body.get("revision"))
        self._changed("added", zone.id, actor)
        return zone

    def update(self, zone_id: int, body: dict[str, Any], actor: str = "") -> Zone:
        """Change a zone's ``name``, ``kind``, ``polygon``, ``speed_limit_mps``."""
        fields: dict[str, Any] = {k: body[k] for k in ("name", "kind", "polygon",
                                                       "speed_limit_mps") if k in body}
        merged: dict[str, Any] = {**self.store.get(zone_id).to_json(), **fields}
        if merged["kind"] == "keepout" and "speed_limit_mps" not in fields:
            merged["speed_limit_mps"] = None
        self._check_placement(make_zone(zone_id, merged["name"], merged["kind"],
                                        merged["polygon"], merged["speed_limit_mps"],
                                        self.store.max_speed_mps))
        zone = self.store.update(zone_id, expect_revision=body.get("revision"), **fields)
        self._changed("updated", zone_id, actor)
        return zone

    def delete(self, zone_id: int, revision: int | None = None, actor: str = "") -> None:
        """Delete a zone."""
        self.store.delete(zone_id, expect_revision=revision)
        self._changed("deleted", zone_id, actor)

    def replace(self, map_name: str, zones: Any, actor: str = "") -> bool:
        """Take a whole set of zones for ``map_name`` (a fleet manager's copy): every zone is
        checked as an edit would be (a keep-out over the rover or its dock refuses the set);
        return False when they equal the zones there are (nothing changes).

        Raises:
            ZoneError: another map's zones, or a bad zone (nothing changes).
        """
        if map_name != self.store.map_name:
            raise ZoneError(f"the zones are for the map {map_name!r}; this rover drives on "
                            f"{self.store.map_name!r}")
        if not isinstance(zones, list):
            raise ZoneError("zones must be a list of zones")
        new = [Zone.from_json(z, self.store.max_speed_mps) for z in zones]
        if [z.to_json() for z in new] == [z.to_json() for z in self.store.list_zones()]:
            return False
        for zone in new:
            self._check_placement(zone)
        self.store.replace_all(new)
        self._changed("replaced", 0, actor)
        return True

    def export(self, out_dir: Path | None = None) -> list[Path]:
        """Write the Nav2 filter masks (default: beside the zone file); return the files."""
        return export_nav2_masks(self.store.list_zones(), self.grid,
                                 out_dir or self.store.path.parent, self.store.map_name)

    # --- applying -----------------------------------------------------------------------------
    def apply(self) -> None:
        """Push the zones to the costmap, the controller and the safety stage; publish them."""
        zones = self.store.list_zones()
        self.guard.set_zones(zones)
        cm = self.costmap
        if cm is not None:
            cm.set_keepout(keepout_mask(zones, cm.resolution_m, cm.origin, cm.shape,
                                        self.cfg.zones.keepout_margin_m))
        self.bus.publish(ZONES, Event(self.clock.now(), "zones", self.list_zones()))

    def _changed(self, change: str, zone_id: int, actor: str) -> None:
        self.apply()
        self.bus.publish(EVENTS, Event(self.clock.now(), "zones.changed", {
            "change": change, "zone_id": zone_id, "actor": actor,
            "map": self.store.map_name}))

    def _check_placement(self, zone: Zone) -> None:
        if zone.kind != "keepout":
            return
        pose_msg = self.bus.latest(POSE)
        if pose_msg is not None and self._covers(zone, pose_msg.pose):
            raise ZoneError("the keep-out zone covers the rover where it stands; drive it out "
                            "of that area first, or draw the zone elsewhere")
        home = self.home() if self.home is not None else None
        if home is not None and self._covers(zone, home):
            raise ZoneError(f"the keep-out zone covers the rover's home and dock at "
                            f"({home.x:.2f}, {home.y:.2f}); move the zone or the home")

    def _covers(self, zone: Zone, pose: Pose2D) -> bool:
        return polygons_overlap(self.guard.footprint_at(pose), zone.vertices())
