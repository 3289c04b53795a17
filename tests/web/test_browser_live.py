"""End-to-end, several pages at once: two operators (two browser contexts, two tokens) see who
drives, who deleted a path and who set the e-stop; the page says Offline within a second of the
server stopping, greys what it last saw, and reconnects by itself; ``curio run`` exits within
3 s with pages open; the health panel lists every part with its age, and a part that stops goes
stale; events read as sentences in wall-clock time. Desktop and phone viewports.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
import signal
import sys
from pathlib import Path

import pytest

from curio.app import App
from curio.core.clock import SimClock, wall_perf_counter
from curio.core.topics import OPERATOR
from curio.web.tokens import TokenStore
from tests.web import browser_kit as kit

pytestmark = [pytest.mark.browser]


async def test_two_operators_see_who_does_what(tmp_path: Path, viewport: str) -> None:
    """Alice drives: Bob's page says so; Bob takes over after confirming; Bob deletes the path
    Alice is editing: she is told who did it; Alice's e-stop shows her name on Bob's page and
    Bob may not release it. Drives: sim, safety stage, behaviour tree (paths)."""
    cfg = kit.make_cfg(tmp_path / "data")
    alice_token, bob_token = kit.add_token(cfg, "alice"), kit.add_token(cfg, "bob")
    async with kit.running_app(cfg, kit.TELEOP_SPEED) as (app, clock), kit.chromium() as browser:
        base = (app.web_url or "").split("?")[0]
        alice = await kit.open_page(browser, f"{base}?token={alice_token}", viewport)
        bob = await kit.open_page(browser, f"{base}?token={bob_token}", viewport)
        assert "alice" in await alice.text("#who") and "bob" in await bob.text("#who")
        await alice.wait_js("window.curio.S.pose")

        # Alice drives; Bob's page shows who drives.
        start = kit.truth_xy(app)
        joy = await alice.page.locator("#joystick").bounding_box()
        cx, cy = joy["x"] + joy["width"] / 2, joy["y"] + joy["height"] / 2
        await alice.page.mouse.move(cx, cy)
        await alice.page.mouse.down()
        await alice.page.mouse.move(cx, cy - joy["height"] * 0.5, steps=4)
        await bob.wait_js("document.querySelector('#statusText').textContent === "
                          "'alice is driving by hand'")
        assert "alice is driving" in await bob.text("#leaseText")
        assert await clock.wait_until(lambda: math.dist(start, kit.truth_xy(app)) > 0.1,
                                      timeout_s=10.0)
        await bob.shot("two-operators-lease")
        # Bob reaches for the stick: asked first; he takes over; Alice is told.
        bjoy = await bob.page.locator("#joystick").bounding_box()
        await bob.page.mouse.move(bjoy["x"] + bjoy["width"] / 2, bjoy["y"] + bjoy["height"] / 2)
        await bob.page.mouse.down()
        await bob.page.mouse.up()
        await bob.confirm("alice is driving — take over?", accept=True)
        await alice.wait_js("window.curio.S.lease.holder === 'bob'")
        await alice.wait_js("document.querySelector('#toast').textContent.includes("
                            "'bob took over driving')")
        await alice.page.mouse.up()
        # A refusal of a stick message that was on its way during the take-over is stale:
        # Alice is not asked to take the stick back (she was, now and then, on slow machines).
        await alice.page.evaluate("window.curio.onLeaseRefused('bob')")
        assert await alice.state("document.querySelector('#modal').classList"
                                 ".contains('hidden')")
        await alice.wait_js("document.querySelector('#events').textContent.includes("
                            "'bob took over driving from alice')")

        # Bob deletes the path Alice is editing: Alice is told who did it.
        await alice.page.click("#pathsCard summary")
        await alice.page.select_option("#editPath", "2")
        await bob.page.click("#pathsCard summary")
        await bob.page.select_option("#editPath", "2")
        await bob.page.click("#deletePath")
        await bob.confirm("Delete path 2", accept=True)
        await alice.wait_js("document.querySelector('#pathEditMsg').textContent.includes("
                            "'was deleted by bob')")
        await alice.shot("two-operators-deleted", "#pathsCard")

        # Alice's e-stop: Bob's page names her; Bob may not release it; Alice may.
        await alice.page.click("#estop")
        await bob.wait_js("document.querySelector('#estopWho').textContent.includes('alice')")
        await bob.shot("two-operators-estop")
        bob.allowed.append("status of 403")  # the browser logs the refused request
        await bob.page.click("#releaseEstop")
        await bob.confirm("set by alice", accept=True)
        await bob.wait_js("document.querySelector('#cmdMsg').textContent.includes("
                          "'only alice or an admin')")
        assert await bob.state("window.curio.S.estop.engaged")
        await alice.page.click("#releaseEstop")
        await alice.confirm("Release the emergency stop", accept=True)
        await bob.wait_js("document.querySelector('#estopLog').textContent.includes("
                          "'released by alice')")
        events = await bob.text("#events")
        assert "alice pressed the e-stop" in events and "alice released the e-stop" in events
        assert re.search(r"\d\d:\d\d:\d\d", events)

        # Bob's token is revoked ('curio token revoke bob'): his page drops to view-only.
        TokenStore(cfg.data_path(cfg.web.tokens_file)).revoke("bob")
        await bob.wait_js("window.curio.S.who.role === 'viewer' && document.querySelector("
                          "'#who').textContent.startsWith('View')")
        await bob.wait_js("window.curio.S.connected")
        assert await bob.page.is_disabled("#goHome")
        assert alice.errors == [] and bob.errors == []


async def test_offline_at_once_stale_data_and_reconnection(tmp_path: Path,
                                                           viewport: str) -> None:
    """The server stops: within 1 s the page says Offline, and the pose, laser and chips are
    greyed with their age; the server comes back on the same port: the page reconnects by
    itself and shows live data again. The page refuses to be framed by another site.
    Drives: the whole App (twice)."""
    cfg = kit.make_cfg(tmp_path / "data")
    clock = SimClock(speed=4.0)
    app = App(cfg, clock, web=True)
    await app.start()
    runner = asyncio.create_task(clock.run())
    assert app.web is not None
    port = app.web.port
    try:
        async with kit.browser_on(app.web_url or "", viewport) as b:
            await b.wait_js("window.curio.S.pose && window.curio.S.loc")
            ops = app.bus.subscribe(OPERATOR)
            b.allowed.append("ERR_CONNECTION_REFUSED")  # the page retrying while it is down
            t0 = wall_perf_counter()
            stopping = asyncio.ensure_future(app.stop())
            await b.wait_js("!window.curio.S.connected", timeout_s=1.0)
            offline_s = wall_perf_counter() - t0
            await stopping
            assert offline_s < 1.0
            assert await b.text("#stateBadge") == "Offline"
            assert await b.text("#conn") == "Offline"
            await b.wait_js("document.querySelector('#locChip').classList.contains('stale')")
            await b.wait_js("!document.querySelector('#staleNote').classList.contains('hidden')")
            assert "Offline" in await b.text("#staleNote")
            assert await b.state("window.curio.isStale('pose') && window.curio.isStale('scan')")
            assert await b.page.is_disabled("#goHome")  # nothing can be sent offline
            await b.shot("offline")
            assert ops.drain() == []

            runner.cancel()
            cfg2 = kit.make_cfg(tmp_path / "data", f"web.port={port}")
            clock = SimClock(speed=4.0)
            app = App(cfg2, clock, web=True)
            await app.start()
            runner = asyncio.create_task(clock.run())
            await b.wait_js("window.curio.S.connected && window.curio.S.status", timeout_s=15)
            await b.wait_js("!window.curio.isStale('pose')")
            assert await b.text("#conn") == "Live"
            assert await b.text("#stateBadge") != "Offline"

            # Another site cannot frame the dashboard (CSP frame-ancestors 'none').
            b.allowed.append("frame-ancestors")
            frame_page = await b.page.context.new_page()
            await frame_page.set_content(f'<iframe src="{app.web_url}"></iframe>')
            frame = frame_page.frames[-1]
            with contextlib.suppress(Exception):
                await frame.wait_for_load_state()
            framed = await frame.evaluate("() => typeof window.curio")
            assert framed == "undefined"
            assert b.errors == []
    finally:
        await app.stop()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner


async def test_curio_run_exits_within_3_s_with_pages_open(tmp_path: Path) -> None:
    """``curio run`` with a desktop and a phone page open: Ctrl-C ends the process within
    3 s and both pages say Offline within 1 s."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "curio", "run", "--set", "web.port=0",
        "--set", f'data_dir="{tmp_path / "data"}"', "--set", "bt.speak=false",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    try:
        url = None
        while url is None:
            line = (await asyncio.wait_for(proc.stdout.readline(), 60)).decode()
            assert line, "curio run ended before printing the dashboard address"
            match = re.search(r"dashboard: (http://\S+)", line)
            url = match.group(1) if match else None
        async with kit.chromium() as browser:
            pages = [await kit.open_page(browser, url, vp) for vp in ("desktop", "phone")]
            t0 = wall_perf_counter()
            proc.send_signal(signal.SIGINT)
            for page in pages:
                await page.wait_js("!window.curio.S.connected",
                                   timeout_s=max(0.05, 1.0 - (wall_perf_counter() - t0)))
            assert wall_perf_counter() - t0 < 1.0
            code = await asyncio.wait_for(proc.wait(), 10.0)
            exit_s = wall_perf_counter() - t0
            assert code == 0
            assert exit_s < 3.0, f"curio run took {exit_s:.1f} s to exit with pages open"
            for page in pages:
                assert await page.text("#stateBadge") == "Offline"
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def test_health_lists_every_part_with_its_age_and_events_read_well(
        tmp_path: Path, viewport: str) -> None:
    """The health panel lists the planner, navigator, behaviour tree, lidar and costmap among
    every part, each with the age of its last sign of life; counters as rates; a part whose
    task stops shows it. Events are sentences with wall-clock times. Drives: the whole App."""
    async with kit.running_app(kit.make_cfg(tmp_path / "data")) as (app, clock), \
            kit.browser_on(app.web_url or "", viewport) as b:
        page = b.page
        await b.wait_js("window.curio.S.pose")
        await page.click("#goHome")  # some events to read
        await page.click("#healthCard summary")
        for name in ("planner", "navigator", "behaviour tree", "lidar", "costmap", "safety",
                     "localisation", "web"):
            await b.wait_js(f"!!document.querySelector('#health .hpart[data-name=\"{name}\"]')")
        await b.wait_js("[...document.querySelectorAll('#health .hage')].every(a => "
                        "/ago|just now/.test(a.textContent))")
        lidar = await b.text('#health .hpart[data-name="lidar"]')
        assert re.search(r"\d+(\.\d+)? scans/s", lidar), lidar
        await page.locator('#health .hpart[data-name="safety"] summary').click()
        await b.wait_js("document.querySelector('#health .hpart[data-name=\"safety\"]')"
                        ".textContent.includes('control cycles: ')")
        assert "/s (total" in await b.text('#health .hpart[data-name="safety"]')
        assert "Bus:" in await b.text("#busNote")
        await b.shot("health", "#healthCard")

        # The costmap's task stops: its row goes stale and says so.
        for task in app._tasks:
            if task.get_name() == "costmap":
                task.cancel()
        await b.wait_js("document.querySelector('#health .hpart[data-name=\"costmap\"]')"
                        ".textContent.includes('task costmap stopped')", timeout_s=15)
        await b.wait_js("document.querySelector('#healthSummary').textContent.includes("
                        "'need attention')")

        await page.locator("#logCard").scroll_into_view_if_needed()
        events = await b.text("#events")
        assert re.search(r"\d\d:\d\d:\d\d", events) and "{" not in events
        assert "sent the rover home" in events
        await b.shot("events", "#logCard")
        await page.click("#treeCard summary")
        await b.wait_js("document.querySelectorAll('#tree .node').length > 3")
        await b.shot("tree", "#treeCard")
        await b.shot("page-bottom")
        assert clock.now() > 0
        assert b.errors == []
