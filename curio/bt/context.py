"""What every behaviour of a tree shares: the context, the blackboard keys, the base class.

Every behaviour reads and writes the blackboard through its own py_trees client with declared
READ/WRITE keys, in the tree's namespace (two trees in one process never share keys). None of
them awaits: actions start navigator goals through the :class:`~curio.bt.follower.PathFollower`
and poll the goal handles on later ticks (py_trees issue #420's advice).

The behaviours themselves are grouped by role: :mod:`curio.bt.feeds` (bus → blackboard),
:mod:`curio.bt.guards` (conditions) and :mod:`curio.bt.actions` (what the priorities do).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Access

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import BtConfig
from curio.nav.api import GoalHandle

from .follower import PathFollower, Route, StatusSink
from .paths import HOME_PATH_ID, PathManager
from .probe import WayProbe

__all__ = ["BB_DEFAULTS", "CurioBehaviour", "TreeContext"]

log = logging.getLogger("curio.bt")

# Every blackboard key with its initial value (original-system.md §2.3, fixed: ``blocked``
# replaces the inverted ``pathclear`` and starts False, §9.1–9.2).
BB_DEFAULTS: dict[str, Any] = {
    "command": None,          # pending select_path / cancel / start_tour / stop_tour (a dict)
    "home_request": None,     # pending Go Home press (a dict) or None
    "pause_request": None,    # pending pause / resume (a dict) or None
    "paused": False,          # the tree is paused (owned by Pause; set by HoldEStop on release)
    "estop": False,           # e-stop engaged (ESTOP topic or an operator estop)
    "blocked": False,         # BLOCKED says: obstacle ahead and no progress
    "blocked_stamp": None,    # clock time of the BLOCKED message, seconds
    "obstacle_distance_m": None,
    "help_active": False,     # a help request is open (HELP ME shown)
    "help_done": None,        # pending operator "help done" (a dict) or None
    "help_rearm_until": None,  # clock time before which BLOCKED is ignored (or None)
    "battery_v": None,        # latest supply voltage, volts
    "battery_low": False,     # low with hysteresis (low < low_battery_v, ok >= battery_ok_v)
    "battery_home_pending": False,  # a low-battery go-home not yet started
    "battery_critical": False,  # below critical_battery_v until battery_ok_v (stop, ask help)
    "dock_request": None,     # docking asked for (a dict with "reason": battery / home)
    "docked": False,          # the docker says the rover is on its dock
    "charging": False,        # ... and the charger's voltage is on the contacts
    "lost": False,            # localisation lost (confirmed; curio/bt/unattended.py)
    "lost_hint": None,        # after a jump: (x, y, yaw) where the rover was, moved by odometry
    "relocalising": False,    # the rover turns in place to relocalise
    "curr_path": None,        # route id being followed (0 = Home, -1 = tour) or None
    "waypoint": 0,            # index of the current waypoint (the original's goal_cnt)
    "phase": "idle",          # follower phase: idle/moving/dwelling/held/finished/failed/...
    "goal_state": "",         # state of the last goal sent (pending/active/succeeded/...)
}


@dataclass
class TreeContext:
    """What every behaviour of one tree shares (constructor injection, no globals).

    Attributes:
        cfg: the ``[bt]`` config section.
        bus, clock: the application's bus and clock.
        navigator: the navigator (curio/nav/api.py) or None when navigation is not running.
        probe: tells whether a path leads to the held waypoint again (None: judge by BLOCKED).
        paths: the path manager.
        follower: drives the current route.
        sink: publishes status, progress and events.
        namespace: blackboard namespace of this tree (``/curio_<n>``).
        tree_kind: ``follow_path``, ``two_step`` or ``tour``.
        tour_route: the configured tour as a route (None when no stops are configured).
        docker: docks and undocks the rover (None without a dock).
        lost: the lost episode being reported (:func:`curio.bt.unattended.lost_report`).
    """

    cfg: BtConfig
    bus: Bus
    clock: Clock
    navigator: Any
    paths: PathManager
    follower: PathFollower
    sink: StatusSink
    namespace: str
    tree_kind: str = "follow_path"
    tour_route: Route | None = None
    probe: WayProbe | None = None
    clients: list[py_trees.blackboard.Client] = field(default_factory=list)
    docker: Any = None  # curio/docking/docker.py (None: no dock, Go Home drives path 0)
    lost: Any = None  # curio/bt/unattended.py LostReport: one lost episode, shared by branches

    def key(self, name: str) -> str:
        """The absolute blackboard key of ``name`` in this tree's namespace."""
        return f"{self.namespace}/{name}"

    def accept(self, req: dict[str, Any] | None, action: str, message: str) -> None:
        """Tell the operator a command was carried out."""
        req = req or {}
        self.sink.event("bt.command_accepted", action=action, message=message,
                        request_id=req.get("request_id", ""), source=req.get("source", ""))

    def reject(self, req: dict[str, Any] | None, action: str, message: str) -> None:
        """Tell the operator a command was refused, and why."""
        req = req or {}
        log.info("command %s rejected: %s", action, message)
        self.sink.event("bt.command_rejected", action=action, message=message,
                        request_id=req.get("request_id", ""), source=req.get("source", ""))

    def home_route(self) -> Route:
        """Path 0 as a route."""
        return Route.from_path(self.paths.get(HOME_PATH_ID))

    def cancel_foreign_goal(self) -> GoalHandle | None:
        """Cancel a navigator goal that the tree did not send (paused or e-stopped)."""
        nav = self.navigator
        if nav is None:
            return None
        active = nav.active
        if active is not None and not active.done and not self.follower.owns(active):
            nav.cancel()
            return active  # type: ignore[no-any-return]
        return None


class CurioBehaviour(py_trees.behaviour.Behaviour):
    """Base: a blackboard client in the tree's namespace with declared keys.

    Args:
        name: the node's name (shown in snapshots).
        ctx: the tree's shared context.
        read: keys this behaviour reads.
        write: keys this behaviour writes (and may read).
    """

    def __init__(self, name: str, ctx: TreeContext, read: tuple[str, ...] = (),
                 write: tuple[str, ...] = ()) -> None:
        super().__init__(name)
        self.ctx = ctx
        self.bb = self.attach_blackboard_client(name=name, namespace=ctx.namespace)
        ctx.clients.append(self.bb)
        for key in read:
            self.bb.register_key(key=key, access=Access.READ)
        for key in write:
            self.bb.register_key(key=key, access=Access.WRITE)

    def get(self, key: str) -> Any:
        """Read a declared key."""
        return self.bb.get(key)

    def set(self, key: str, value: Any) -> None:
        """Write a declared key."""
        self.bb.set(key, value, overwrite=True)

    def take(self, key: str) -> Any:
        """Read a declared request key and clear it (set it to None): the request is consumed."""
        value = self.get(key)
        self.set(key, None)
        return value
