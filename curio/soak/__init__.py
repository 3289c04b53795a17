"""``curio soak``: days without a person — the whole rover for simulated days, with operators,
a fault campaign and ``kill -9``, counting what was lost.

Two processes, so the rover can be killed for real:

* the **orchestrator** (:mod:`curio.soak.orchestrator`, the parent: ``curio soak``) draws the
  fault campaign from the seed (:mod:`curio.soak.plan`), prepares the rover's data directory
  (named tokens, a size-limited filesystem for the disk-full faults: :mod:`curio.soak.disk`),
  starts the rover, runs the scripted dashboard clients over real WebSockets
  (:mod:`curio.soak.clients`), sends ``SIGKILL`` when the campaign asks for it, checks every
  persisted file while the rover is dead (:mod:`curio.soak.files`), corrupts one when the
  campaign says so and starts the rover again where the simulated world stood; it keeps the
  ledger of operator commands (:mod:`curio.soak.ledger`) and writes the report
  (:mod:`curio.soak.report`);
* the **rover** (:mod:`curio.soak.rover`, the child) is the whole application in emulated mode
  (the real drivers on byte-exact device emulators) on a simulated clock, in the default
  building with its scheduled tours (:mod:`curio.soak.day`); it injects the campaign's faults
  and judges them (:mod:`curio.soak.faults`), measures itself (:mod:`curio.soak.probes`) and
  reports to the orchestrator over its standard output, one JSON object a line
  (:mod:`curio.soak.link`).

Simulated time continues across a restart: the orchestrator starts the new rover's clock where
the killed one's last report left it plus the restart's downtime (``RESTART_S``), with the
simulated rover where it stood; the rover itself knows only what it persisted.
"""
