"""The operator dashboard: one page served by the rover (replaces the original's Qt dashboard,
RViz and rqt_py_trees), working on a phone, a tablet or a laptop with no internet.

* :mod:`curio.web.server` — ``create_app(services)``: the aiohttp application (middleware,
  page, WebSocket endpoint, background tasks) and its route table.
* :mod:`curio.web.api` — REST endpoints (state, grids as PNG, paths, commands) as module-level
  handlers and their ``ROUTES``; :mod:`curio.web.tours_api` (tours, schedules, the running
  tour), :mod:`curio.web.log_api` (the event log, the daily report), :mod:`curio.web.records_api`
  (recordings, the replay's timeline) likewise, with :mod:`curio.web.apikit` for what they share.
* :mod:`curio.web.pages` — the other pages: ``/kiosk``, ``/events``, ``/report``,
  ``/recordings``.
* :mod:`curio.web.services` — ``WebServices`` and the typed app keys the handlers read.
* :mod:`curio.web.hub` — the hub: one bus subscription per topic, fanned out to every client;
  the latched state a new client starts from.
* :mod:`curio.web.session` — ``ClientSession``: one browser's queues, sender, receive loop and
  rate limits.
* :mod:`curio.web.control` — ``RoverControl``: commands, the e-stop, the initial pose, teleop
  under a lease with a deadman and a disconnect stop; who did what.
* :mod:`curio.web.auth` — ``Gate``: identity and roles, Origin and Host checks, rate limits,
  wrong-token throttling, socket caps, token redaction in logs.
* :mod:`curio.web.tokens` — named tokens and roles (``curio token ...``).
* :mod:`curio.web.liveness` — the health panel: every part with its age.
* :mod:`curio.web.blocker` — what blocks the rover, for the map.
* :mod:`curio.web.inputs` — validation shared by REST and the WebSocket; the JSON errors.
* :mod:`curio.web.encode` — binary frames (scan in uint16 mm, poses and paths in float32).
* :mod:`curio.web.system` — CPU, temperature and event-loop lag for the health panel.
* :mod:`curio.web.wiring` — ``build_web(...)``: the server as a Part, with its control URL.
* ``static/`` — ``index.html``, ``core.js``, ``map.js``, ``panels.js``, ``drive.js``,
  ``tours.js``, ``schedule.js``, ``replay.js``, ``app.js``, ``style.css``; the other pages
  (``kiosk``, ``events``, ``report``, ``recordings``: ``.html`` and ``.js``, ``pagekit.js``,
  ``plot.js``, ``pages.css``): hand-written, no CDN, no build step. Modules add map tools and
  layers (``curio.mapTools``, ``curio.mapLayers``) and listen to the rover's messages
  (``curio.on(type, fn)``) without editing the shared files.

Security: viewing is open; everything else needs a named token whose role allows it
(:mod:`curio.web.tokens`: kiosk, operator, admin), kept in ``<data_dir>/<web.tokens_file>``
(0600; the admin token is made on the first start and printed at start-up as
``http://host:port/?token=...``). The server binds ``web.host`` (127.0.0.1 by default; set
``0.0.0.0`` on the Pi and prefer the rover's own hotspot or a VPN). Browser WebSockets and
changes must come from the rover's own origin or ``web.allowed_origins``, every request must
name the rover in ``Host``, and every response carries a CSP (``frame-ancestors 'none'``).
Messages larger than ``web.max_message_bytes`` or faster than ``web.max_messages_per_s`` are
refused with a reason — except the e-stop, which is never limited.
"""
