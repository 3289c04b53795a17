"""End-to-end: the ``/maps`` page on the real App rebuilt by ``curio run``'s host (a real-time
SimClock), in Debian's Chromium on a desktop (1280×800) and a phone (390×844): the library
grouped by floor, the cell editor (a wall painted with the real mouse, undo, redo, saved as a
revision), switching the active map (the confirm box, the pose asked for, Relocalise), and a
mapping run started and discarded from the page. Screenshots in ``artifacts/screenshots/``.
Every wait is for a condition.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from curio.commands.host import MapHost
from curio.core.clock import Clock
from tests.web import browser_kit as kit
from tests.web.maps_kit import hosted

pytestmark = [pytest.mark.browser]


async def _until(clock: Clock, cond: Callable[[], bool], what: str) -> None:
    """Wait for ``cond`` (at most 90 simulated seconds: 30 s of the wall clock)."""
    for _ in range(300):
        if cond():
            return
        await clock.sleep(0.3)
    raise AssertionError(f"timed out waiting for {what}")


def _shown(element_id: str, shown: bool = True) -> str:
    """A condition: the element is shown (or hidden)."""
    hidden = f"document.getElementById('{element_id}').classList.contains('hidden')"
    return hidden if not shown else f"!{hidden}"


async def test_maps_page(tmp_path: Path, viewport: str) -> None:
    cfg = kit.make_cfg(tmp_path / "data", "record.enabled=false")
    token = kit.add_token(cfg, "alice")
    async with hosted(cfg) as (host, base):
        host.library.add("annex", host.library.grid("curio_building"), "First floor", "upload")
        async with kit.chromium() as browser:
            b = await kit.open_page(browser, base + f"/maps?token={token}", viewport,
                                    connected=False)
            await b.wait_js("document.querySelectorAll('.mapCard').length === 2", timeout_s=40)
            floors = await b.state("[...document.querySelectorAll('.floor h2')]"
                                   ".map(h => h.textContent)")
            assert floors == ["First floor", "Ground floor"]
            assert "Active map: curio_building" in await b.text("#mapsState")
            await b.wait_js("window.curio.mapsPage.state() !== null")
            await b.shot("maps-library")
            await _edit_a_wall(b, host)
            # The dashboard, open meanwhile, follows the switch: it reconnects by itself and
            # loads the new map (a new grid version), not the old image.
            dash = await kit.open_page(browser, base + "/", viewport)
            await dash.wait_js("window.curio.S.grids.map && window.curio.S.images.map")
            old_version = await dash.state("window.curio.S.grids.map.version")
            # While the App is rebuilt the server is down for a moment: a refused, reset or
            # unanswered request (a network error, never an HTTP error status).
            b.allowed = dash.allowed = ["Failed to load resource: net::ERR_",
                                        "WebSocket connection"]
            await _switch(b, host)
            await dash.wait_js(f"window.curio.S.connected && window.curio.S.grids.map && "
                               f"window.curio.S.grids.map.version !== {old_version} && "
                               "window.curio.S.images.map", timeout_s=40)
            assert dash.errors == [], dash.errors
            await _edit_the_active_map(b, host)
            await _mapping_run(b, host)
            assert b.errors == [], b.errors


async def _edit_a_wall(b: kit.Browser, host: MapHost) -> None:
    """A wall painted with the real mouse on the annex (not the active map), undone, redone,
    saved as revision 2."""
    page = b.page
    await page.click(".mapCard[data-name=annex] >> text=Edit cells")
    await b.wait_js(_shown("editor") + " && window.curio.mapsPage.editor.grid", timeout_s=40)
    await page.click(".edTools .tool[data-tool='100']")
    box = await page.locator("#edCanvas").bounding_box()
    assert box is not None
    x0, y = box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.5
    await page.mouse.move(x0, y)
    await page.mouse.down()
    await page.mouse.move(x0 + box["width"] * 0.3, y, steps=8)
    await page.mouse.up()
    count = "window.curio.mapsPage.editor.changedCount()"
    changed = await b.state(count)
    assert changed > 20
    await b.shot("maps-editor", "#editor")
    await page.click("#edUndo")
    assert await b.state(count) == 0
    await page.click("#edRedo")
    assert await b.state(count) == changed
    await page.click("#edSave")
    await b.wait_js("document.getElementById('edMsg').textContent.includes('revision 2')",
                    timeout_s=40)
    # Saved means nothing is unsaved, even before the editor reloads the new revision (Close
    # right after the message asked "Close without saving …?" on a slow machine).
    assert await b.state(count) == 0
    assert host.library.revisions("annex") == [1]
    edited = host.library.grid("annex")
    original = host.library.grid("curio_building")
    assert int(np.count_nonzero(edited.data != original.data)) == changed
    await page.click("#edClose")


async def _switch(b: kit.Browser, host: MapHost) -> None:
    """Switch to the annex: the confirm box, the rover rebuilt, the pose asked for."""
    await b.page.click(".mapCard[data-name=annex] >> text=Switch to")
    await b.confirm("Switch the rover to annex", accept=True)
    await _until(host.clock, lambda: host.library.active == "annex" and host.generation == 2,
                 "the switch")
    await b.wait_js(_shown("poseNeeded"), timeout_s=30)
    assert "Active map: annex" in await b.text("#mapsState")
    await b.page.evaluate("() => window.scrollTo(0, 0)")
    await b.shot("maps-pose-needed")
    await b.page.click("#relocalise")
    await b.wait_js(_shown("poseNeeded", False), timeout_s=40)


async def _edit_the_active_map(b: kit.Browser, host: MapHost) -> None:
    """Erase cells of the active map: saved as revision 3, the rover rebuilt on it (the
    localiser's map has the edit), the editor back on the new revision."""
    page = b.page
    await page.click(".mapCard[data-name=annex] >> text=Edit cells")
    await b.wait_js(_shown("editor") + " && window.curio.mapsPage.editor.meta.revision === 2",
                    timeout_s=40)
    assert "saving stops the rover" in await b.text("#edMsg")
    await page.click(".edTools .tool[data-tool='-1']")
    box = await page.locator("#edCanvas").bounding_box()
    assert box is not None
    await page.mouse.click(box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.3)
    changed = await b.state("window.curio.mapsPage.editor.changedCount()")
    assert changed > 0
    generation = host.generation
    await page.click("#edSave")
    await b.wait_js("window.curio.mapsPage.editor.meta.revision === 3 && document."
                    "getElementById('edMsg').textContent.includes('revision 3')", timeout_s=40)
    assert host.generation == generation + 1 and host.library.active == "annex"
    app = host.app
    assert app is not None and app.localizer is not None
    assert int((app.map_server.grid.data == -1).sum()) - int(
        (host.library.grid("curio_building").data == -1).sum()) >= changed
    await page.click("#edClose")


async def _mapping_run(b: kit.Browser, host: MapHost) -> None:
    """A mapping run from the page: the live view drawn; discarded."""
    await b.page.click("#mapStart")
    await b.confirm("Start mapping", accept=True)
    await _until(host.clock, lambda: host.mapping and host.generation == 4, "the mapping run")
    await b.wait_js(_shown("mappingLive"), timeout_s=30)
    await b.wait_js("document.getElementById('liveMap').width > 0")
    await b.shot("maps-mapping", "#mappingBox")
    await b.page.click("#mapDiscard")
    await b.confirm("Throw this map away", accept=True)
    await _until(host.clock, lambda: not host.mapping and host.generation == 5, "the discard")
    await b.wait_js(_shown("mappingLive", False), timeout_s=30)
