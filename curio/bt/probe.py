"""Is the way clear? A planning probe the help request uses to decide when to say "Thanks!".

While the rover holds for help its goal is cancelled, so the blocked-path detector (which only
judges an active goal) cannot say when the way is clear again. :class:`WayProbe` asks the
global planner, on the current costmap, whether a collision-free path now leads from the
rover's pose (``/pose``, ``map``) to the waypoint it was heading for: a closed door that
reopens or an obstacle taken away clears its cells (lidar ray tracing), and the plan appears.

Behaviours never block: :meth:`WayProbe.start` launches the plan with ``Clock.offload`` (a
worker thread on the real clock, inline on a simulated one, like the navigator's plans) and
:meth:`WayProbe.poll` picks the answer up.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D
from curio.core.topics import POSE
from curio.nav.api import NavError

__all__ = ["ProbeResult", "WayProbe"]

log = logging.getLogger("curio.bt.probe")


@dataclass(frozen=True, slots=True)
class ProbeResult:
    """The answer of one probe: ``clear`` when a path exists; ``reason`` otherwise."""

    started_s: float
    clear: bool
    reason: str = ""


class WayProbe:
    """Plans from the rover to a goal on the live costmap, off the event loop.

    Args:
        planner: has ``plan(start, goal, costs, resolution_m, origin) -> list[Pose2D]`` and
            raises :class:`~curio.nav.api.NavError` when there is no path.
        costmap: has ``costs()``, ``resolution_m`` and ``origin``.
        bus: for the rover's pose (``/pose``).
        clock: plans run through ``clock.offload`` (a worker thread on real time).
    """

    def __init__(self, planner: Any, costmap: Any, bus: Bus, clock: Clock) -> None:
        self.planner = planner
        self.costmap = costmap
        self.bus = bus
        self.clock = clock
        self._job: asyncio.Future[list[Pose2D]] | None = None
        self._job_started_s = 0.0
        self.last: ProbeResult | None = None
        self.count = 0

    @property
    def busy(self) -> bool:
        """A probe is still running."""
        return self._job is not None and not self._job.done()

    def start(self, goal: Pose2D, now_s: float) -> bool:
        """Start a probe towards ``goal`` (``map``); False if one runs or there is no pose."""
        if self.busy:
            return False
        pose_msg = self.bus.latest(POSE)
        if pose_msg is None:
            return False
        start = pose_msg.pose
        costs = self.costmap.costs()
        res = self.costmap.resolution_m
        origin = self.costmap.origin
        self.count += 1
        self._job_started_s = now_s
        self._job = self.clock.offload(self.planner.plan, start, goal, costs, res, origin)
        self.poll()
        return True

    def poll(self) -> ProbeResult | None:
        """Collect a finished probe; return the latest answer (None before the first)."""
        job = self._job
        if job is not None and job.done():
            self._job = None
            try:
                job.result()
                self.last = ProbeResult(self._job_started_s, True)
            except NavError as exc:
                self.last = ProbeResult(self._job_started_s, False, str(exc))
            except Exception as exc:  # a planner bug must not stop the tree
                log.warning("way probe failed: %s", exc)
                self.last = ProbeResult(self._job_started_s, False, str(exc))
        return self.last

    def reset(self) -> None:
        """Forget earlier answers (a new help episode)."""
        if self._job is not None and not self._job.done():
            self._job.cancel()
        self._job = None
        self.last = None
