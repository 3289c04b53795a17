"""The dashboard's other pages, beside the operator's map (``/``): the visitors' kiosk and the
pages that read the rover's history. Each is a hand-written HTML file in ``static/`` whose
scripts and styles carry the static files' version in their URLs, like the main page.

* ``/kiosk`` — the lobby screen (the kiosk token: start and stop the offered tours, the current
  stop's name and message in large type, "next stop in …"; nothing else moves the rover).
* ``/events`` — the event log with filters and CSV export.
* ``/report`` — the daily report as a table, and plots of tours and help waits per day.
* ``/recordings`` — the flight recorder's files: download, and how to replay one.
"""

from __future__ import annotations

from pathlib import Path

from aiohttp import web

from curio.web.services import STATIC_VERSION

__all__ = ["PAGES", "ROUTES", "page"]

STATIC_DIR = Path(__file__).resolve().parent / "static"
PAGES = ("kiosk", "events", "report", "recordings")


async def page(request: web.Request) -> web.Response:
    """One of :data:`PAGES`, with the static files' version in its URLs."""
    name = request.path.strip("/")
    html = (STATIC_DIR / f"{name}.html").read_text(encoding="utf-8")
    return web.Response(text=html.replace("{{VERSION}}", request.app[STATIC_VERSION]),
                        content_type="text/html", headers={"Cache-Control": "no-cache"})


ROUTES: list[web.RouteDef] = [web.get(f"/{name}", page) for name in PAGES]
