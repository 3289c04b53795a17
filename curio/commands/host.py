"""``curio run``'s host: the App on the active map of the library, rebuilt in-process to switch
maps, to start and end a mapping run, and to use a saved edit of the active map.

Why a rebuild and not a swap inside the running parts: the map reaches the map server, the
localiser's likelihood field, the costmap's static layer, the planner, the zones' masks, the
tours' placement, the people tracker, the clearance probe, the dock drawn at home and (in the
simulator) the simulated building — and the paths, tours and schedules belong to the map too.
Building a new App from the new map's configuration (:func:`curio.maps.control.config_for`)
changes all of them at once through the same code that builds them at start-up, and nothing
keeps a stale reference. The cost: about a second without the dashboard (the page reconnects
by itself) and a new flight-recorder file. docs/maps.md has the details.

A change is asked for by a dashboard handler (:class:`~curio.maps.control.MapControl`),
checked at once (refused while a tour runs or while another change is under way), and done
by :meth:`MapHost.serve` after the answer has gone out: the tree is cancelled and zero
velocities go through the safety stage until the rover stands still (at most
``maps.stop_timeout_s``), the App stops (its own halt: zero velocity, the base halted), the
library changes, the new App starts. After a switch the rover's pose is not known on the new
map: ``last_pose.json`` is removed (it was on the old map), the rover starts at the new map's
home, and ``pose_needed`` stays set until somebody relocalises or sets the pose.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from curio.app import App
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Event, OperatorCommand, Twist
from curio.core.parts import Part
from curio.core.topics import (
    CMD_VEL,
    CMD_VEL_NAV,
    CMD_VEL_TELEOP,
    EVENTS,
    INITIAL_POSE,
    OPERATOR,
    TOUR,
)
from curio.estimation.last_pose import LAST_POSE_FILE
from curio.estimation.maps import load_map
from curio.estimation.wiring import map_path
from curio.maps.control import MAPPING_SCRATCH, MapsAccess, config_for
from curio.maps.library import MapLibrary, MapLibraryError, check_floor, check_name

__all__ = ["MapHost", "MapsBusy"]

log = logging.getLogger("curio.maps.host")


class MapsBusy(MapLibraryError):
    """Refused because the rover is busy (a tour, another change): HTTP 409."""

    busy = True


@dataclass(frozen=True)
class _Change:
    kind: str  # switch | reload | start_mapping | save_mapping | discard_mapping
    actor: str
    name: str = ""
    floor: str = ""


class MapHost:
    """Owns the App of the active map and rebuilds it on request (module docstring).

    Args:
        cfg: the configuration as loaded (its map only seeds the library on the first start).
        clock: the injected clock (shared by every App it builds).
        web: serve the dashboard (None: ``web.enabled``).
    """

    def __init__(self, cfg: Config, clock: Clock, web: bool | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.web = web
        self.library = MapLibrary(cfg.data_path(cfg.maps.directory),
                                  cfg.data_path(cfg.zones.directory), clock.wall_time)
        configured = Path(map_path(cfg))
        self.library.seed(configured, cfg.maps.default_floor)
        if configured.stem != self.active and not self.library.exists(configured.stem):
            log.info("maps: the configured map %s is not in the library (the active map is %s);"
                     " add it on the dashboard's Maps page to use it", configured, self.active)
        self.app: App | None = None
        self.mapping = False
        self.pose_needed = False
        self.message = ""
        self._pending: _Change | None = None
        self._working = False
        self._wake: asyncio.Event | None = None
        self._port: int | None = None
        self.generation = 0  # Apps built so far
        # Before the last swap: seconds until the safety stage commanded zero (None: it did
        # not within maps.stop_timeout_s, and stopping the App halted the base).
        self.stand_still_s: float | None = None

    # --- building ----------------------------------------------------------------------------

    @property
    def active(self) -> str:
        """The active map's name."""
        name = self.library.active
        assert name is not None  # seeded in __init__
        return name

    def build(self) -> App:
        """The App for the active map (a mapping run's while mapping)."""
        cfg = config_for(self.cfg, self.library, self.active, mapping=self.mapping,
                         web_port=self._port)
        app = App(cfg, self.clock, web=self.web,
                  maps=MapsAccess(self.library, self, self.active))
        app.add(Part("maps.pose_watch", run=lambda: self._watch_pose(app)))
        return app

    async def start(self) -> App:
        """Build and start the App of the active map."""
        if self._wake is None:
            self._wake = asyncio.Event()
        app = self.build()
        await app.start()
        self.app = app
        self.generation += 1
        if app.web is not None:
            self._port = app.web.port  # the next App listens where the pages reconnect
        return app

    async def serve(self, stop: asyncio.Event) -> None:
        """Carry out the asked changes until ``stop`` is set (then stop the App)."""
        assert self._wake is not None, "start() first"
        stopper = asyncio.create_task(stop.wait())
        try:
            while not stop.is_set():
                waker = asyncio.create_task(self._wake.wait())
                await asyncio.wait({stopper, waker}, return_when=asyncio.FIRST_COMPLETED)
                waker.cancel()
                self._wake.clear()
                change, self._pending = self._pending, None
                if change is not None and not stop.is_set():
                    await self.apply(change)
        finally:
            stopper.cancel()

    async def stop(self) -> None:
        """Stop the current App."""
        if self.app is not None:
            await self.app.stop()

    # --- MapControl ----------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """For the page: the active map, a mapping run, a change under way, the pose."""
        return {"active": self.active, "mapping": self.mapping,
                "switching": self._pending is not None or self._working,
                "pose_needed": self.pose_needed, "message": self.message,
                "busy": self._busy(), "generation": self.generation}

    def switch(self, name: str, actor: str) -> str:
        """Ask for a switch to ``name``."""
        self.library.map_yaml(check_name(name))  # refused when there is no such map
        if name == self.active:
            raise MapLibraryError(f"map {name!r} is already the active map")
        self._ask(_Change("switch", actor, name=name))
        return (f"Switching to {name}: the rover stops, then set its pose on the new map "
                "(relocalise or set pose).")

    def reload(self, actor: str, why: str) -> str:
        """Ask for the App to be rebuilt on the same map."""
        self._ask(_Change("reload", actor, name=self.active))
        return "The rover stops while the map is reloaded."

    def start_mapping(self, actor: str) -> str:
        """Ask for a mapping run."""
        self._ask(_Change("start_mapping", actor))
        return ("Mapping starts in a moment: drive the rover slowly with teleop (the "
                "dashboard's joystick); the map grows here.")

    def finish_mapping(self, name: str, floor: str, actor: str, save: bool) -> str:
        """Ask to end the mapping run (with ``save``: as the new map ``name``)."""
        if not self.mapping:
            raise MapsBusy("no mapping run is under way")
        if save:
            check_name(name)
            floor = check_floor(floor)
            if self.library.exists(name):
                raise MapLibraryError(f"map name {name!r} is taken: choose another name")
            mapper = self.app.localizer if self.app is not None else None
            if mapper is None or not getattr(getattr(mapper, "mapper", None), "keyframes", []):
                raise MapLibraryError("nothing has been mapped yet: drive the rover a few "
                                      "metres first")
        self._ask(_Change("save_mapping" if save else "discard_mapping", actor, name=name,
                          floor=floor))
        return (f"Saving the map as {name}; the rover returns to {self.active}." if save else
                f"Mapping discarded; the rover returns to {self.active}.")

    def _busy(self, kind: str = "") -> str | None:
        """Why a change of ``kind`` cannot be done now (None: it can)."""
        if self._pending is not None or self._working:
            return "another map change is under way; wait a moment"
        if self.mapping and kind not in ("save_mapping", "discard_mapping"):
            return "a mapping run is under way: save or discard it first"
        tour = self.app.bus.latest(TOUR) if self.app is not None else None
        if tour is not None and tour.tour_id is not None:
            return (f"the tour {tour.name!r} is running: stop the tour first (maps cannot "
                    "change under a running tour)")
        return None

    def _ask(self, change: _Change) -> None:
        busy = self._busy(change.kind)
        if busy is not None:
            raise MapsBusy(busy)
        self._pending = change
        if self._wake is not None:
            self._wake.set()

    # --- doing -------------------------------------------------------------------------------

    async def apply(self, change: _Change) -> None:
        """Stop the rover and the App, change the library, start the new App."""
        self._working = True
        try:
            old = self.app
            assert old is not None
            await self._stand_still(old, change)
            await old.stop()
            before = (self.active, self.mapping, self.pose_needed)
            self.message = self._change_library(change)
            try:
                app = await self.start()
            except Exception as exc:  # the new map cannot run: back to the one that did
                log.error("maps: %s failed: %s; back on %s", change.kind, exc, before[0])
                self.library.set_active(before[0])
                self.mapping, self.pose_needed = before[1], before[2]
                self.message = (f"The change was NOT made: the rover cannot run on that map "
                                f"({exc}); it is back on {before[0]}.")
                app = await self.start()
            self._event(app, change)
        finally:
            self._working = False

    def _change_library(self, change: _Change) -> str:
        data = self.cfg.resolve(self.cfg.data_dir)
        if change.kind == "switch":
            self.mapping = False
            self.library.set_active(change.name)
            (data / LAST_POSE_FILE).unlink(missing_ok=True)  # a pose on the old map
            self.pose_needed = True
            return f"Now on {change.name}: set the rover's pose on this map."
        if change.kind == "start_mapping":
            (self.library.root / MAPPING_SCRATCH).unlink(missing_ok=True)
            self.mapping = True
            return "Mapping: drive the rover with teleop."
        if change.kind in ("save_mapping", "discard_mapping"):
            self.mapping = False
            if change.kind == "discard_mapping":
                return "Mapping discarded."
            try:
                grid = load_map(self.library.root / MAPPING_SCRATCH)
                self.library.add(change.name, grid, change.floor, "mapping",
                                 world_from=self.library.world_yaml(self.active))
            except (MapLibraryError, ValueError) as exc:
                return f"The map was NOT saved: {exc}"
            return f"Saved the new map {change.name} (switch to it to use it)."
        return f"Reloaded {self.active}."

    async def _stand_still(self, app: App, change: _Change) -> None:
        """Cancel the tree and send zero velocities through the safety stage until the base
        is commanded zero (at most ``maps.stop_timeout_s``)."""
        bus, clock = app.bus, self.clock
        bus.publish(OPERATOR, OperatorCommand(clock.now(), "cancel", source="maps",
                                              request_id=f"maps-{change.kind}"))
        start = clock.now()
        deadline = start + self.cfg.maps.stop_timeout_s
        with contextlib.suppress(Exception):
            async for t in clock.every(0.05):
                for topic in (CMD_VEL_NAV, CMD_VEL_TELEOP):
                    bus.publish(topic, Twist(t, 0.0, 0.0, source="maps"))
                out = bus.latest(CMD_VEL)
                still = out is None or (out.linear_mps == 0.0 and out.angular_radps == 0.0)
                if still and t >= start + 0.3:
                    self.stand_still_s = t - start
                    break
                if t >= deadline:
                    self.stand_still_s = None
                    log.warning("maps: the rover was still commanded to move after %.1f s; "
                                "stopping the App halts it", self.cfg.maps.stop_timeout_s)
                    break

    def _event(self, app: App, change: _Change) -> None:
        detail = {"change": change.kind, "map": change.name or self.active,
                  "by": change.actor, "message": self.message}
        app.bus.publish(EVENTS, Event(self.clock.now(), f"maps.{change.kind}", detail))

    async def _watch_pose(self, app: App) -> None:
        """Clear ``pose_needed`` when somebody relocalises or sets the pose."""
        sub = app.bus.subscribe(INITIAL_POSE, maxsize=4)
        try:
            async for _ in sub:
                self.pose_needed = False
        finally:
            sub.close()
