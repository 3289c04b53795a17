"""Behaviour wiring: the path manager and the configured tree's runner, as a part.

``build_behaviour`` runs after navigation is built: the tree drives the navigator, and its help
request asks the way probe (the planner on the live costmap) whether the way is clear.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from curio.bt.paths import PathManager
from curio.bt.probe import WayProbe
from curio.bt.runner import TreeRunner, build_tree_runner
from curio.bt.speech import Speaker
from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import Event
from curio.core.parts import Part, Parts
from curio.core.topics import EVENTS
from curio.nav.wiring import Navigation
from curio.tours.store import TourStore

__all__ = ["Behaviour", "build_behaviour"]


@dataclass(frozen=True)
class Behaviour:
    """The behaviour subsystem's objects."""

    paths: PathManager
    tree: TreeRunner


def build_behaviour(cfg: Config, bus: Bus, clock: Clock, parts: Parts,
                    nav: Navigation, paths: PathManager | None = None,
                    tours: TourStore | None = None, docker: Any = None,
                    probe: Any = None) -> Behaviour:
    """Construct the path manager (unless given) and the configured tree; register the tree
    as a part. With ``tours`` the tour tree runs the tours of the tour store; with ``docker``
    Go Home and low battery dock the rover; ``probe`` judges "the way is clear" while asking
    for help (default: a :class:`WayProbe` on the live costmap)."""
    paths = paths or PathManager(cfg.bt.paths, cfg.data_path(cfg.bt.paths_file))

    def on_paths_changed(what: str, path_id: int) -> None:
        bus.publish(EVENTS, Event(clock.now(), "paths.changed",
                                  {"change": what, "path_id": path_id}))

    paths.add_listener(on_paths_changed)
    speaker = Speaker(enabled=cfg.bt.speak)
    probe = probe if probe is not None else WayProbe(nav.planner, nav.costmap, bus, clock)
    runner = build_tree_runner(cfg.bt, bus, clock, nav.navigator, paths, speaker, probe=probe,
                               tours=tours, tours_cfg=cfg.tours, docker=docker)

    async def close() -> None:
        await runner.close()
        await speaker.close()

    parts.add(Part("behaviour", run=runner.run, close=close))
    return Behaviour(paths, runner)
