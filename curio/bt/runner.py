"""The tick runner: ticks a tree at ``cfg.bt.tick_hz`` on the injected clock, publishes snapshots.

``TreeRunner.run`` is the Part's coroutine: ``async for _ in clock.every(1 / tick_hz)`` it
ticks the tree once (a tick never awaits), mirrors the follower on the blackboard and, when a
node's status or a blackboard value changed, publishes a :class:`~curio.core.messages.TreeSnapshot`
on TREE. About once a second it publishes its health (``/health``, name ``behaviour``: ticks,
overruns), so the dashboard can tell a ticking tree from a stuck one. ``close()`` interrupts
the tree (every running behaviour gets ``terminate(INVALID)``, which cancels its goal)
and unregisters the blackboard clients.

py_trees' own ``BehaviourTree.tick_tock`` sleeps on the wall clock and its ``setup`` uses
signals and a timer thread, so neither is used: setting up a Curio behaviour only registers
blackboard keys (dependencies come through the constructor) and cannot block.
"""

from __future__ import annotations

import logging
from typing import Any

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from curio.core.bus import Bus
from curio.core.clock import Clock, RateStats
from curio.core.config import BtConfig, ToursConfig
from curio.core.jsonable import to_jsonable
from curio.core.messages import DriverHealth, Event, OperatorCommand, TreeSnapshot
from curio.core.topics import EVENTS, HEALTH, TREE
from curio.tours.store import TourStore

from .context import BB_DEFAULTS, TreeContext
from .feeds import Follower2BB, Operator2BB
from .follower import PathFollower, StatusSink
from .paths import PathManager
from .probe import WayProbe
from .speech import Speaker
from .tour_feed import Tours2BB, tour_route
from .trees import build_root, tour_route_from_config

__all__ = ["TreeRunner", "build_tree_runner"]

log = logging.getLogger("curio.bt.runner")

def _preorder(root: Behaviour) -> list[Behaviour]:
    """Every node, parents before children, left to right (snapshot ids follow this order)."""
    out: list[Behaviour] = []
    stack = [root]
    while stack:
        node = stack.pop()
        out.append(node)
        stack.extend(reversed(node.children))
    return out


class TreeRunner:
    """Ticks one tree; exposes :meth:`tick` (tests, benchmarks) and :meth:`snapshot`.

    Args:
        root: the tree.
        ctx: its shared context.
        operator_feed: the OPERATOR feed inside the tree (for autostart and close).
        tick_hz: ticks per second (the original: 2).
    """

    def __init__(self, root: Behaviour, ctx: TreeContext, operator_feed: Operator2BB,
                 tick_hz: float) -> None:
        if tick_hz <= 0:
            raise ValueError(f"tick_hz must be > 0, got {tick_hz}")
        self.root = root
        self.ctx = ctx
        self.operator_feed = operator_feed
        self.period_s = 1.0 / tick_hz
        self.tick_count = 0
        self.snapshots_published = 0
        self.rate = RateStats()  # ticks, overruns, worst lateness
        self._nodes = _preorder(root)
        self._ids = {node.id: i for i, node in enumerate(self._nodes)}
        self._last_signature: tuple[Any, ...] | None = None
        self._last_snapshot: TreeSnapshot | None = None
        self._mirror = Follower2BB(ctx, name="Runner")
        self._closed = False
        for node in self._nodes:
            node.setup()

    @property
    def overruns(self) -> int:
        """Ticks that started more than a period late (the missed ones were skipped)."""
        return self.rate.overruns

    # --- ticking ----------------------------------------------------------------------------

    def tick(self) -> TreeSnapshot | None:
        """Tick the tree once; return the snapshot if it was published (something changed)."""
        self.root.tick_once()
        self.tick_count += 1
        self._mirror.refresh()
        return self._publish_if_changed()

    async def run(self) -> None:
        """Tick at the configured rate on the injected clock until cancelled."""
        self.ctx.sink.status("Idle", "idle")
        warning = self.ctx.paths.load_warning
        if warning:
            self.ctx.bus.publish(EVENTS, Event(self.ctx.clock.now(), "paths.load_failed",
                                               {"message": warning}))
        # An overrun skips the missed ticks instead of bursting (counted in ``rate``).
        next_health = self.ctx.clock.now()
        async for now in self.ctx.clock.every(self.period_s, self.rate):
            self.tick()
            if now >= next_health:  # liveness for the dashboard's health panel, ~1 Hz
                next_health = now + 1.0
                self.ctx.bus.publish(HEALTH, self.health())

    def health(self) -> DriverHealth:
        """The runner's health (name ``behaviour``): ticks, overruns and snapshots so far."""
        return DriverHealth(self.ctx.clock.now(), "behaviour", "ok",
                            f"ticking at {1.0 / self.period_s:g} Hz",
                            counters={"ticks": float(self.tick_count),
                                      "overruns": float(self.overruns),
                                      "snapshots": float(self.snapshots_published)})

    def inject(self, cmd: OperatorCommand) -> None:
        """Hand a command to the tree as if it came from OPERATOR (next tick)."""
        self.operator_feed.inject(cmd)

    async def close(self) -> None:
        """Interrupt the tree (cancel goals) and release the blackboard."""
        if self._closed:
            return
        self._closed = True
        self.root.stop(Status.INVALID)
        self.ctx.follower.stop()
        self.operator_feed.close()
        for node in self._nodes:
            if isinstance(node, Tours2BB):
                node.close()
        clients = {id(c): c for c in self.ctx.clients}
        for node in self._nodes:
            clients.update((id(c), c) for c in node.blackboards)
        for client in clients.values():
            client.unregister(clear=True)

    # --- snapshots --------------------------------------------------------------------------

    def blackboard(self) -> dict[str, Any]:
        """This tree's blackboard, keys without the namespace, values JSON-safe."""
        prefix = self.ctx.namespace + "/"
        storage = py_trees.blackboard.Blackboard.storage
        return {key[len(prefix):]: to_jsonable(value, 4) for key, value in sorted(storage.items())
                if key.startswith(prefix)}

    def _node_dicts(self) -> tuple[dict[str, Any], ...]:
        out = []
        for node in self._nodes:
            parent = node.parent
            out.append({
                "id": self._ids[node.id],
                "name": node.name,
                "type": type(node).__name__,
                "status": node.status.value,
                "parent": self._ids[parent.id] if parent is not None else None,
                "children": [self._ids[c.id] for c in node.children],
            })
        return tuple(out)

    def _signature(self, blackboard: dict[str, Any]) -> tuple[Any, ...]:
        return (tuple(node.status for node in self._nodes), repr(blackboard))

    def _publish_if_changed(self) -> TreeSnapshot | None:
        blackboard = self.blackboard()
        signature = self._signature(blackboard)
        if signature == self._last_signature:
            return None
        self._last_signature = signature
        snap = TreeSnapshot(self.ctx.clock.now(), self.tick_count, self._node_dicts(),
                            blackboard)
        self._last_snapshot = snap
        self.snapshots_published += 1
        self.ctx.bus.publish(TREE, snap)
        return snap

    def snapshot(self) -> TreeSnapshot:
        """The latest snapshot (built now if nothing was published yet)."""
        if self._last_snapshot is None:
            return TreeSnapshot(self.ctx.clock.now(), self.tick_count, self._node_dicts(),
                                self.blackboard())
        return self._last_snapshot

    def ascii(self) -> str:
        """The tree with statuses, as text (py_trees' unicode renderer)."""
        return str(py_trees.display.unicode_tree(self.root, show_status=True))


