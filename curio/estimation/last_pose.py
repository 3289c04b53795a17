"""The rover's last known pose, kept on disk so a restart starts localised where it stopped.

A real rover that restarts (a crash, ``kill -9``, a power cut, an update) is where it was, not
at home; without this it would start localised at home and have to find itself (or be shown
where it is). :class:`LastPoseKeeper` writes ``<data_dir>/last_pose.json`` (map, metres and
radians, with the wall time) atomically whenever the localised pose has moved
``MIN_MOVE_M`` or turned ``MIN_TURN_RAD`` since the last save — at most every ``PERIOD_S``
of clock time — only while localisation is ``ok`` (a lost estimate is not worth keeping), and
once more at a clean stop. :func:`load_last_pose` reads it back; the estimation wiring starts
the localiser there (``localization.resume_last_pose``), and the simulator's world starts its
rover there too when no ``sim.start`` is given (the simulated building keeps the rover where
it stopped).

A pose saved up to ``PERIOD_S`` before an unclean stop is that much stale; the filter's initial
spread (``localization.initial_std_xy_m``) covers the difference, and a pose that does not
match the scans at all makes localisation search (``lost``), as after a kidnap.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.fileio import atomic_write_json, read_json
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.topics import LOCALIZATION, POSE

__all__ = ["LAST_POSE_FILE", "LastPoseKeeper", "load_last_pose"]

log = logging.getLogger("curio.estimation.last_pose")

LAST_POSE_FILE = "last_pose.json"
PERIOD_S = 1.0
MIN_MOVE_M = 0.1
MIN_TURN_RAD = 0.1


def load_last_pose(path: Path) -> Pose2D | None:
    """The pose in ``path`` (None: no file, or one that cannot be used — logged)."""
    try:
        data = read_json(path)
        if data is None:
            return None
        pose = Pose2D(float(data["x_m"]), float(data["y_m"]), float(data["yaw_rad"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring the last pose in %s: %s", path, exc)
        return None
    if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.yaw)):
        log.warning("ignoring the last pose in %s: not finite", path)
        return None
    return pose


class LastPoseKeeper:
    """Saves the localised pose (see the module docstring).

    Args:
        path: the file.
        bus, clock: the application's.
    """

    def __init__(self, path: Path, bus: Bus, clock: Clock) -> None:
        self.path = path
        self.bus = bus
        self.clock = clock
        self.saved: Pose2D | None = load_last_pose(path)
        self.saves = 0
        self._failing = False

    def _due(self, pose: Pose2D) -> bool:
        last = self.saved
        return last is None or pose.distance_to(last) >= MIN_MOVE_M or \
            abs(wrap_angle(pose.yaw - last.yaw)) >= MIN_TURN_RAD

    def _current(self) -> Pose2D | None:
        est, loc = self.bus.latest(POSE), self.bus.latest(LOCALIZATION)
        if est is None or (loc is not None and loc.state not in ("ok", "off")):
            return None
        return est.pose

    async def save(self, force: bool = False) -> None:
        """Write the current pose if it moved enough (or ``force``) and is trustworthy."""
        pose = self._current()
        if pose is None or not (force or self._due(pose)):
            return
        record = {"x_m": round(pose.x, 4), "y_m": round(pose.y, 4),
                  "yaw_rad": round(pose.yaw, 5), "frame_id": "map",
                  "wall_s": round(self.clock.wall_time(), 3)}
        try:
            await self.clock.offload(atomic_write_json, self.path, record)
        except OSError as exc:  # a full disk: keep the older pose, try again later
            if not self._failing:
                log.warning("cannot save the last pose to %s: %s", self.path, exc)
            self._failing = True
            return
        self._failing = False
        self.saved = pose
        self.saves += 1

    async def run(self) -> None:
        """Save every ``PERIOD_S`` when due, until cancelled."""
        async for _ in self.clock.every(PERIOD_S):
            await self.save()

    async def close(self) -> None:
        """A clean stop: the pose now."""
        await self.save(force=True)
