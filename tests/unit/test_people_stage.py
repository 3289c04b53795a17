"""The controller's people stage: yielding to a head-on walker, never driving at a person,
"Excuse me" instead of freezing, keeping the chosen arc when nobody minds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import PeopleTracks, PersonTrack
from curio.nav.controller import ControlStatus, LocalController
from curio.nav.costmap import Costmap
from curio.people.stage import PeopleStage
from curio.robot import RobotModel
from curio.safety.stop_zone import polygon_distances
from tests.unit.test_controller import drive_arc, open_grid, straight_plan

BODY_M = 0.2  # the walker's real body radius (the stage assumes people.person_radius_m)


class Walker:
    """A scripted person: walks from ``start`` at ``velocity`` (m/s) after ``delay_s``."""

    def __init__(self, start: tuple[float, float], velocity: tuple[float, float],
                 delay_s: float = 0.0) -> None:
        self.start, self.velocity, self.delay_s = start, velocity, delay_s

    def at(self, t: float) -> tuple[float, float, float, float]:
        dt = max(0.0, t - self.delay_s)
        moving = t >= self.delay_s
        vx, vy = self.velocity if moving else (0.0, 0.0)
        return (self.start[0] + self.velocity[0] * dt, self.start[1] + self.velocity[1] * dt,
                vx, vy)


def run(ctrl: LocalController, pose: Pose2D, walkers: list[Walker], seconds: float,
        stage: PeopleStage | None) -> tuple[Pose2D, list, float]:
    """Drive the controller with perfect tracks of ``walkers``; return the final pose, the
    log and the smallest footprint-to-body distance."""
    now = {"t": 0.0}
    footprint = np.asarray(ctrl.robot.footprint_points)

    def tracks() -> PeopleTracks:
        t = now["t"]
        return PeopleTracks(t, tuple(PersonTrack(k + 1, *w.at(t), walked=True)
                                     for k, w in enumerate(walkers)))

    if stage is not None:
        stage.tracks = tracks
    ctrl.people = stage
    dt = ctrl.dt_s
    log = []
    closest = math.inf
    for _ in range(int(seconds / dt)):
        t = now["t"]
        out = ctrl.compute(pose, t)
        log.append((t, pose, out))
        xy = np.array([w.at(t)[:2] for w in walkers])
        d = polygon_distances(pose.inverse().transform_points(xy), footprint) - BODY_M
        closest = min(closest, float(d.min()))
        if out.status is ControlStatus.GOAL_REACHED:
            break
        pose = drive_arc(pose, out.linear_mps, out.angular_radps, dt)
        now["t"] = t + dt
    return pose, log, closest


@pytest.fixture
def parts(cfg: Config) -> tuple[LocalController, PeopleStage, Config]:
    robot = RobotModel.from_config(cfg.robot)
    cm = Costmap(open_grid(12.0), robot, cfg.nav.costmap)
    ctrl = LocalController(cfg.nav.controller, robot, cm)
    ctrl.set_plan(straight_plan(-4.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
    return ctrl, stage, cfg


def test_yields_to_a_head_on_walker_and_then_goes_on(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """A walker comes down the rover's path (0.3 m off its centre line) at 0.9 m/s and never
    swerves: the rover gets out of the way (bends aside, waits) and keeps its distance — at
    least 0.25 m edge to edge, where a rover that did nothing would be walked into — then
    reaches its goal. (The stage keeps min_distance_m to a body of person_radius_m = 0.25 m
    round the track; this walker's body is 0.2 m.)"""
    ctrl, stage, cfg = parts
    walker = Walker((4.5, 0.3), (-0.9, 0.0), delay_s=2.0)
    pose, log, closest = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [walker], 90.0, stage)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert pose.distance_to(Pose2D(4.0, 0.0)) <= cfg.nav.controller.xy_goal_tolerance_m + 0.01
    assert closest >= 0.25, closest
    # It gave way: stepped off the line while the walker came, or waited for them.
    near = [(p, o) for t, p, o in log if abs(walker.at(t)[0] - p.x) < 2.5]
    assert max(abs(p.y) for p, _ in near) > 0.3 or min(o.linear_mps for _, o in near) < 0.05
    assert any(o.status in (ControlStatus.AVOIDING, ControlStatus.YIELDING) for _, o in near)


