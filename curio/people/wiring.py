"""People wiring: the tracker, and with ``people.aware`` the costmap filter, the controller's
people stage and the guide's manners.

``build_people`` runs after ``build_navigation`` (it hooks into the costmap node and the local
controller; both work unchanged without it) and returns None when ``people.tracking`` is off.
With ``people.aware`` false — the baseline — the tracker still runs and publishes ``/people``
but nothing in navigation uses it. Either way the localiser (``localizer``, when it is the
map localiser) drops the returns on tracked people from its scans: localisation is not the
controller the baseline stands for. ``attach_guide`` gives the behaviour tree's path follower
the guide's manners once the tree is built, and lets it speak "Excuse me".

"Excuse me" is a ``people.excuse_me`` event (``text``, the rover's ``x``, ``y``, ``yaw`` in
``map``); the simulated visitors hear it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.messages import Event, PeopleTracks
from curio.core.parts import Part, Parts
from curio.core.topics import EVENTS, PEOPLE, POSE
from curio.estimation.localization import LocalizerNode
from curio.estimation.maps import OccupancyGrid
from curio.nav.wiring import Navigation
from curio.people.guide import GuideManners
from curio.people.node import PeopleNode
from curio.people.stage import PeopleStage
from curio.robot import RobotModel

__all__ = ["People", "attach_guide", "build_people"]


@dataclass(frozen=True)
class People:
    """The people subsystem's objects (``stage`` and ``guide`` only with ``people.aware``)."""

    node: PeopleNode
    stage: PeopleStage | None
    guide: GuideManners | None


def build_people(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
                 nav: Navigation, grid: OccupancyGrid,
                 localizer: object | None = None) -> People | None:
    """Construct the tracker, hook it into the localiser (a :class:`LocalizerNode`), and with
    ``people.aware`` into navigation."""
    pcfg = cfg.people
    if not pcfg.tracking:
        return None

    def rover_pose(stamp: float = float("inf")) -> Pose2D | None:
        msg = bus.latest(POSE)
        return None if msg is None else msg.pose

    cm_node = nav.costmap_node
    pose_at = cm_node.pose_at if cm_node is not None else rover_pose
    node = PeopleNode(pcfg, robot, bus, clock, grid, pose_at)
    parts.add(Part("people", run=node.run))
    if isinstance(localizer, LocalizerNode):
        localizer.beam_filter = node
    if not pcfg.aware:
        return People(node, None, None)
    if cm_node is not None:
        cm_node.mark_filter = node

    def tracks() -> PeopleTracks | None:
        return bus.latest(PEOPLE)

    def excuse_me(text: str) -> None:
        pose = rover_pose()
        detail: dict[str, Any] = {"text": text}
        if pose is not None:
            detail.update(x=round(pose.x, 3), y=round(pose.y, 3), yaw=round(pose.yaw, 3))
        bus.publish(EVENTS, Event(clock.now(), "people.excuse_me", detail))

    stage = PeopleStage(pcfg, cfg.nav.controller, robot, tracks)
    stage.on_excuse_me.append(excuse_me)
    nav.controller.people = stage
    half_width = float(abs(robot.footprint[:, 1]).max())
    guide = GuideManners(pcfg, clock, nav.navigator, stage, tracks, rover_pose, excuse_me,
                         half_width, robot.circumscribed_radius_m)
    return People(node, stage, guide)


def attach_guide(people: People | None, follower: Any) -> None:
    """Give the path follower the guide's manners; let it speak "Excuse me" aloud."""
    if people is None or people.guide is None:
        return
    follower.manners = people.guide
    speak: Callable[[str], None] | None = getattr(follower, "speak", None)
    if speak is None:
        return
    guide, stage = people.guide, people.stage
    said = guide.excuse_me

    def excuse_me(text: str) -> None:
        said(text)
        speak(text)

    guide.excuse_me = excuse_me
    if stage is not None:
        stage.on_excuse_me.append(speak)
