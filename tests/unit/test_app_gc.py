"""The App keeps what it built at start out of the cyclic garbage collector's full passes
(``gc.freeze``): on a Pi 4 core a full collection of the ~200 000 objects Curio and numba
create took ~0.4 s, with the safety stage held (docs/benchmarks.md, pi-budget)."""

from __future__ import annotations

import gc

from curio.app import App
from curio.core.clock import SimClock
from curio.core.config import Config


async def test_start_freezes_what_was_built_and_stop_gives_it_back(cfg: Config) -> None:
    gc.unfreeze()
    app = App(cfg, SimClock(), web=False)
    before = len(gc.get_objects())
    await app.start()
    try:
        assert gc.get_freeze_count() >= before // 2, "start must freeze the long-lived objects"
        assert len(gc.get_objects()) < before // 10  # what a full collection still walks
    finally:
        await app.stop()
    # A stopped App (a map switch rebuilds it) must not keep its cycles for ever.
    assert gc.get_freeze_count() == 0
