"""The people tracker on scripted crossings: one person, two crossing, a group side by side;
clean birth and death; the map's walls are not people; the CLEAR MOT figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import LaserScan, PeopleTracks, SimPeople, SimPerson
from curio.estimation.maps import OccupancyGrid
from curio.people.detect import Detector, StaticMap
from curio.people.metrics import MotAccumulator
from curio.people.node import seen_through
from curio.people.tracker import Tracker
from curio.sim.crowd_kernel import count_hits
from curio.sim.raycast import GridRaycaster, cast_circles

BEAMS = 360
INC = 2.0 * math.pi / BEAMS
DT = 0.1


def room(size_m: float = 14.0, res: float = 0.05) -> OccupancyGrid:
    """A square room with walls, centred on the origin, and a pillar at (-3, 3)."""
    n = int(size_m / res)
    data = np.zeros((n, n), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    c = int((3.0 + size_m / 2) / res)
    data[c - 4:c + 4, int((-3.0 + size_m / 2) / res) - 4:int((-3.0 + size_m / 2) / res) + 4] = 100
    return OccupancyGrid(data, res, Pose2D(-size_m / 2, -size_m / 2, 0.0))


class Walker:
    """A person walking a straight line at constant velocity, seen as two swinging legs."""

    def __init__(self, start: tuple[float, float], velocity: tuple[float, float]) -> None:
        self.start, self.velocity = np.array(start), np.array(velocity)

    def at(self, t: float) -> np.ndarray:
        return self.start + self.velocity * t

    def legs(self, t: float) -> np.ndarray:
        x, y = self.at(t)
        speed = float(np.hypot(*self.velocity))
        h = math.atan2(self.velocity[1], self.velocity[0]) if speed > 0 else 0.0
        swing = 0.15 * min(1.0, speed) * math.sin(2.0 * math.pi * speed * t / 1.3)
        c, s = math.cos(h), math.sin(h)
        return np.array([(x + sg * (c * swing - s * 0.1), y + sg * (s * swing + c * 0.1), 0.06)
                         for sg in (1.0, -1.0)])


def scan_of(grid: OccupancyGrid, laser: Pose2D, walkers: list[Walker], t: float,
            rng: np.random.Generator) -> tuple[LaserScan, np.ndarray]:
    """A scan at time ``t`` (2 cm noise) and its end points in map."""
    ang = -math.pi + np.arange(BEAMS) * INC + laser.yaw
    r = GridRaycaster(grid).cast(laser.x, laser.y, ang, 12.0)
    if walkers:
        circles = np.concatenate([w.legs(t) for w in walkers])
        r = np.minimum(r, cast_circles(laser.x, laser.y, np.cos(ang), np.sin(ang), circles))
    r = r + rng.normal(0.0, 0.02, BEAMS)
    r[~np.isfinite(r) | (r > 12.0)] = np.inf
    ok = np.isfinite(r)
    pts = np.column_stack([laser.x + r[ok] * np.cos(ang[ok]), laser.y + r[ok] * np.sin(ang[ok])])
    return LaserScan(t, -math.pi, INC, 0.15, 12.0, r.astype(np.float32)), pts


def track(cfg: Config, walkers: list[Walker], seconds: float, laser: Pose2D = Pose2D(),
          hide_after_s: float = math.inf) -> tuple[list[PeopleTracks], MotAccumulator, Tracker]:
    """Run detector and tracker for ``seconds``; score against the walkers' truth."""
    grid = room()
    static = StaticMap(grid)
    detector, tracker = Detector(cfg.people, static), Tracker(cfg.people, static)
    mot = MotAccumulator()
    rng = np.random.default_rng(7)
    frames = []
    for k in range(int(seconds / DT)):
        t = k * DT
        shown = walkers if t < hide_after_s else []
        scan, pts = scan_of(grid, laser, shown, t, rng)
        tracker.update(detector.detect(scan, laser), t, seen_through(scan, laser))
        msg = PeopleTracks(t, tracker.message_tracks(t))
        frames.append(msg)
        centres = np.array([w.at(t) for w in shown]).reshape(-1, 2)
        hits = np.zeros(len(centres), dtype=np.int64)
        count_hits(np.ascontiguousarray(pts), centres, 0.3, hits)
        truth = SimPeople(t, tuple(
            SimPerson(i + 1, *map(float, w.at(t)), *map(float, w.velocity), 0.2,
                      visible_beams=int(h)) for i, (w, h) in enumerate(zip(shown, hits,
                                                                         strict=True))))
        mot.add(truth, msg, (laser.x, laser.y))
    return frames, mot, tracker


