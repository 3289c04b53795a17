"""The tour guide's manners among its visitors (the path follower asks them at tour stops).

* **On the way to a stop** the people stage may stop short of it (``stop_short_m``) when
  people stand where the rover would: it keeps its distance instead of pushing in.
* **At the stop** it turns to face the group — the tracked people within
  ``group_radius_m`` — when they are more than 0.4 rad off its heading (through the
  navigator: a goal at its own position with the heading towards the group's centre), and
  again a few seconds later if the group has moved round it; not while someone stands where
  its corners would swing.
* **Before leaving** it waits until nobody is within ``leave_clearance_m`` of the way out
  (the corridor its footprint sweeps over the first 1.5 m towards the next stop); after
  ``leave_wait_max_s`` it says "Excuse me" and goes (the people stage then yields as needed).

Everything here is advice to the follower; the controller's people stage and the safety
stage's stop zone still decide every motion.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from curio.core.clock import Clock
from curio.core.config import PeopleConfig
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import PeopleTracks
from curio.people.stage import PeopleStage

__all__ = ["GuideManners"]

FACE_TOLERANCE_RAD = 0.4
FACE_RECHECK_S = 3.0
WAY_OUT_M = 1.5


class GuideManners:
    """The manners (see the module docstring).

    Args:
        cfg: ``people``.
        clock: the injected clock.
        navigator: sends the goal that turns the rover (``send_goal``), or None.
        stage: the controller's people stage (its ``stop_short``), or None.
        tracks: the latest ``/people`` message.
        pose: the rover's pose in ``map`` (None: unknown).
        excuse_me: says "Excuse me" (speech and the ``people.excuse_me`` event).
        half_width_m: half the footprint's width.
        reach_m: the footprint's circumscribed radius.
    """

    def __init__(self, cfg: PeopleConfig, clock: Clock, navigator: Any,
                 stage: PeopleStage | None, tracks: Callable[[], PeopleTracks | None],
                 pose: Callable[[], Pose2D | None], excuse_me: Callable[[str], None],
                 half_width_m: float, reach_m: float) -> None:
        self.cfg = cfg
        self.clock = clock
        self.navigator = navigator
        self.stage = stage
        self.tracks = tracks
        self.pose = pose
        self.excuse_me = excuse_me
        self.half_width_m = half_width_m
        self.reach_m = reach_m
        self._face_due_s = math.inf
        self._face_handle: Any = None
        self._leave_since: float | None = None
        self._excused = False
        self.faced = 0
        self.waited_to_leave_s = 0.0

    # -- what the follower tells ---------------------------------------------------------------
    def driving_to(self, tour_stop: bool) -> None:
        """The follower drives to its next waypoint (``tour_stop``: one it will dwell at)."""
        if self.stage is not None:
            self.stage.stop_short = tour_stop
        self._face_due_s = math.inf
        self._leave_since = None
        self._excused = False

    def arrived(self) -> None:
        """The rover reached a tour stop: face the group now (and look again later)."""
        self._face_due_s = self.clock.now()

    def dwelling(self) -> None:
        """Called on every tick at a stop: face the group when it is time."""
        now = self.clock.now()
        if not self.cfg.face_group or now < self._face_due_s:
            return
        self._face_due_s = now + FACE_RECHECK_S
        if self._face_handle is not None and not self._face_handle.done:
            return
        yaw = self.group_heading()
        pose = self.pose()
        if yaw is None or pose is None or self.navigator is None or self._crowded(pose):
            return
        if abs(wrap_angle(yaw - pose.yaw)) > FACE_TOLERANCE_RAD:
            self._face_handle = self.navigator.send_goal(Pose2D(pose.x, pose.y, yaw),
                                                         tag="face the group")
            self.faced += 1

    def may_leave(self, next_xy: tuple[float, float] | None) -> bool:
        """Whether the rover may leave for ``next_xy`` (map): the way out is clear, or it has
        waited ``leave_wait_max_s`` and said "Excuse me"."""
        now = self.clock.now()
        if next_xy is None or self._excused or self.way_out_clear(next_xy):
            self._done_leaving(now)
            return True
        if self._leave_since is None:
            self._leave_since = now
        if now - self._leave_since >= self.cfg.leave_wait_max_s:
            self.excuse_me(self.cfg.excuse_me_text)
            self._excused = True
            self._done_leaving(now)
            return True
        return False

    def _done_leaving(self, now: float) -> None:
        if self._leave_since is not None:
            self.waited_to_leave_s += now - self._leave_since
        self._leave_since = None

    # -- looking at people ---------------------------------------------------------------------
    def _crowded(self, pose: Pose2D) -> bool:
        """Whether someone stands where the footprint's corners would swing turning here."""
        msg = self.tracks()
        if msg is None:
            return False
        room = self.reach_m + self.cfg.person_radius_m + self.cfg.min_distance_m
        return any(math.hypot(t.x_m - pose.x, t.y_m - pose.y) < room for t in msg.tracks)

    def group_heading(self) -> float | None:
        """Heading (map, rad) from the rover to the centre of the people round it, or None."""
        pose = self.pose()
        msg = self.tracks()
        if pose is None or msg is None:
            return None
        near = [(t.x_m, t.y_m) for t in msg.tracks
                if math.hypot(t.x_m - pose.x, t.y_m - pose.y) <= self.cfg.group_radius_m]
        if not near:
            return None
        cx = sum(x for x, _ in near) / len(near)
        cy = sum(y for _, y in near) / len(near)
        return math.atan2(cy - pose.y, cx - pose.x)

    def way_out_clear(self, next_xy: tuple[float, float]) -> bool:
        """Nobody within ``leave_clearance_m`` of the corridor swept over the first 1.5 m
        towards ``next_xy``."""
        pose = self.pose()
        msg = self.tracks()
        if pose is None or msg is None:
            return True
        yaw = math.atan2(next_xy[1] - pose.y, next_xy[0] - pose.x)
        c, s = math.cos(yaw), math.sin(yaw)
        room = self.half_width_m + self.cfg.leave_clearance_m + self.cfg.person_radius_m
        for t in msg.tracks:
            dx, dy = t.x_m - pose.x, t.y_m - pose.y
            along, lateral = c * dx + s * dy, -s * dx + c * dy
            if -0.3 <= along <= WAY_OUT_M + room and abs(lateral) <= room:
                return False
        return True
