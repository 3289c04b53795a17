"""Behaviour wiring: the path manager on ``app.paths`` and the tree runner on ``app.tree``.

``build_behaviour(app)`` runs after navigation is built, so ``app.navigator`` is set when the
navigation stack is configured (None otherwise: the tree still runs and answers every command,
and goals fail with "navigation is not running").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from curio.core.clock import SimClock
from curio.core.messages import Event
from curio.core.topics import EVENTS

from .paths import PathManager
from .probe import WayProbe
from .runner import build_tree_runner
from .speech import Speaker

if TYPE_CHECKING:
    from curio.app import App


def build_behaviour(app: App) -> None:
    """Construct the path manager and the configured tree; register the tree as a Part."""
    from curio.app import Part

    cfg = app.cfg
    paths = PathManager(cfg.bt.paths, cfg.data_path(cfg.bt.paths_file))
    app.paths = paths

    def on_paths_changed(what: str, path_id: int) -> None:
        app.bus.publish(EVENTS, Event(app.clock.now(), "paths.changed",
                                      {"change": what, "path_id": path_id}))

    paths.add_listener(on_paths_changed)
    speaker = Speaker(enabled=cfg.bt.speak)
    probe = None
    if app.planner is not None and app.costmap is not None:
        probe = WayProbe(app.planner, app.costmap, app.bus,
                         in_thread=not isinstance(app.clock, SimClock))
    runner = build_tree_runner(cfg.bt, app.bus, app.clock, app.navigator, paths, speaker,
                               probe=probe)
    app.tree = runner

    async def close() -> None:
        await runner.close()
        await speaker.close()

    app.add(Part("behaviour", run=runner.run, close=close))
