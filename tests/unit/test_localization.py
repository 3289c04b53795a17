"""Localisation: distance field, scan matching, tracking with noisy odometry, global search."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from curio.core.config import LocalizationConfig
from curio.core.geometry import Pose2D
from curio.estimation.localization import (
    DistanceField,
    Localizer,
    _kld_bound,
    scan_match,
)
from curio.estimation.maps import OccupancyGrid
from tests.unit.test_localization_helpers import cast_scan, room_grid

LASER = Pose2D(0.152, 0.078, 0.0)


def test_distance_field_measures_distance_to_walls() -> None:
    grid = room_grid()
    field = DistanceField(grid, 2.0)
    # A point right of the left wall (wall cells x in [-1, -0.9), last centre at -0.925).
    d = field.lookup(np.array([0.075]), np.array([4.0]))
    assert d[0] == pytest.approx(1.0, abs=0.06)
    # Far outside the grid: the maximum.
    assert field.lookup(np.array([100.0]), np.array([0.0]))[0] == 2.0
    v, gx, gy = field.lookup_grad(np.array([-0.5]), np.array([3.0]))
    assert v[0] == pytest.approx(0.425, abs=0.03)
    assert gx[0] == pytest.approx(1.0, abs=0.05)   # moving right moves away from the left wall
    assert abs(gy[0]) < 0.05


def test_scan_match_pulls_a_wrong_guess_onto_the_truth() -> None:
    grid = room_grid()
    field = DistanceField(grid, 2.0)
    truth = Pose2D(2.5, 1.5, 0.3)
    scan = cast_scan(grid, truth, LASER)
    pts = scan.points(LASER, max_beams=180)
    m = scan_match(field, pts, Pose2D(2.62, 1.42, 0.35), iterations=15)
    assert m.pose.distance_to(truth) < 0.01
    assert abs(m.pose.yaw - truth.yaw) < math.radians(0.3)
    assert m.inlier_fraction > 0.9


def test_kld_bound_grows_with_bins() -> None:
    k = np.array([1.0, 2.0, 10.0, 100.0])
    n = _kld_bound(k, 0.01, 0.99)
    assert n[0] == 1.0
    assert np.all(np.diff(n) > 0)
    assert n[3] > 4000  # many bins need thousands of particles


def _drive(loc: Localizer, grid, poses, rng, scale=1.05, drift=math.radians(2.0)):  # type: ignore[no-untyped-def]
    """Feed the localiser a path with scaled, drifting odometry; return errors (m, rad)."""
    odom = Pose2D()
    errs = []
    for prev, cur in itertools.pairwise(poses):
        d = prev.inverse() @ cur
        dist = math.hypot(d.x, d.y)
        noisy = Pose2D(d.x * scale, d.y * scale, d.yaw + drift * dist)
        odom = odom @ noisy
        scan = cast_scan(grid, cur, LASER, sigma_m=0.02, dropout=0.02, rng=rng)
        loc.update(scan, odom)
        errs.append((loc.pose.distance_to(cur), abs(math.remainder(loc.pose.yaw - cur.yaw,
                                                                      2 * math.pi))))
    return errs


def _path(n: int = 120) -> list[Pose2D]:
    out = []
    for i in range(n):
        t = i / n * 2 * math.pi
        out.append(Pose2D(4.0 + 2.5 * math.cos(t), 3.0 + 1.8 * math.sin(t), t + math.pi / 2))
    return out


def test_tracks_a_loop_with_noisy_odometry_to_centimetres() -> None:
    grid = room_grid()
    rng = np.random.default_rng(3)
    path = _path()
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=1)
    loc.initialize(Pose2D(path[0].x + 0.1, path[0].y - 0.1, path[0].yaw + 0.05))
    errs = _drive(loc, grid, path, rng)
    pos = np.array([e[0] for e in errs[10:]])
    yaw = np.array([e[1] for e in errs[10:]])
    assert math.sqrt(np.mean(pos**2)) < 0.03
    assert math.sqrt(np.mean(yaw**2)) < math.radians(1.0)
    assert loc.state == "ok"
    assert loc.cfg.min_particles <= len(loc.particles) <= 1000


def test_pure_particle_filter_without_scan_matching_still_tracks() -> None:
    grid = room_grid()
    rng = np.random.default_rng(4)
    path = _path()
    cfg = LocalizationConfig(scan_match=False)
    loc = Localizer(grid, cfg, LASER, seed=2)
    loc.initialize(path[0])
    errs = _drive(loc, grid, path, rng)
    assert max(e[0] for e in errs[10:]) < 0.25


def _kidnap(loc: Localizer, rng: np.random.Generator, steps: int = 80) -> tuple[list[str], Pose2D]:
    grid = loc.grid
    path = _path(60)
    loc.initialize(path[0])
    _drive(loc, grid, path[:20], rng)
    assert loc.state == "ok"
    # Teleport: the odometry keeps counting from where it was, the scans come from elsewhere.
    far = [Pose2D(9.5 + 0.02 * i, 3.5 + 0.01 * i, 2.0 + 0.01 * i) for i in range(steps)]
    odom = Pose2D(5, 5, 0)
    states = []
    for i, cur in enumerate(far):
        odom = odom @ Pose2D(0.0202 if i else 0.0, 0.0, 0.01)
        loc.update(cast_scan(grid, cur, LASER, sigma_m=0.02, rng=rng), odom)
        states.append(loc.state)
    return states, far[-1]


def test_kidnapped_rover_relocalises() -> None:
    loc = Localizer(room_grid(), LocalizationConfig(), LASER, seed=3)
    states, truth = _kidnap(loc, np.random.default_rng(5))
    assert states[0] != "ok"
    assert loc.state == "ok"
    # The filter updates every 5 cm of travel, so its pose may lag the last scan by 2 steps.
    assert loc.pose.distance_to(truth) < 0.1


def test_kidnapped_rover_without_recovery_is_declared_lost() -> None:
    cfg = LocalizationConfig(auto_relocalize=False, recovery_alpha_fast=0.0,
                             recovery_alpha_slow=0.0)
    loc = Localizer(room_grid(), cfg, LASER, seed=3)
    states, truth = _kidnap(loc, np.random.default_rng(5), steps=30)
    assert states[-1] == "lost"
    assert loc.pose.distance_to(truth) > 1.0


def test_lost_rover_with_global_search_relocalises() -> None:
    cfg = LocalizationConfig(recovery_alpha_fast=0.0, recovery_alpha_slow=0.0,
                             global_poses_per_scan=20000)
    loc = Localizer(room_grid(), cfg, LASER, seed=3)
    states, truth = _kidnap(loc, np.random.default_rng(5))
    assert "lost" in states
    assert loc.state == "ok"
    assert loc.pose.distance_to(truth) < 0.1


def _parked_then_carried(cfg: LocalizationConfig, scans: int) -> tuple[list[str], Pose2D,
                                                                         Localizer]:
    """Track a drive, stand still, then the scans come from elsewhere while the odometry
    stands (the rover lifted and put down): 10 scans per second of scan time."""
    grid = room_grid()
    rng = np.random.default_rng(5)
    loc = Localizer(grid, cfg, LASER, seed=3)
    path = _path(60)
    loc.initialize(path[0])
    _drive(loc, grid, path[:20], rng)
    odom = loc._last_odom  # where the odometry stops
    assert odom is not None
    truth = Pose2D(9.5, 3.5, 2.0)
    states = []
    for i in range(scans):
        at = path[19] if i < 20 else truth
        loc.update(cast_scan(grid, at, LASER, sigma_m=0.02, rng=rng, stamp=0.1 * i), odom)
        states.append(loc.state)
    return states, truth, loc


def test_a_rover_carried_away_while_standing_still_is_noticed_and_found() -> None:
    """The filter skips scans without motion; a poor fit at a standstill still counts."""
    states, truth, loc = _parked_then_carried(LocalizationConfig(), 120)
    assert states[19] == "ok"  # parked, still fitting
    assert "lost" in states[20:40]  # within 2 s of scan time
    assert loc.state == "ok"  # the search found it where it stands
    assert loc.pose.distance_to(truth) < 0.1


def test_a_parked_rover_whose_scan_fits_is_not_updated() -> None:
    """Standing still with a scan that fits: no filter update (no overconfidence from one
    repeated view), only the periodic check."""
    _, _, loc = _parked_then_carried(LocalizationConfig(), 20)
    before = loc.updates
    grid = loc.grid
    rng = np.random.default_rng(9)
    odom = loc._last_odom
    assert odom is not None
    for i in range(30):
        loc.update(cast_scan(grid, _path(60)[19], LASER, sigma_m=0.02, rng=rng,
                             stamp=2.0 + 0.1 * i), odom)
    assert loc.updates == before
    assert loc.state == "ok"


def test_global_localization_finds_the_pose() -> None:
    grid = room_grid()
    rng = np.random.default_rng(6)
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=4)
    loc.global_localization()
    truth = Pose2D(7.5, 2.0, -2.5)
    odom = Pose2D()
    for i in range(40):
        cur = truth @ Pose2D(0.03 * i, 0.0, 0.0)
        odom = Pose2D(0.03 * i, 0.0, 0.0)
        loc.update(cast_scan(grid, cur, LASER, sigma_m=0.02, rng=rng), odom)
    assert loc.state == "ok"
    assert loc.pose.distance_to(truth @ Pose2D(0.03 * 39, 0, 0)) < 0.05


def test_long_middling_fit_rechecks_the_map_and_keeps_a_right_pose() -> None:
    """A noisy lidar (8 cm) puts some ends past the walls, which keeps the fit below
    ok_inlier_fraction; after recheck_after_scans updates a global search runs, and the right
    current pose survives it. (Clutter the map lacks would not: a beam that stops in front of
    the map is no evidence about the pose, see the crowd test below.)"""
    grid = room_grid()
    cfg = LocalizationConfig(ok_inlier_fraction=0.99, recheck_after_scans=3,
                             global_poses_per_scan=50000)
    loc = Localizer(grid, cfg, LASER, seed=5)
    rng = np.random.default_rng(11)
    path = _path(60)
    loc.initialize(path[0])
    fits = []
    errs = []
    for k in range(1, 40):
        odom = path[0].inverse() @ path[k]
        # (The test path grazes the partition wall: a scan from inside it has no valid beam
        # and no update; only updated poses are scored.)
        if loc.update(cast_scan(grid, path[k], LASER, sigma_m=0.08, rng=rng), odom):
            fits.append(loc.inlier_fraction)
            errs.append(loc.pose.distance_to(path[k]))
    assert max(fits) < 0.99
    assert loc.searches >= 1
    assert max(errs[5:]) < 0.05


def _crowd_around(grid: OccupancyGrid, centre: Pose2D, count: int, seed: int,
                  within_m: tuple[float, float] = (0.6, 1.6)) -> OccupancyGrid:
    """``grid`` with ``count`` people (discs of 0.2 m radius) standing ``within_m`` around
    ``centre``: the world's grid; the map stays without them."""
    rng = np.random.default_rng(seed)
    world = grid.copy()
    res = grid.resolution_m
    rows, cols = np.mgrid[0:grid.height, 0:grid.width]
    xs = grid.origin.x + (cols + 0.5) * res
    ys = grid.origin.y + (rows + 0.5) * res
    for k in range(count):
        ang = 2 * math.pi * k / count + rng.uniform(-0.2, 0.2)
        dist = rng.uniform(*within_m)
        px, py = centre.x + dist * math.cos(ang), centre.y + dist * math.sin(ang)
        world.data[(xs - px) ** 2 + (ys - py) ** 2 <= 0.2**2] = 100
    return world


