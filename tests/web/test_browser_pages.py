"""End-to-end (the whole App on a real-time SimClock, Debian's Chromium on a desktop and a phone):
the event log page (filters, a CSV download), the daily report page (figures, tables, bars
drawn on the canvas), the recordings page (what happened, a download, how to replay); and the
replay's timeline when ``curio replay --web`` serves the dashboard (pause, seek forwards and
backwards, Finish). Screenshots in ``artifacts/screenshots/``. Every wait is for a condition.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import re
import threading
from pathlib import Path

import pytest

from curio.commands.replay import main as replay_main
from curio.core.clock import SimClock
from curio.core.geometry import Pose2D
from curio.eventlog.store import EventLog
from tests.web import browser_kit as kit
from tests.web.conftest import at, fill_log, write_recording

pytestmark = [pytest.mark.browser]

# Count the pixels of one colour on a canvas (the report's bars are drawn, not just present).
PIXELS = """([id, r, g, b]) => {
    const c = document.getElementById(id), d = c.getContext('2d').getImageData(0, 0, c.width,
        c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) if (d[i] === r && d[i + 1] === g && d[i + 2] === b) n++;
    return n;
}"""


async def test_event_log_report_and_recordings_pages(tmp_path: Path, viewport: str) -> None:
    """Two days of records and a recording made before the App starts. Drives: the event log
    (SQLite, the recorder part), the daily report, the recordings list; the web pages."""
    cfg = kit.make_cfg(tmp_path / "data", 'tours.timezone="Europe/London"')
    log = EventLog(cfg.data_path(cfg.eventlog.file))
    fill_log(log)
    log.close()
    recordings = cfg.data_path("recordings")
    recordings.mkdir(parents=True)
    name = write_recording(recordings, at("09:59"), ["nav.goal_succeeded", "collision", "x"])
    token = kit.add_token(cfg, "alice")
    async with kit.running_app(cfg, epoch_wall_s=at("17:00")) as (app, _clock):
        base = (app.web_url or "").split("?")[0]
        async with kit.chromium() as browser:
            b = await kit.open_page(browser, base + f"events?token={token}", viewport,
                                connected=False)
            page = b.page
            await b.wait_js("document.querySelectorAll('#log tbody tr[data-kind]').length > 5")
            assert "times in the building's zone (Europe/London)" in await b.text("#count")
            await page.select_option("#kind", label="help requests")
            await b.wait_js("[...document.querySelectorAll('#log tbody tr')].map(r => "
                            "r.dataset.kind).join() === 'help.resolved,help.requested'")
            assert "Help came after 42 s" in await b.text("#log tbody")
            await b.shot("events")
            async with page.expect_download() as got:
                await page.click("#csv")
            csv_text = Path(await (await got.value).path()).read_text()
            assert csv_text.splitlines()[0] == "id,time,wall_s,kind,source,detail"
            assert [line.split(",")[3] for line in csv_text.splitlines()[1:]] == [
                "help.requested", "help.resolved"]

            await page.goto(base + "report?day=2025-06-02")
            await b.wait_js("document.querySelectorAll('#figures .figure').length > 8 && "
                            "window.curio.reportDays && window.curio.reportDays()")
            assert "Monday, 2 June 2025" in await b.text("#title")
            assert "Highlights" in await b.text("#toursTable")
            assert "the battery is low" in await b.text("#skippedTable")
            # The bars are drawn: completed tours in green, the help wait in purple.
            await b.wait_js("document.getElementById('toursPlot').width > 0")
            assert await page.evaluate(PIXELS, ["toursPlot", 22, 163, 74]) > 50
            assert await page.evaluate(PIXELS, ["helpPlot", 124, 58, 237]) > 50
            await b.shot("report")
            await b.shot("report-plots", ".plots")

            await page.goto(base + "recordings")
            await b.wait_js(f"!!document.querySelector('#recTable tr[data-name=\"{name}\"]')")
            row = page.locator(f'#recTable tr[data-name="{name}"]')
            assert "1 tour" in await row.text_content()  # 10:00 on 2 June, from the event log
            assert "1 collision" in await row.text_content()  # the file's own events
            assert await page.locator("#recTable tbody tr").count() == 2  # and the App's own
            async with page.expect_download() as got:
                await row.get_by_text("Download").click()
            assert Path(await (await got.value).path()).read_bytes()[:8] == b"\x89MCAP0\r\n"
            await row.get_by_text("Replay…").click()
            await b.wait_js("!document.querySelector('#replayHelp').classList.contains('hidden')")
            assert f"curio replay {name} --web" in await b.text("#replayHelp")
            await b.shot("recordings")
            assert b.errors == []


class _Lines(io.StringIO):
    """The replay command's output, read by the test while the command runs."""


