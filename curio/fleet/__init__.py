"""A fleet of Curio rovers over Eclipse Zenoh (issue 17; ``docs/fleet.md``).

* :mod:`curio.fleet.keys` — the key expressions (``curio/<rover>/<topic>``) and their matching;
* :mod:`curio.fleet.transport` — the :class:`~curio.fleet.transport.Transport` interface the
  fleet code talks to, and an in-process one for tests;
* :mod:`curio.fleet.zenoh_link` — the Zenoh transport (imports ``zenoh`` lazily: Curio runs
  without the ``curio[fleet]`` extra);
* :mod:`curio.fleet.codec` — what goes over the wire (compact JSON, binary scans and maps);
* :mod:`curio.fleet.auth` — signed commands, keys and roles;
* :mod:`curio.fleet.bridge` — the rover's bridge part (topics out, commands in, queryables);
* :mod:`curio.fleet.traffic` — other rovers as moving obstacles with known intent, narrow
  passages and the right-of-way rule;
* :mod:`curio.fleet.ros2` — ROS 2 CDR messages under ``rmw_zenoh``'s key expressions;
* :mod:`curio.fleet.manager` — the fleet manager (``curio fleet run``): discovery, shared
  tours and schedules, dispatch;
* :mod:`curio.fleet.wiring` — ``build_fleet`` for the composition root.
"""
