"""The operator dashboard: one page served by the rover (replaces the original's Qt dashboard,
RViz and rqt_py_trees), working on a phone, a tablet or a laptop with no internet.

* :mod:`curio.web.server` — ``create_app(services)``: the aiohttp application (middleware,
  page, WebSocket endpoint, background tasks) and its route table.
* :mod:`curio.web.api` — REST endpoints (state, grids as PNG, paths, commands) as module-level
  handlers and their ``ROUTES``.
* :mod:`curio.web.services` — ``WebServices`` and the typed app keys the handlers read.
* :mod:`curio.web.hub` — the hub: one bus subscription per topic, fanned out to every client;
  the latched state a new client starts from.
* :mod:`curio.web.session` — ``ClientSession``: one browser's queues, sender, receive loop and
  rate limits.
* :mod:`curio.web.control` — ``RoverControl``: commands, the initial pose, teleop with a
  deadman and a disconnect stop.
* :mod:`curio.web.auth` — the control token, Origin checks, rate limiting, ``ControlGate``.
* :mod:`curio.web.inputs` — validation shared by REST and the WebSocket; the JSON errors.
* :mod:`curio.web.encode` — binary frames (scan in uint16 mm, poses and paths in float32).
* :mod:`curio.web.system` — CPU, temperature and event-loop lag for the health panel.
* :mod:`curio.web.wiring` — ``build_web(...)``: the server as a Part, with its control URL.
* ``static/`` — ``index.html``, ``app.js``, ``style.css``: hand-written, no CDN, no build step.

Security: viewing is open; control (commands, teleop, path edits, initial pose) needs the
token stored in ``<data_dir>/<web.token_file>`` (0600, generated on first start) and printed
at start-up as ``http://host:port/?token=...``. The server binds ``web.host`` (127.0.0.1 by
default; set ``0.0.0.0`` on the Pi and prefer the rover's own hotspot or a VPN). Browser
WebSockets and control requests must come from the rover's own origin or
``web.allowed_origins``. Messages larger than ``web.max_message_bytes`` or faster than
``web.max_messages_per_s`` are refused with a reason.
"""