@pytest.mark.parametrize("seed", range(6))
def test_a_crowd_hiding_most_of_the_walls_at_the_right_pose_is_not_lost(seed: int) -> None:
    """Crowd benchmark finding (`curio bench crowd`, curio_shapes, 20 visitors, jobs 100111,
    100115, 100125): visitors around the start hid two thirds of the beams; the share on a wall
    (0.31–0.38) read ``lost`` after five scans at the right pose, and the search moved the
    estimate 14–17 m to a place that fitted better by chance. A beam that stops on something
    narrow in known-free space in front of the map is explained (half a beam on a wall), and
    such beams do not weigh the particles: the rover stays where it is. Here 14 people stand
    around it and hide three quarters of the beams; before, every seed went ``lost`` and ended
    2.6–3.6 m off."""
    grid = room_grid()
    truth = Pose2D(4.0, 3.5, 0.3)
    world = _crowd_around(grid, truth, 14, seed)
    assert np.mean(cast_scan(world, truth, LASER).ranges_m
                   < cast_scan(grid, truth, LASER).ranges_m - 0.3) > 0.7
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=seed)
    rng = np.random.default_rng(seed + 10)
    loc.initialize(truth)
    states = []
    for k in range(30):
        odom = Pose2D(0.02 * k, 0.0, 0.0)  # creeping forward among them
        loc.update(cast_scan(world, truth @ odom, LASER, sigma_m=0.02, rng=rng), odom)
        states.append(loc.state)
    assert "lost" not in states
    assert loc.searches == 0
    assert loc.pose.distance_to(truth @ Pose2D(0.58, 0.0, 0.0)) < 0.3