def build_tree_runner(
    cfg: BtConfig,
    bus: Bus,
    clock: Clock,
    navigator: Any,
    paths: PathManager,
    speaker: Speaker | None = None,
    *,
    autostart_path: int | None = None,
    probe: WayProbe | None = None,
    tours: TourStore | None = None,
    tours_cfg: ToursConfig | None = None,
    docker: Any = None,
) -> TreeRunner:
    """Build the configured tree (``cfg.tree``) and its runner.

    Args:
        cfg: the ``[bt]`` section.
        bus, clock: the application's.
        navigator: the navigator (curio/nav/api.py), or None.
        paths: the path manager.
        speaker: speaks tour messages (None: silent).
        probe: judges "the way is clear" while asking for help (None: by BLOCKED).
        autostart_path: a path to select at the first tick (``cfg.autostart_path``); the
            original drove path 1 at launch unasked (§9.16), Curio only when configured.
        tours: the tour store: the tour tree's ``start_tour`` runs the tour it names (None: the
            configured ``bt.tour_stops``).
        tours_cfg: ``[tours]`` (defaults when None).
        docker: docks the rover (``curio/docking/docker.py``; None: no dock).
    """
    sink = StatusSink(bus, clock)
    follower = PathFollower(navigator, sink, clock,
                            speak=speaker.say if speaker is not None else None)
    ctx = TreeContext(cfg=cfg, bus=bus, clock=clock, navigator=navigator, paths=paths,
                      follower=follower, sink=sink, namespace=f"/curio_{id(follower):x}",
                      tree_kind=cfg.tree, tour_route=tour_route_from_config(cfg),
                      probe=probe, docker=docker)
    init = py_trees.blackboard.Client(name="Init", namespace=ctx.namespace)
    ctx.clients.append(init)
    for key, value in BB_DEFAULTS.items():
        init.register_key(key=key, access=py_trees.common.Access.WRITE)
        init.set(key, value, overwrite=True)
    operator_feed = Operator2BB(ctx)
    tour_feed = None
    if tours is not None and cfg.tree == "tour":
        tour_feed = Tours2BB(ctx, tours, tours_cfg or ToursConfig(), speaker)
        first = tours.first()
        ctx.tour_route = tour_route(first, paths) if first is not None and first.stops else None
    root = build_root(ctx, operator_feed, tour_feed)
    runner = TreeRunner(root, ctx, operator_feed, cfg.tick_hz)
    start = cfg.autostart_path if autostart_path is None else autostart_path
    if start is not None:
        runner.inject(OperatorCommand(clock.now(), "select_path", path_id=start,
                                      source="config"))
    return runner
