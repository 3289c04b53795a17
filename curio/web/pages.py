"""The dashboard's other pages, beside the operator's map (``/``): the visitors' kiosk and the
pages that read the rover's history. Each is a hand-written HTML file in ``static/`` whose
scripts and styles carry the static files' version in their URLs, like the main page.

* ``/kiosk`` — the lobby screen (the kiosk token: start and stop the offered tours, the current
  stop's name and message in large type, "next stop in …"; nothing else moves the rover).
* ``/events`` — the event log with filters and CSV export.
* ``/report`` — the daily report as a table, and plots of tours and help waits per day.
* ``/recordings`` — the flight recorder's files: download, and how to replay one.
* ``/maps`` — the map library: floors, switching, a mapping run, the cell editor (docs/maps.md).
"""

from __future__ import annotations

from pathlib import Path

from aiohttp import web

from curio.web.services import STATIC_VERSION

__all__ = ["PAGES", "ROUTES", "page"]

STATIC_DIR = Path(__file__).resolve().parent / "static"
PAGES = ("kiosk", "events", "report", "recordings", "maps")


# What every page's <head> holds ({{HEAD}} in the files): no referrer, no favicon request, the
# dashboard's styles and the pages' own.
HEAD = """<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1, viewport-fit=cover">
<meta name="referrer" content="no-referrer">
<link rel="icon" href="data:,">
<link rel="stylesheet" href="/static/style.css?v={{VERSION}}">
<link rel="stylesheet" href="/static/pages.css?v={{VERSION}}">"""


async def page(request: web.Request) -> web.Response:
    """One of :data:`PAGES`, with the common head and the static files' version in its URLs."""
    name = request.path.strip("/")
    html = (STATIC_DIR / f"{name}.html").read_text(encoding="utf-8").replace("{{HEAD}}", HEAD)
    return web.Response(text=html.replace("{{VERSION}}", request.app[STATIC_VERSION]),
                        content_type="text/html", headers={"Cache-Control": "no-cache"})


ROUTES: list[web.RouteDef] = [web.get(f"/{name}", page) for name in PAGES]