def test_one_person_crossing(cfg: Config) -> None:
    """One person crosses 4 m in front of the rover at 1 m/s: confirmed within half a second,
    one id all the way, position within 7 cm on average (15 cm at worst: legs 5 m away are
    hit by two or three beams), velocity within 0.1 m/s on average (0.3 m/s at worst, when
    one leg hides the other) from 1.5 s on."""
    walker = Walker((4.0, -4.0), (0.0, 1.0))
    frames, mot, _ = track(cfg, [walker], 8.0)
    first = next(k for k, f in enumerate(frames) if f.tracks)
    assert first * DT <= 0.5
    ids = {t.track_id for f in frames for t in f.tracks}
    assert len(ids) == 1
    later = [(k * DT, f.tracks[0]) for k, f in enumerate(frames) if k * DT >= 1.5 and f.tracks]
    assert later
    errors, off = [], []
    for t, tr in later:
        x, y = walker.at(t)
        off.append(math.hypot(tr.x_m - x, tr.y_m - y))
        errors.append(math.hypot(tr.vx_mps - 0.0, tr.vy_mps - 1.0))
        assert tr.moving and tr.walked
    assert np.mean(off) < 0.07 and max(off) < 0.15
    assert np.mean(errors) < 0.1 and max(errors) < 0.3
    assert mot.mota is not None and mot.mota >= 0.95
    assert mot.switches == 0


def test_a_track_dies_cleanly_when_the_person_is_gone(cfg: Config) -> None:
    """The person is no longer there (the scan sees through where they would be): the track
    goes within tentative_coast_s plus a scan; never a ghost coasting on."""
    walker = Walker((4.0, -2.0), (0.0, 1.0))
    frames, _mot, tracker = track(cfg, [walker], 5.0, hide_after_s=2.0)
    gone = next(k * DT for k, f in enumerate(frames) if k * DT >= 2.0 and not f.tracks)
    assert gone <= 2.0 + cfg.people.tentative_coast_s + DT + 1e-9
    assert not tracker.tracks
    assert tracker.births == tracker.deaths


def test_two_people_crossing_keep_their_ids(cfg: Config) -> None:
    """Two people walk an X and pass each other 0.6 m apart (centre to centre, their legs
    0.3 m apart): two tracks, and each keeps its person."""
    a = Walker((2.0, -2.0), (0.8, 0.8))
    b = Walker((2.6, 2.6), (0.8, -0.8))
    frames, mot, _ = track(cfg, [a, b], 5.0)
    assert mot.switches == 0
    assert mot.mota is not None and mot.mota >= 0.9
    end = frames[-1]
    assert len(end.tracks) == 2
    for tr in end.tracks:
        ends = [w.at(end.stamp) for w in (a, b)]
        assert min(math.hypot(tr.x_m - x, tr.y_m - y) for x, y in ends) < 0.3
    # The track that ended on a started where a started (identities were not swapped).
    first_a = min((f for f in frames if len(f.tracks) == 2), key=lambda f: f.stamp)
    start_id = min(first_a.tracks, key=lambda tr: math.hypot(tr.x_m - a.at(first_a.stamp)[0],
                                                             tr.y_m - a.at(first_a.stamp)[1]))
    end_id = min(end.tracks, key=lambda tr: math.hypot(tr.x_m - a.at(end.stamp)[0],
                                                       tr.y_m - a.at(end.stamp)[1]))
    assert start_id.track_id == end_id.track_id


def test_a_group_side_by_side(cfg: Config) -> None:
    """Three people walk abreast, 0.6 m apart: three tracks, not one or two."""
    group = [Walker((1.5, -0.6 + k * 0.6), (0.8, 0.0)) for k in range(3)]
    frames, mot, _ = track(cfg, group, 5.0)
    counts = [len(f.tracks) for f in frames[10:]]
    assert np.mean([c == 3 for c in counts]) >= 0.9
    assert mot.mota is not None and mot.mota >= 0.9


@pytest.mark.parametrize("laser", [Pose2D(), Pose2D(2.0, -1.0, 1.2)])
def test_walls_and_pillars_of_the_map_are_not_people(cfg: Config, laser: Pose2D) -> None:
    """An empty room with a mapped pillar: no detection, no track."""
    frames, mot, tracker = track(cfg, [], 3.0, laser)
    assert not any(f.tracks for f in frames)
    assert tracker.births == 0
    assert mot.false_positives == 0