def test_without_the_stage_the_walker_is_run_into(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """The same walk without the people stage: nothing keeps the distance (the test above
    would catch a stage that does nothing)."""
    ctrl, _stage, _cfg = parts
    walker = Walker((4.5, 0.3), (-0.9, 0.0), delay_s=2.0)
    _pose, _log, closest = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [walker], 20.0, None)
    assert closest < 0.0


def test_a_fast_walker_beside_the_path_is_passed_with_room_for_the_prediction(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """Someone walks down beside the rover's path at 1.2 m/s, 0.7 m off its centre line: the
    rover passes them at about the passing distance (0.497 m), because the room it asks for
    grows with how far ahead they are predicted (``prediction_growth_mps``); without that
    growth it passed at 0.375 m, its comfortable distance eaten by the prediction's drift."""
    ctrl, stage, cfg = parts
    walker = Walker((4.5, 0.7), (-1.2, 0.0), delay_s=1.0)
    _pose, log, closest = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [walker], 90.0, stage)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert closest >= cfg.people.passing_distance_m - 0.05, closest
    assert log[-1][0] < 30.0  # and no slower for it (26.8 s without the growth)


def test_passes_a_standing_person_at_a_comfortable_distance(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """Someone stands just beside the path (driving straight on would brush them): the rover
    bends away and passes at about the passing distance. (Someone standing *on* the path is
    the planner's: a person who stands still is marked in the costmap.)"""
    ctrl, stage, cfg = parts
    person = Walker((0.0, 0.6), (0.0, 0.0))
    _pose, log, closest = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [person], 90.0, stage)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert closest >= cfg.people.passing_distance_m - 0.1, closest
    ctrl.reset()
    ctrl.set_plan(straight_plan(-4.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    _pose, _log, straight = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [person], 90.0, None)
    assert straight < 0.15  # without the stage it passes far too close


def test_never_drives_at_a_person_and_says_excuse_me(cfg: Config) -> None:
    """In a corridor too narrow to pass, someone stands in the way: the rover stops short,
    waits, says "Excuse me" after excuse_me_after_s, and never comes nearer than
    min_distance_m."""
    robot = RobotModel.from_config(cfg.robot)
    grid = open_grid(12.0)
    res = grid.resolution_m
    data = grid.data.copy()
    n = data.shape[0]
    centre = n // 2
    half = round(0.75 / res)  # a 1.5 m corridor along x
    data[: centre - half, :] = 100
    data[centre + half:, :] = 100
    grid = type(grid)(data, res, grid.origin)
    cm = Costmap(grid, robot, cfg.nav.costmap)
    ctrl = LocalController(cfg.nav.controller, robot, cm)
    ctrl.set_plan(straight_plan(-4.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
    said: list[str] = []
    stage.on_excuse_me.append(said.append)
    person = Walker((1.0, 0.0), (0.0, 0.0))
    _pose, log, closest = run(ctrl, Pose2D(-3.0, 0.0, 0.0), [person], 25.0, stage)
    assert closest >= cfg.people.min_distance_m, closest
    assert said and said[0] == cfg.people.excuse_me_text
    assert any(o.status is ControlStatus.YIELDING for _, _, o in log)


def test_keeps_the_arc_when_nobody_minds(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """People far off the path do not change a single command."""
    ctrl, stage, _cfg = parts
    far = Walker((0.0, 3.5), (0.3, 0.0))
    _pose, with_stage, _ = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [far], 40.0, stage)
    ctrl.reset()
    ctrl.set_plan(straight_plan(-4.0, 4.0), Pose2D(4.0, 0.0, 0.0))
    _pose, without, _ = run(ctrl, Pose2D(-4.0, 0.0, 0.0), [far], 40.0, None)
    assert [o.linear_mps for _, _, o in with_stage] == [o.linear_mps for _, _, o in without]


@pytest.mark.parametrize("count", [1, 2, 3])
def test_the_kernels_get_dense_arrays_whatever_the_number_of_people(
        parts: tuple[LocalController, PeopleStage, Config], count: int,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """numba compiles a kernel once per array layout, and a slice's layout depends on its shape
    (one person makes ``people[:, :4]`` contiguous, two do not). The stage passes C-contiguous
    arrays only, so the one variant ``curio warmup`` compiles is the only one ever called —
    before, a kidnap with one tracked person compiled new variants inside the running loop."""
    import curio.people.stage as stage_module

    seen: list[tuple[str, bool]] = []

    def recording(name: str, kernel: object) -> object:
        def call(*args: object) -> None:
            seen.extend((name, a.flags.c_contiguous) for a in args if isinstance(a, np.ndarray))
            kernel(*args)  # type: ignore[operator]
        return call

    monkeypatch.setattr(stage_module, "people_clearances",
                        recording("people_clearances", stage_module.people_clearances))
    monkeypatch.setattr(stage_module, "path_clearances",
                        recording("path_clearances", stage_module.path_clearances))
    ctrl, stage, _cfg = parts
    walkers = [Walker((1.0 + k, 0.6), (-0.5, 0.0)) for k in range(count)]
    run(ctrl, Pose2D(-4.0, 0.0, 0.0), walkers, 3.0, stage)
    assert seen, "the stage never called its kernels"
    assert all(dense for _, dense in seen), sorted({n for n, d in seen if not d})


def test_a_track_on_a_rover_the_fleet_knows_is_not_a_person(
        parts: tuple[LocalController, PeopleStage, Config]) -> None:
    """The lidar sees another rover and the tracker makes a track of it; the fleet link says a
    rover stands there: it is not a person (the right-of-way rule deals with it). Before, the
    rover with the right of way yielded to the one holding at the doorway's staging point —
    `curio bench fleet` seed 7 deadlocked."""
    _ctrl, stage, _cfg = parts
    on_rover = PersonTrack(1, 1.0, 0.1, 0.0, 0.0, walked=True)
    person = PersonTrack(2, 1.5, -1.0, 0.0, 0.0, walked=True)
    stage.tracks = lambda: PeopleTracks(0.0, (on_rover, person))
    here = Pose2D(0.0, 0.0, 0.0)
    assert len(stage.people_near(here, 0.0)) == 2  # no fleet: both count
    stage.rovers = lambda: np.array([[1.05, 0.0, 0.45]])
    near = stage.people_near(here, 0.0)
    assert len(near) == 1 and tuple(near[0, :2]) == (1.5, -1.0)


def test_making_room_to_turn_never_drives_at_a_person(cfg: Config) -> None:
    """Wedged along a wall with its goal behind it, the rover must drive an arc to make room
    to turn. Someone stands ahead of it: it backs out instead of driving on at them."""
    from tests.unit.test_controller import wedged

    _cm, ctrl, start = wedged(cfg)
    stage = PeopleStage(cfg.people, cfg.nav.controller, ctrl.robot, lambda: None)
    ahead = Walker((0.95, 0.25), (0.0, 0.0))
    _pose, log, closest = run(ctrl, start, [ahead], 120.0, stage)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    assert not any(o.detail == "driving on to make room to turn" for _t, _p, o in log)
    assert closest >= _gap(ctrl, start, ahead) - 0.01, closest


def test_with_people_on_both_sides_it_waits_to_make_room(cfg: Config) -> None:
    """The same wedge with someone ahead *and* someone behind: no arc keeps clear of them, so
    the rover waits ("waiting for people to pass before making room to turn", yielding:
    the progress checks pause) instead of driving at either; once they walk off it makes
    room, turns and reaches its goal. Before, the manoeuvre was the one motion the people
    stage never saw (in the crowd benchmark it backed to 0.19 m of passing visitors)."""
    from tests.unit.test_controller import wedged

    _cm, ctrl, start = wedged(cfg)
    stage = PeopleStage(cfg.people, cfg.nav.controller, ctrl.robot, lambda: None)
    ahead = Walker((0.95, 0.25), (0.0, 1.0), delay_s=12.0)
    behind = Walker((-0.95, 0.25), (0.0, 1.0), delay_s=12.0)
    _pose, log, closest = run(ctrl, start, [ahead, behind], 120.0, stage)
    assert log[-1][2].status is ControlStatus.GOAL_REACHED
    early = [o for t, _p, o in log if t < 12.0]
    assert all(o.detail == "waiting for people to pass before making room to turn"
               and o.status is ControlStatus.YIELDING for o in early[1:])
    assert closest >= min(_gap(ctrl, start, ahead), _gap(ctrl, start, behind)) - 0.01, closest


def _gap(ctrl: LocalController, pose: Pose2D, person: Walker) -> float:
    """Footprint-to-body distance (m) from the rover at ``pose`` to ``person``'s start."""
    return float(polygon_distances(pose.inverse().transform_points(np.array([person.start])),
                                   np.asarray(ctrl.robot.footprint_points))[0]) - BODY_M


def _standing_at(cfg: Config, robot: RobotModel, xy: tuple[float, float]) -> PeopleStage:
    """A people stage that sees one person standing at ``xy`` (``map``; they walked before)."""
    track = PersonTrack(1, xy[0], xy[1], 0.0, 0.0, walked=True)
    return PeopleStage(cfg.people, cfg.nav.controller, robot,
                       lambda: PeopleTracks(0.0, (track,)))


def test_a_turn_in_place_waits_only_for_people_its_corners_swing_at(cfg: Config) -> None:
    """Only the turn the rover makes counts, not the whole circle its corners could sweep.

    Someone stands beside its left side, 0.4 m from it and 0.96 m from its centre (inside
    that circle, about 1.0 m with the minimum distance): a small turn either way passes them
    by, a turn of 1 rad either way swings a corner to 0.26 m of them, so the rover waits.
    Someone off the front-left corner, already nearer than the minimum (0.23 m): a turn to
    the left swings that corner at them (wait), a turn to the right does not bring the rover
    any nearer (turn). Before, every one of these turns waited: in a crowded doorway the
    rover stood for minutes (20 visitors, the crowd benchmark)."""
    robot = RobotModel.from_config(cfg.robot)
    reach_m = max(math.hypot(x, y) for x, y in robot.footprint_points)
    room_m = reach_m + cfg.people.person_radius_m + cfg.people.min_distance_m
    here = Pose2D(0.0, 0.0, 0.0)
    beside = _standing_at(cfg, robot, (0.0, 0.96))
    assert room_m > 0.96  # the whole circle's check would wait for them
    assert beside.review_turn(here, 0.0, +0.3) is None
    assert beside.review_turn(here, 0.0, -0.3) is None
    for turn in (+1.0, -1.0):
        held = beside.review_turn(here, 0.0, turn)
        assert held is not None and held.status is ControlStatus.YIELDING
        assert held.detail == "waiting for people to step back before turning"
    corner = _standing_at(cfg, robot, (0.85 * math.cos(1.2), 0.85 * math.sin(1.2)))
    assert corner.review_turn(here, 0.0, +1.0) is not None
    assert corner.review_turn(here, 0.0, -0.5) is None


@pytest.mark.parametrize(("side", "turns_at_once"), [(-1.0, True), (+1.0, False)])
def test_the_controller_asks_about_the_turn_it_makes(cfg: Config, side: float,
                                                    turns_at_once: bool) -> None:
    """The path leaves 0.9 rad to the right: the rover turns in place to the right, which
    swings its front-left corner forward and its front-right corner back. Someone off the
    front-right corner does not hold that turn; someone off the front-left corner does (the
    controller passes the turn's direction and size to the people stage). Half-way through
    the turn the rover stands farther from the first than at either end: the turn, judged
    from where it began, goes on."""
    robot = RobotModel.from_config(cfg.robot)
    ctrl = LocalController(cfg.nav.controller, robot, Costmap(open_grid(12.0), robot,
                                                              cfg.nav.costmap))
    heading = -0.9
    s = np.arange(0.0, 4.0 + 1e-9, 0.05)
    plan = np.stack([s * math.cos(heading), s * math.sin(heading),
                     np.full_like(s, heading)], axis=1)
    ctrl.set_plan(plan, Pose2D(4.0 * math.cos(heading), 4.0 * math.sin(heading), heading))
    person = Walker((0.85 * math.cos(0.45), side * 0.85 * math.sin(0.45)), (0.0, 0.0))
    stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
    pose, log, _closest = run(ctrl, Pose2D(0.0, 0.0, 0.0), [person], 3.0, stage)
    details = {o.detail for _t, _p, o in log}
    if turns_at_once:  # and it does not stop half-way (the corners pass them, then go)
        assert "waiting for people to step back before turning" not in details, details
        assert log[0][2].detail == "turning towards the path"
        assert pose.yaw < heading + cfg.nav.controller.rotate_exit_rad + 0.05, pose
    else:
        assert details == {"waiting for people to step back before turning"}, details
        assert pose.yaw == 0.0
