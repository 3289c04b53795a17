"""The fleet manager (``curio fleet run``): one process that discovers the rovers, keeps the
shared tours and schedules and dispatches tours to the best rover.

* :mod:`~curio.fleet.manager.roster` — what the manager knows of each rover;
* :mod:`~curio.fleet.manager.routes` — how far a rover has to drive (on the shared map);
* :mod:`~curio.fleet.manager.dispatch` — tours as jobs: choose, send, watch, re-dispatch;
* :mod:`~curio.fleet.manager.service` — the manager itself (link, stores, scheduler, parts);
* :mod:`~curio.fleet.manager.web` — its JSON API and a small self-contained page.
"""