def _one_box_hall(resolution_m: float = 0.05) -> OccupancyGrid:
    """A 20 m × 20 m hall with no walls and one 1 m box: from its corner, 9 m from the box,
    nothing else is in the lidar's range (the corner of the curio_shapes map)."""
    n = round(20.0 / resolution_m)
    data = np.zeros((n, n), dtype=np.int8)
    data[round(8.0 / resolution_m):round(9.0 / resolution_m),
         round(5.5 / resolution_m):round(6.5 / resolution_m)] = 100
    return OccupancyGrid(data, resolution_m, Pose2D(0.0, 0.0, 0.0), name="hall")


@pytest.mark.parametrize("seed", range(16))
def test_seeing_one_distant_box_the_estimate_follows_the_odometry_instead_of_jumping(
        seed: int) -> None:
    """Nav benchmark finding (`curio bench nav`, curio_shapes, seed 1050): ten beams on one
    box 9 m away pin the pose down along some directions only. The particle cloud smeared
    along the others until its heaviest 0.5 m bin held less than 80 % of the weight; the
    estimate then left the odometry's prediction for the heaviest part of the smear, 0.7 m
    off, and the tree took the jump for being lost and dropped the goal. Turning on the spot,
    then driving 4.5 m with 2 % odometry error: before, seeds 11 and 14 ended 0.9 and 0.7 m
    off the truth on the way."""
    grid = _one_box_hall()
    rng = np.random.default_rng(seed + 20)
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=seed)
    start = Pose2D(1.2, 1.1, -1.0)
    loc.initialize(start)
    poses = [Pose2D(1.2, 1.1, -1.0 + 0.1 * k) for k in range(12)]
    poses += [poses[-1] @ Pose2D(0.03 * k, 0.0, 0.0) for k in range(1, 150)]
    errors, states = [], set()
    for truth in poses:
        rel = start.inverse() @ truth
        odom = Pose2D(rel.x * 1.02, rel.y * 1.02, rel.yaw * 1.01)
        loc.update(cast_scan(grid, truth, LASER, sigma_m=0.02, rng=rng), odom)
        errors.append(loc.pose.distance_to(truth))
        states.add(loc.state)
    assert max(errors) < 0.3
    assert "lost" not in states and loc.searches == 0


