"""The people tracker on the bus, and what the costmap asks of it.

:class:`PeopleNode` runs the detector and the tracker on every ``/scan`` (placed with the
rover's pose in ``map`` at the scan's stamp) and publishes the confirmed tracks on ``/people``
(stamped with the scan's stamp). It follows ``/map`` (a new map: a new distance field).

The costmap's obstacle layer asks it two things when ``people.aware`` is on (the baseline
marks everyone, as before):

* :meth:`PeopleNode.beams_to_skip` — the beams of a scan that ended on a *walking* person
  (a track that walked and has not stood still for ``standing_mark_s``): they clear along
  their ray but mark nothing, so a walking person leaves no mark at all;
* :meth:`PeopleNode.cleared_spots` — where walking people are and have been (their recent
  trail): marks there are removed, so a mark made before the person was recognised (or
  while they stood) does not stay behind as a ghost that closes a corridor.

A person standing still for longer than ``standing_mark_s`` (a group at an exhibit) is
marked like any obstacle, so the global planner routes round a standing group.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import PeopleConfig
from curio.core.geometry import Pose2D
from curio.core.messages import DriverHealth, GridMessage, LaserScan, PeopleTracks
from curio.core.topics import HEALTH, MAP, PEOPLE, SCAN
from curio.estimation.maps import OccupancyGrid
from curio.people.detect import Detection, Detector, StaticMap
from curio.people.tracker import Track, Tracker
from curio.people.tracking_kernel import beams_near
from curio.robot import RobotModel

__all__ = ["PeopleNode", "seen_through"]

B = npt.NDArray[np.bool_]


def seen_through(scan: LaserScan, laser: Pose2D) -> Callable[[float, float], bool]:
    """Whether the scan saw at least 0.3 m beyond map point (x, y) along its beam (a person
    predicted there would have been seen)."""
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    n = len(ranges)

    def seen(x: float, y: float) -> bool:
        dx, dy = x - laser.x, y - laser.y
        ang = math.atan2(dy, dx) - laser.yaw - scan.angle_min_rad
        i = round(ang / scan.angle_increment_rad) % n
        r = ranges[i]
        if math.isnan(r):
            return False
        return bool(r > math.hypot(dx, dy) + 0.3)  # an inf return saw through, too

    return seen


class PeopleNode:
    """Detects and tracks people on every scan (see the module docstring).

    Args:
        cfg: ``people``.
        robot: the robot model (the laser's pose on the rover).
        bus, clock: injected.
        grid: the static map the tracker starts with.
        pose_at: the rover's pose in ``map`` at a clock stamp (None: not known yet).
    """

    def __init__(self, cfg: PeopleConfig, robot: RobotModel, bus: Bus, clock: Clock,
                 grid: OccupancyGrid, pose_at: Callable[[float], Pose2D | None]) -> None:
        self.cfg = cfg
        self.robot = robot
        self.bus = bus
        self.clock = clock
        self.pose_at = pose_at
        self.static = StaticMap(grid)
        self.detector = Detector(cfg, self.static)
        self.tracker = Tracker(cfg, self.static)
        self.last_stamp = -math.inf
        self.last_detections: list[Detection] = []
        self.scans = 0
        self._cleared_upto = -math.inf
        self._walking_ids: set[int] = set()
        self._angles: tuple[tuple[float, float, int], npt.NDArray[np.float64]] | None = None

    # -- one scan ----------------------------------------------------------------------------
    def process(self, scan: LaserScan) -> bool:
        """Track with ``scan`` unless already done (the costmap may ask first); publish the
        tracks. False when the rover's pose is not known yet."""
        if scan.stamp == self.last_stamp:
            return True
        pose = self.pose_at(scan.stamp)
        if pose is None:
            return False
        self.last_stamp = scan.stamp
        laser = pose @ self.robot.laser_in_base
        self.last_detections = self.detector.detect(scan, laser)
        self.tracker.update(self.last_detections, scan.stamp, seen_through(scan, laser))
        self.scans += 1
        self.bus.publish(PEOPLE, PeopleTracks(scan.stamp,
                                              self.tracker.message_tracks(scan.stamp)))
        return True

    def _walking(self, t: Track, stamp: float) -> bool:
        """Whether a track is a person walking (or only just stopped): not to be marked."""
        if not (t.confirmed and t.walked):
            return False
        return t.still_since_s is None or stamp - t.still_since_s < self.cfg.standing_mark_s

    # -- what the costmap asks ---------------------------------------------------------------
    @property
    def clear_radius_m(self) -> float:
        """Marks this near a walking person's positions are removed (``clear_radius_m``)."""
        return self.cfg.clear_radius_m

    def beams_to_skip(self, scan: LaserScan) -> B | None:
        """Beams of ``scan`` that ended on a walking person (None: nothing to skip)."""
        if not self.process(scan) or scan.stamp != self.last_stamp:
            return None
        beams = [t.beams for t in self.tracker.tracks if self._walking(t, scan.stamp)
                 and len(t.beams)]
        if not beams:
            return None
        mask = np.zeros(len(scan.ranges_m), dtype=bool)
        mask[np.concatenate(beams)] = True
        return mask

    # -- what the localiser asks -------------------------------------------------------------
    def beams_to_ignore(self, scan: LaserScan, laser_in_map: Pose2D) -> B | None:
        """Beams of ``scan`` (its laser at ``laser_in_map``) that end where a person is, not
        evidence about the rover's pose (None: nothing to ignore).

        People are the confirmed tracks that have travelled (moved 0.8 m from where they were
        born), standing or not: furniture the map lacks never travels, even when its velocity
        estimate jitters, so it still counts for or against the pose. Predicted at constant
        velocity to the scan's stamp from the scans tracked before: the localiser asks before
        this scan is tracked, as the rover's pose at its stamp comes from the localiser. A
        beam counts when its end lies within ``person_radius_m`` + 0.15 m of a prediction.
        """
        at = []
        for t in self.tracker.tracks:
            if t.confirmed and t.travelled:
                x, y, vx, vy = t.kf.x[:, 0].tolist()
                ahead = scan.stamp - t.stamp_s
                at.append((x + vx * ahead, y + vy * ahead))
        if not at:
            return None
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        ang = laser_in_map.yaw + self._angles_rad(scan)
        reach = self.cfg.person_radius_m + 0.15
        mask, found = beams_near(scan.valid_mask(), ranges, np.cos(ang), np.sin(ang),
                                 float(laser_in_map.x), float(laser_in_map.y),
                                 np.array(at, dtype=np.float64), float(reach * reach))
        return mask if found else None

    def _angles_rad(self, scan: LaserScan) -> npt.NDArray[np.float64]:
        """``scan.angles_rad``, kept while the scans' geometry stays the same (never
        written to)."""
        key = (scan.angle_min_rad, scan.angle_increment_rad, len(scan.ranges_m))
        if self._angles is None or self._angles[0] != key:
            self._angles = (key, scan.angles_rad)
        return self._angles[1]

    def cleared_spots(self) -> list[tuple[float, float]]:
        """Where walking people have been since the last call (map, m): clear marks there."""
        out: list[tuple[float, float]] = []
        after = self._cleared_upto - 0.5
        walking = set()
        for t in self.tracker.tracks:
            if not self._walking(t, self.last_stamp):
                continue
            walking.add(t.track_id)
            # A person just recognised as walking: their whole recent trail (marked before).
            if t.track_id not in self._walking_ids:
                out += [(x, y) for x, y, _ in t.trail]
            else:
                out += [(x, y) for x, y, s in t.trail if s > after]
            out.append(t.xy)
        self._walking_ids = walking
        self._cleared_upto = self.last_stamp
        return out

    # -- task --------------------------------------------------------------------------------
    def health(self) -> DriverHealth:
        """The tracker's counters."""
        trk = self.tracker
        return DriverHealth(self.clock.now(), "people", "ok", "", counters={
            "scans": float(self.scans), "tracks": float(len(trk.tracks)),
            "confirmed": float(sum(t.confirmed for t in trk.tracks)),
            "births": float(trk.births), "deaths": float(trk.deaths)})

    def _take_map(self, msg: GridMessage) -> None:
        if msg.kind != "map":
            return
        old = self.static.grid
        if (msg.data.shape == old.data.shape and msg.origin == old.origin
                and np.array_equal(msg.data, old.data)):
            return
        grid = OccupancyGrid(np.asarray(msg.data, dtype=np.int8), msg.resolution_m, msg.origin,
                             old.occupied_thresh, old.free_thresh, old.name)
        self.static = StaticMap(grid)
        self.detector.static = self.static
        self.tracker.static = self.static

    async def run(self) -> None:
        """Track on every scan until cancelled; health once a second."""
        scans = self.bus.subscribe(SCAN)
        maps = self.bus.subscribe(MAP)
        last_health = -math.inf
        try:
            async for scan in scans:
                for msg in maps.drain():
                    self._take_map(msg)
                self.process(scan)
                now = self.clock.now()
                if now - last_health >= 1.0:
                    last_health = now
                    self.bus.publish(HEALTH, self.health())
        finally:
            scans.close()
            maps.close()
