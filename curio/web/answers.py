"""``GET /api/commands/{request_id}``: what became of an operator command.

A page that lost its socket (or whose rover restarted) asks about each command it has no
answer for. The answer comes from the command journal
(:class:`~curio.eventlog.commands.CommandJournal`): ``{"request_id", "state", "action",
"source", "wall_s", "run", "answer"}`` with ``state`` ``answered`` (``answer``: ``{kind,
message, wall_s}``, the rover's ``bt.command_accepted`` / ``bt.command_rejected``), ``pending``
(received, not answered yet) or ``unknown`` (never received: send it again). Readable by
anyone, like the rest of the state.
"""

from __future__ import annotations

from aiohttp import web

from curio.core.jsonable import to_json
from curio.web.inputs import REQUEST_ID, http_error
from curio.web.services import SERVICES

__all__ = ["command_status"]


async def command_status(request: web.Request) -> web.Response:
    """The fate of one command (see the module docstring)."""
    rid = request.match_info["request_id"]
    if not REQUEST_ID.match(rid):
        raise http_error(web.HTTPBadRequest, "a request id is 1–64 characters of letters, "
                                             "digits, _ . : -")
    journal = request.app[SERVICES].journal
    if journal is None:
        return web.json_response({"request_id": rid, "state": "unknown", "answer": None})
    return web.json_response(journal.lookup(rid), dumps=to_json)