@pytest.mark.parametrize("people", [0, 8])
def test_a_rover_carried_to_the_other_room_is_lost_with_or_without_people(people: int) -> None:
    """Ends in front of the map do not vouch for a pose when they lie on a wide surface: carried
    into the other room, half the beams end in the free space of the old one, on its walls
    (not narrow like a person), and the old pose still fits poorly — also with people around
    the rover, whose ends do count as explained."""
    grid = room_grid()
    before, after = Pose2D(3.0, 4.5, 0.0), Pose2D(9.0, 3.5, 2.0)
    world = _crowd_around(grid, after, people, seed=5, within_m=(0.8, 2.0))
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=6)
    rng = np.random.default_rng(7)
    loc.initialize(before)
    states = []
    for k in range(12):
        odom = Pose2D(0.02 * k, 0.0, 0.0)
        loc.update(cast_scan(world, after @ odom, LASER, sigma_m=0.02, rng=rng), odom)
        states.append(loc.state)
    assert "lost" in states
    assert loc.searches >= 1


def test_a_parked_rover_carried_to_a_place_that_fits_middling_is_found() -> None:
    """Soak finding (2026-12-02, `curio soak --hours 3 --start 09:00 --clients 3 --faults 30
    --kinds kidnap,kidnap_parked --seed 11`, fault 18): in the default building a parked rover
    carried from (9.73, -1.07) to (18.98, -1.48) fits its old pose middling (~0.58 of the
    beams: above lost_inlier_fraction, below ok_inlier_fraction). The filter does not update
    standing still and the stationary check only acted on a poor fit, so the localiser stayed
    ``uncertain`` 9 m off for good: never lost, no search, no help. Now the stationary checks
    count a middling fit and start the whole-map re-check, also within the guard after a set
    pose (the soak's rover had been relocalised 1.5 s before)."""
    from curio.core.config import REPO_ROOT
    from curio.estimation.maps import load_map

    grid = load_map(REPO_ROOT / "maps" / "curio_building.yaml")
    # The defaults: the pose was just set (as the tree sets it after an earlier kidnap) and
    # the rover has not driven since, so the re-check's guard after a set pose
    # (recheck_after_set_m) must not hold it once the filter was ok there.
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=1)
    rng = np.random.default_rng(1)
    parked = Pose2D(9.73, -1.07, -0.39)
    loc.initialize(parked)
    odom, t = Pose2D(), 0.0
    for _ in range(30):  # turn on the spot: the filter settles on the parked pose
        t += 0.1
        parked = parked @ Pose2D(0.0, 0.0, 0.1)
        odom = odom @ Pose2D(0.0, 0.0, 0.1)
        loc.update(cast_scan(grid, parked, LASER, sigma_m=0.02, rng=rng, stamp=t), odom)
    assert loc.state == "ok" and loc.pose.distance_to(parked) < 0.05
    truth = Pose2D(18.98, -1.48, 2.63)
    states = []
    for _ in range(450):  # 45 s standing at the truth, the odometry still
        t += 0.1
        loc.update(cast_scan(grid, truth, LASER, sigma_m=0.02, rng=rng, stamp=t), odom)
        states.append(loc.state)
    assert "ok" not in states[:20]  # the middling fit is not trusted meanwhile
    assert loc.searches == 1
    assert loc.state == "ok"
    assert loc.pose.distance_to(truth) < 0.05