async def test_replay_timeline_pauses_and_seeks(tmp_path: Path) -> None:
    """``curio replay --web`` of a short recorded run: the timeline bar pauses the replay,
    seeks forwards (computed up to there) and backwards (the run restarts on the same address),
    and Finish ends the command with its report. On a desktop; a phone looks at the bar too.
    Drives: the recorder, replay, the whole stack again, the dashboard."""
    run = tmp_path / "run.mcap"
    cfg = kit.make_cfg(tmp_path / "data", f'record.file="{run}"')
    clock = SimClock()
    from curio.app import App

    app = App(cfg, clock, web=False)
    await app.start()
    app.navigator.send_goal(Pose2D(2.0, 0.0, 0.0), tag="test")
    await clock.run(until_s=40.0)
    await app.stop()
    out = _Lines()
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(replay_main(
        [str(run), "--web", "--speed", "2"], out, out)), daemon=True)
    thread.start()
    try:
        for _ in range(600):
            found = re.search(r"dashboard: (\S+)", out.getvalue())
            if found or codes:
                break
            await asyncio.sleep(0.05)  # noqa: TID251 - the command starts in its own thread
        assert found, out.getvalue()
        async with kit.chromium() as browser:
            phone = await kit.open_page(browser, found.group(1), "phone")
            await phone.wait_js("!!document.getElementById('replayBar') && "
                                "!document.getElementById('replayFinish').disabled")
            await phone.shot("replay")
            b = await kit.open_page(browser, found.group(1), "desktop")
            page = b.page
            await b.wait_js("!!document.getElementById('replayBar')")
            await page.click("#replayPlay")  # pause
            await b.wait_js("document.getElementById('replayPlay').textContent === '▶'")
            # A poll already on its way when the pause was clicked may still show the last
            # step: read the position after one full poll more, then watch it hold.
            polls = await b.state("window.curio.replayPolls")
            await b.wait_js(f"window.curio.replayPolls >= {polls + 2}")
            held = await b.text("#replayTime")
            polls = await b.state("window.curio.replayPolls")
            await b.wait_js(f"window.curio.replayPolls >= {polls + 3}")  # asked 3 times more:
            assert await b.text("#replayTime") == held  # the position did not move
            await b.shot("replay")
            # Seek forwards to 30 s (computed at full speed), then back to 5 s (a restart).
            await page.evaluate("""() => { const s = document.getElementById('replaySeek');
                s.value = '30'; s.dispatchEvent(new Event('change')); }""")
            await b.wait_js("document.getElementById('replayTime').textContent"
                            ".startsWith('0:30')", timeout_s=60)
            await page.evaluate("""() => { const s = document.getElementById('replaySeek');
                s.value = '5'; s.dispatchEvent(new Event('change')); }""")
            await b.wait_js("document.getElementById('replayTime').textContent"
                            ".startsWith('0:05')", timeout_s=60)
            await b.wait_js("window.curio.S.connected", timeout_s=30)
            await page.click("#replayFinish")
            await b.confirm("End the replay?", accept=True)
            for _ in range(600):
                if codes:
                    break
                await asyncio.sleep(0.05)  # noqa: TID251 - the command ends in its thread
            b.errors = [e for e in b.errors if "WebSocket" not in e and "Failed to load" not in e]
            assert b.errors == []
        assert codes and codes[0] in (0, 1), out.getvalue()
        assert "replayed run.mcap" in out.getvalue()
    finally:
        thread.join(timeout=30)
        with contextlib.suppress(Exception):
            out.close()


async def test_a_start_after_a_crash_reads_as_sentences(tmp_path: Path, viewport: str) -> None:
    """What a rover finds at a start after ``kill -9`` or a power cut — the run marker of a
    process that never stopped, the journal of a tour it was running, a damaged schedules file
    — reaches the operator as sentences that stand out, on the dashboard and in the event log.
    Drives: the run marker, the tour journal, the data notes, the event log, the two pages."""
    from tests.unit.test_schedules import store

    cfg = kit.make_cfg(tmp_path / "data", 'tours.timezone="Europe/London"')
    marker = cfg.data_path("running.json")
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text('{"pid": 999999, "started_wall_s": 1699990000.0, '
                      '"alive_wall_s": 1699999880.0}')
    cfg.data_path("tours.running.json").write_text(
        '{"tour_id": 1, "tour": "Highlights", "source": "schedule", "request_id": null, '
        '"stops": 5, "stops_reached": 2, "started_wall_s": 1699999700.0}')
    schedules = cfg.data_path(cfg.tours.schedules_file)
    store(schedules).add(1, ["mon"], ["10:00"])
    schedules.write_bytes(b"\x00" * 40)  # torn by the power cut; its backup is whole
    token = kit.add_token(cfg, "alice")
    async with kit.running_app(cfg) as (app, _clock):
        base = (app.web_url or "").split("?")[0]
        async with kit.chromium() as browser:
            b = await kit.open_page(browser, base + f"?token={token}", viewport)
            rows = "[...document.querySelectorAll('#events li')]"
            for cls, text in (("ev-bad", "restarted after an unclean stop"),
                              ("ev-bad", "The tour 'Highlights' was interrupted after 2 of 5"),
                              ("ev-warn", "schedules.json")):
                await b.wait_js(f"{rows}.some(li => li.className === '{cls}' && "
                                f"li.textContent.includes({text!r}))")
            await b.shot("after-a-crash", "#events")

            await b.page.goto(base + f"events?token={token}")
            await b.page.select_option("#kind", label="restarts, stalls and damaged files")
            await b.wait_js("[...document.querySelectorAll('#log tbody tr')].map(r => "
                            "r.dataset.kind).sort().join() === "
                            "'data.restored,system.unclean_restart,tour.interrupted'")
            log_rows = b.page.locator("#log tbody tr")
            classes = {await r.get_attribute("data-kind"): await r.get_attribute("class")
                       for r in await log_rows.all()}
            assert classes == {"system.unclean_restart": "bad", "tour.interrupted": "bad",
                               "data.restored": "warn"}
            assert "restarted after an unclean stop" in await b.text("#log tbody")
            await b.shot("events-after-a-crash")
            assert b.errors == []
