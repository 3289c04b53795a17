"""The guide's manners: face the group at a stop, wait for the way out to clear (then
"Excuse me"), stop short of a stop people stand on; the path follower asks them."""

from __future__ import annotations

import math

from curio.bt.follower import PathFollower, Route, StatusSink, Stop
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import PeopleTracks, PersonTrack
from curio.core.topics import make_bus
from curio.people.guide import GuideManners
from curio.people.stage import PeopleStage
from curio.robot import RobotModel
from tests.unit.bt_fakes import FakeNavigator, ManualClock


class Scene:
    """The manners on a fake navigator, a manual clock and scripted people."""

    def __init__(self, cfg: Config, pose: Pose2D = Pose2D()) -> None:
        self.cfg = cfg
        self.clock = ManualClock()
        self.nav = FakeNavigator()
        self.pose = pose
        self.people: list[tuple[float, float]] = []
        self.said: list[str] = []
        robot = RobotModel.from_config(cfg.robot)
        self.stage = PeopleStage(cfg.people, cfg.nav.controller, robot, self.tracks)
        self.guide = GuideManners(cfg.people, self.clock, self.nav, self.stage,  # type: ignore[arg-type]
                                  self.tracks, lambda: self.pose, self.said.append, 0.31,
                                  robot.circumscribed_radius_m)

    def tracks(self) -> PeopleTracks:
        return PeopleTracks(self.clock.now(), tuple(
            PersonTrack(k + 1, x, y, 0.0, 0.0, walked=True)
            for k, (x, y) in enumerate(self.people)))


def test_faces_the_group_at_a_stop(cfg: Config) -> None:
    s = Scene(cfg)
    s.people = [(0.3, 2.0), (-0.3, 2.2), (0.0, 1.8)]  # a group to the rover's left
    s.guide.arrived()
    s.guide.dwelling()
    assert len(s.nav.goals) == 1
    goal = s.nav.last.poses[0]
    assert (goal.x, goal.y) == (0.0, 0.0)
    assert math.isclose(goal.yaw, math.atan2(2.0, 0.0), abs_tol=0.05)
    s.nav.succeed()
    s.pose = Pose2D(0.0, 0.0, goal.yaw)
    s.clock.t += 5.0
    s.guide.dwelling()
    assert len(s.nav.goals) == 1  # already facing them: no second turn


def test_does_not_turn_with_someone_in_the_corners_sweep(cfg: Config) -> None:
    s = Scene(cfg)
    s.people = [(0.0, 2.0), (0.0, -0.8)]
    s.guide.arrived()
    s.guide.dwelling()
    assert not s.nav.goals


def test_waits_for_the_way_out_then_says_excuse_me(cfg: Config) -> None:
    s = Scene(cfg)
    s.people = [(1.2, 0.1)]  # standing in the way towards the next stop at (5, 0)
    assert not s.guide.may_leave((5.0, 0.0))
    s.clock.t += cfg.people.leave_wait_max_s - 0.5
    assert not s.guide.may_leave((5.0, 0.0))
    assert not s.said
    s.clock.t += 1.0
    assert s.guide.may_leave((5.0, 0.0))
    assert s.said == [cfg.people.excuse_me_text]


def test_leaves_at_once_when_the_way_is_clear(cfg: Config) -> None:
    s = Scene(cfg)
    s.people = [(-1.5, 0.0), (0.5, 2.5)]  # behind the rover and well to the side
    assert s.guide.may_leave((5.0, 0.0))
    assert not s.said


def test_stop_short_is_set_only_on_the_way_to_a_tour_stop(cfg: Config) -> None:
    s = Scene(cfg)
    s.guide.driving_to(True)
    assert s.stage.stop_short
    s.guide.driving_to(False)
    assert not s.stage.stop_short


def test_the_follower_leaves_a_stop_only_when_the_manners_say_so(cfg: Config) -> None:
    s = Scene(cfg)
    follower = PathFollower(s.nav, StatusSink(make_bus(), s.clock), s.clock)  # type: ignore[arg-type]
    follower.manners = s.guide
    route = Route(-1, "Tour", (Stop(0.0, 0.0, name="A", dwell_s=2.0),
                               Stop(5.0, 0.0, name="B", dwell_s=2.0)))
    follower.switch(route)
    assert math.isnan(s.nav.last.poses[0].yaw)  # the guide faces its group there instead
    assert s.stage.stop_short
    s.nav.succeed()
    follower.step()
    assert follower.phase == "dwelling"
    s.people = [(1.2, 0.0)]  # someone in the way out
    s.clock.t += 3.0
    follower.step()
    assert follower.phase == "dwelling"
    s.people = []
    follower.step()
    assert follower.phase == "moving" and follower.index == 1
