"""What the fleet manager knows about each rover, from what the rovers publish.

A rover is *discovered* by its liveliness token ``curio/<rover>/alive`` (or its first status);
it is *online* while its token is present and its last status is younger than
``fleet.manager.offline_after_s``; ``offline_since`` says since when it is not. Statuses,
poses, tour states and batteries are kept as they came (JSON); events are numbered by the
rover, so a gap (events lost while the link was down) is noticed and filled by querying the
rover's recent events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Roster", "RoverState"]


@dataclass
class RoverState:
    """One rover as the manager sees it (times are the manager's wall clock, seconds)."""

    name: str
    alive: bool = False
    heard_wall_s: float = -math.inf
    status: dict[str, Any] = field(default_factory=dict)
    pose: tuple[float, float, float] | None = None
    tour: dict[str, Any] = field(default_factory=dict)
    battery_v: float | None = None
    plan: list[list[float]] = field(default_factory=list)
    traffic: dict[str, Any] = field(default_factory=dict)
    event_seq: int = 0
    gaps: int = 0
    offline_since: float | None = None
    alerts: list[dict[str, Any]] = field(default_factory=list)

    def online(self, now_wall_s: float, offline_after_s: float) -> bool:
        """Its token is present and it was heard from within ``offline_after_s``."""
        return self.alive and now_wall_s - self.heard_wall_s <= offline_after_s

    @property
    def ready(self) -> bool:
        """It says it may start a tour (docs/tours.md's rule, checked on the rover)."""
        return bool(self.status.get("ready"))

    @property
    def battery(self) -> float | None:
        """The latest supply voltage, volts."""
        value = self.status.get("battery_v", self.battery_v)
        return float(value) if isinstance(value, int | float) else self.battery_v

    @property
    def soc(self) -> float | None:
        """State of charge 0..1 from the rover's power model (``/power``), None when the
        rover does not report one."""
        value = self.status.get("soc")
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        return None

    @property
    def has_dock(self) -> bool:
        """A dock is fitted (its status carries the dock's state)."""
        return isinstance(self.status.get("dock"), dict)

    @property
    def home_action(self) -> str:
        """What sends it home to charge: ``dock`` with a dock fitted, else ``go_home``."""
        return "dock" if self.has_dock else "go_home"

    @property
    def tour_id(self) -> int | None:
        """The tour it runs now, by its status."""
        value = self.status.get("tour")
        return value if isinstance(value, int) and not isinstance(value, bool) else None

    def to_json(self, now_wall_s: float, offline_after_s: float) -> dict[str, Any]:
        """For the fleet page and the API."""
        return {"name": self.name, "online": self.online(now_wall_s, offline_after_s),
                "heard_s_ago": round(now_wall_s - self.heard_wall_s, 1)
                if math.isfinite(self.heard_wall_s) else None,
                "state": self.status.get("state", "unknown"),
                "text": self.status.get("text", ""), "ready": self.ready,
                "why_not_ready": self.status.get("why", ""),
                "battery_v": self.battery, "pose": self.pose,
                "estop": bool(self.status.get("estop")),
                "tour": self.tour_id, "tour_name": self.status.get("tour_name", ""),
                "tour_phase": self.status.get("tour_phase", "idle"),
                "stop": self.status.get("stop"), "stops": self.status.get("stops", 0),
                "traffic": self.status.get("traffic", "off"),
                "map": self.status.get("map", ""),
                "map_name": self.status.get("map_name", ""), "plan": self.plan,
                "soc": self.soc, "charging": bool(self.status.get("charging")),
                "power_level": self.status.get("power_level"),
                "time_left_s": self.status.get("time_left_s"),
                "dock": self.status.get("dock"), "loc": self.status.get("loc", "unknown"),
                "dashboard": self.status.get("dashboard", ""),
                "zones": self.status.get("zones"),
                "alerts": self.alerts[-10:]}


ALERT_KINDS = ("help.requested", "collision", "fault", "estop.engaged", "fleet.link_lost",
               "nav.goal_aborted", "tour.stopped", "fleet.command_refused")


class Roster:
    """Every rover the manager has heard of, by name."""

    def __init__(self) -> None:
        self.rovers: dict[str, RoverState] = {}

    def get(self, name: str) -> RoverState:
        """The state of ``name`` (created on first mention)."""
        state = self.rovers.get(name)
        if state is None:
            state = self.rovers[name] = RoverState(name)
        return state

    def heard(self, name: str, topic: str, msg: dict[str, Any], now_wall_s: float) -> None:
        """Keep a message of ``name`` (status, pose, tour, battery, plan, traffic)."""
        r = self.get(name)
        r.heard_wall_s = now_wall_s
        if topic == "status":
            r.status = msg
            r.alive = True
        elif topic == "pose":
            r.pose = (float(msg["x"]), float(msg["y"]), float(msg["yaw"]))
        elif topic == "tour":
            r.tour = msg
        elif topic == "battery":
            r.battery_v = float(msg["v"])
        elif topic == "plan":
            r.plan = list(msg.get("pts", []))
        elif topic == "traffic":
            r.traffic = msg

    def event(self, name: str, ev: dict[str, Any]) -> bool:
        """Keep an alert; return False when the event was seen already (by its number)."""
        r = self.get(name)
        seq = ev.get("seq")
        if isinstance(seq, int):
            if seq <= r.event_seq:
                return False
            if seq > r.event_seq + 1 and r.event_seq > 0:
                r.gaps += 1
            r.event_seq = seq
        if str(ev.get("kind", "")).startswith(ALERT_KINDS):
            r.alerts.append({"t": ev.get("t"), "kind": ev.get("kind"),
                             "detail": ev.get("detail", {})})
            del r.alerts[:-50]
        return True

    def update_online(self, now_wall_s: float, offline_after_s: float) -> list[str]:
        """Mark rovers that went offline (``offline_since``); return those that came back."""
        back = []
        for r in self.rovers.values():
            online = r.online(now_wall_s, offline_after_s)
            if not online and r.offline_since is None:
                r.offline_since = now_wall_s
            elif online and r.offline_since is not None:
                r.offline_since = None
                back.append(r.name)
        return back