def test_a_global_search_never_puts_the_rover_off_the_map() -> None:
    """A map without border walls: a wall segment at its west rim. Seen from 1.7 m east of
    it (the truth) or from 1.7 m west (outside the map, facing the other way), the scan fits
    the same; the search's hypotheses are only poses on free cells of the map."""
    from curio.estimation.localization import _GlobalSearch
    from curio.estimation.maps import OccupancyGrid

    data = np.zeros((200, 200), dtype=np.int8)
    data[80:120, 5:7] = 100  # x 0.25..0.35 m, y 4..6 m
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    truth = Pose2D(2.0, 5.0, math.pi)
    mirror = Pose2D(0.25 - 1.65, 5.0 - 2 * 0.078, 0.0)  # as far west of its west face
    scan = cast_scan(grid, truth, LASER)
    loc = Localizer(grid, LocalizationConfig(), LASER, seed=3)
    loc.initialize(Pose2D(6.0, 5.0, 0.0))
    assert loc._fit(scan.points(LASER), mirror) > 0.9  # the look-alike outside fits as well
    top = np.array([[*mirror.as_tuple(), 1.0], [*truth.as_tuple(), 1.0]])
    loc.search = _GlobalSearch(top[:, :2].copy(), np.zeros(1), np.zeros(2, dtype=np.int32),
                               next_index=2, top=top)
    loc._finish_search(scan)
    assert loc.pose.distance_to(truth) < 0.1
    assert (loc.particles[:, 0] > 0.0).all()
