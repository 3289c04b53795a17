"""Health that cannot lie: every part of the rover, with the age of its newest sign of life.

A part shows up in the health panel even when it reports nothing itself: :class:`Liveness`
derives its state from three kinds of evidence, newest first:

1. **Its task** — ``part_states()`` (from the composition root) says whether each part's task
   runs, crashed (with the exception) or stopped. A crashed part is an error, whatever it said
   last; a running task is the sign of life of a part that has published nothing yet.
2. **Its output on the bus** — the age of the latest message on the topic it publishes
   (:class:`Watch`): the lidar's ``/scan``, the costmap's ``/local_costmap``, the planner's
   ``/plan`` and the navigator's ``/cmd_vel_nav`` while a goal is active (goals are followed
   from the navigator's ``nav.goal_*`` events), ... An output older than the watch's
   ``max_age_s`` is **stale**, and says how old it is. Publish rates come from the bus's
   counters (Δ published / Δ t).
3. **Its own report** — the latest ``/health`` message with its name (drivers, the safety
   stage, the simulator, the behaviour tree, the dashboard). A report older than
   :data:`REPORT_STALE_S` is stale.

Counters are explained (:data:`COUNTERS`: a label and whether the value is a running total or
a gauge) and totals are shown as rates per second next to their total.

All times are the injected clock's (seconds).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from curio.core.bus import Bus, Topic
from curio.core.clock import Clock
from curio.core.config import Config
from curio.core.messages import DriverHealth, Event
from curio.core.topics import (
    BATTERY,
    BLOCKED,
    CMD_VEL,
    CMD_VEL_NAV,
    IMU,
    LOCAL_COSTMAP,
    ODOM,
    PLAN,
    POSE,
    SCAN,
    WHEEL_ODOM,
    WHEELS,
)

__all__ = ["COUNTERS", "GOAL_OVER", "REPORT_STALE_S", "Liveness", "Watch", "counter_info"]

# A component's own /health report older than this is stale (odometry reports every 2 s).
REPORT_STALE_S = 5.0
# Before this much uptime a part that has shown nothing yet is "starting", not an error.
STARTUP_GRACE_S = 10.0
# The navigator's events that end a goal.
GOAL_OVER = frozenset({"nav.goal_succeeded", "nav.goal_aborted", "nav.goal_preempted",
                       "nav.goal_rejected", "nav.goal_canceled"})
# States from best to worst (the worst piece of evidence decides an entry's state).
SEVERITY = {"ok": 0, "off": 0, "idle": 0, "starting": 1, "degraded": 2, "stale": 3, "error": 4}


@dataclass(frozen=True, slots=True)
class Watch:
    """One part watched through its bus output.

    Attributes:
        name: what the panel calls it.
        topic: the topic it publishes (None: only its task and its report count).
        what: what one message is, plural ("scans").
        max_age_s: its output is stale after this long.
        parts: the names of its tasks (any present counts; none present: not configured).
        report: the name of its own ``/health`` report, if it sends one.
        while_goal: its output is only expected while the navigator has a goal.
    """

    name: str
    topic: Topic[Any] | None
    what: str
    max_age_s: float
    parts: tuple[str, ...] = ()
    report: str | None = None
    while_goal: bool = False


# Counter name → (label, kind, unit). ``total`` counters are shown as a rate per second.
COUNTERS: dict[str, tuple[str, str, str]] = {
    # safety stage
    "cycles": ("control cycles", "total", ""),
    "stop_zone_stops": ("stops for an obstacle", "total", ""),
    "slowed_cycles": ("cycles slowed near an obstacle", "total", ""),
    "estops": ("e-stops", "total", ""),
    "watchdog_trips": ("command watchdog trips", "total", ""),
    "wheel_limited_cycles": ("cycles limited by wheel speed", "total", ""),
    "measured_linear_mps": ("measured speed", "gauge", "m/s"),
    "measured_angular_radps": ("measured turn rate", "gauge", "rad/s"),
    "out_linear_mps": ("commanded speed", "gauge", "m/s"),
    "out_angular_radps": ("commanded turn rate", "gauge", "rad/s"),
    # simulator
    "collisions": ("collisions", "total", ""),
    "physics_steps": ("physics steps", "total", ""),
    "scans": ("scans", "total", ""),
    "in_contact": ("touching an obstacle (1 = yes)", "gauge", ""),
    # dashboard
    "clients": ("pages connected", "gauge", ""),
    "commands": ("commands", "total", ""),
    "teleop_messages": ("teleop messages", "total", ""),
    "rejected_messages": ("messages refused", "total", ""),
    "slow_clients_dropped": ("slow pages disconnected", "total", ""),
    "frames_sent_to_connected": ("frames sent", "total", ""),
    "wrong_tokens": ("wrong tokens", "total", ""),
    # behaviour tree
    "ticks": ("ticks", "total", ""),
    "overruns": ("late ticks", "total", ""),
    "snapshots": ("tree snapshots", "total", ""),
    # base (Arduino), odometry, lidar, IMU
    "crc_errors": ("frames with a bad checksum", "total", ""),
    "resyncs": ("link resyncs", "total", ""),
    "garbage_bytes": ("bytes of noise", "total", ""),
    "length_errors": ("frames of a wrong length", "total", ""),
    "link_losses": ("link losses", "total", ""),
    "reconnects": ("reconnects", "total", ""),
    "tx_holds": ("sends held back", "total", ""),
    "nacks": ("commands refused by the board", "total", ""),
    "tx_frames": ("frames sent", "total", ""),
    "rx_frames": ("frames received", "total", ""),
    "bad_payloads": ("bad payloads", "total", ""),
    "servo_read_failures": ("servo read failures", "total", ""),
    "rc_teleop": ("RC teleop frames", "total", ""),
    "mcu_rx_crc_err": ("checksum errors seen by the board", "total", ""),
    "heartbeat_echo_age_ms": ("heartbeat round trip", "gauge", "ms"),
    "mcu_resets": ("board resets", "total", ""),
    "mcu_state": ("board state code", "gauge", ""),
    "published": ("messages published", "total", ""),
    "suspect_readings": ("suspect readings", "total", ""),
    "rejected_readings": ("rejected readings", "total", ""),
    "sessions": ("sessions", "total", ""),
    "resync_bytes": ("bytes skipped to resync", "total", ""),
    "stalls": ("stalls", "total", ""),
    "unplugs": ("unplugs", "total", ""),
    "resets": ("resets", "total", ""),
    "short_scans": ("short scans", "total", ""),
    "partial_scans": ("scans dropped (cut short)", "total", ""),
    "samples": ("samples", "total", ""),
    "i2c_errors": ("I2C errors", "total", ""),
    "dropped_samples": ("dropped samples", "total", ""),
    "reinits": ("re-initialisations", "total", ""),
    "calibration_saves": ("calibration saves", "total", ""),
    "calibration_restored": ("calibrations restored", "total", ""),
}
_GAUGE_SUFFIXES = {"_mps": "m/s", "_radps": "rad/s", "_ms": "ms", "_s": "s", "_v": "V",
                   "_c": "°C", "_m": "m", "_rad": "rad", "_hz": "Hz", "_fraction": ""}


def counter_info(name: str) -> tuple[str, str, str]:
    """(label, ``total`` | ``gauge``, unit) of a counter; unknown names are guessed from their
    unit suffix (a gauge) or taken for running totals."""
    known = COUNTERS.get(name)
    if known is not None:
        return known
    if name.startswith(("calibration_", "in_")) or name.endswith("_state"):
        return name.replace("_", " "), "gauge", ""
    for suffix, unit in _GAUGE_SUFFIXES.items():
        if name.endswith(suffix):
            return name[: -len(suffix)].replace("_", " "), "gauge", unit
    return name.replace("_", " "), "total", ""


def default_watches(cfg: Config) -> list[Watch]:
    """The parts watched through their output, with limits from the configuration."""
    lidar_period = 1.0 / cfg.sim.lidar_rate_hz
    costmap_period = 1.0 / cfg.nav.costmap.update_rate_hz
    replan_hz = cfg.nav.planner.replan_rate_hz
    replan_age = max(10.0, 5.0 / replan_hz) if replan_hz > 0 else math.inf
    return [
        Watch("lidar", SCAN, "scans", max(1.0, 5 * lidar_period),
              ("lidar", "sim.lidar", "lidar-emulator"), report="lidar"),
        Watch("base", WHEELS, "wheel readings", 1.0, ("arduino", "sim.base"), report="arduino"),
        Watch("odometry", WHEEL_ODOM, "odometry updates", 1.0, ("odometry", "sim.wheels"),
              report="odometry"),
        Watch("imu", IMU, "readings", 1.0, ("imu", "sim.imu"), report="imu"),
        Watch("ekf", ODOM, "fused poses", 1.0, ("ekf",)),
        Watch("localisation", POSE, "poses", 3.0, ("localization", "mapping", "odom_relay"),
              report="localization"),
        Watch("costmap", LOCAL_COSTMAP, "local costmaps", max(2.0, 5 * costmap_period),
              ("costmap",)),
        Watch("planner", PLAN, "plans", replan_age, ("navigator",), while_goal=True),
        Watch("navigator", CMD_VEL_NAV, "velocity commands", 1.0, ("navigator",),
              while_goal=True),
        Watch("obstacles", BLOCKED, "blocked checks", 2.0, ("obstacles",)),
        Watch("behaviour tree", None, "", 0.0, ("behaviour",), report="behaviour"),
        Watch("safety", CMD_VEL, "velocity outputs", 0.5, ("safety",), report="safety"),
        Watch("battery", BATTERY, "readings", 5.0),
        Watch("simulator", None, "", 0.0, ("sim.physics",), report="simulator"),
        Watch("web", None, "", 0.0, ("web",), report="web"),
    ]


class Liveness:
    """Builds the health panel's entries from tasks, bus output and reports.

    Args:
        cfg: the whole configuration (watch limits).
        bus: the application bus (latest messages and publish counters are read, nothing is
            subscribed).
        clock: the injected clock.
        part_states: returns ``{part name: "running" | "crashed: …" | "stopped" | …}``, or
            None when the dashboard runs without the application (tests).
        watches: the parts to watch (default: :func:`default_watches`).
    """

    def __init__(self, cfg: Config, bus: Bus, clock: Clock,
                 part_states: Callable[[], dict[str, str]] | None = None,
                 watches: list[Watch] | None = None) -> None:
        self.bus = bus
        self.clock = clock
        self.part_states = part_states
        self.watches = watches if watches is not None else default_watches(cfg)
        self.started_s = clock.now()
        self.reports: dict[str, DriverHealth] = {}
        self._previous_reports: dict[str, DriverHealth] = {}
        self._topic_samples: dict[str, tuple[float, int]] = {}
        self._topic_rates: dict[str, float] = {}
        self.goal_active = False
        self.goal_started_s: float | None = None
        self._goal_id: Any = None

    # --- input ----------------------------------------------------------------------------------

    def on_report(self, msg: DriverHealth) -> None:
        """A ``/health`` report arrived."""
        old = self.reports.get(msg.name)
        if old is not None and old.stamp < msg.stamp:
            self._previous_reports[msg.name] = old
        self.reports[msg.name] = msg

    def on_event(self, event: Event) -> None:
        """Follow the navigator's goals (``nav.goal_accepted`` … ``nav.goal_succeeded``)."""
        goal_id = event.detail.get("goal_id")
        if event.kind == "nav.goal_accepted":
            self.goal_active = True
            self.goal_started_s = event.stamp
            self._goal_id = goal_id
        elif event.kind in GOAL_OVER and goal_id is not None and goal_id == self._goal_id:
            self.goal_active = False

    def sample(self) -> None:
        """Measure the publish rate of every watched topic (call about once a second)."""
        now = self.clock.now()
        stats = self.bus.stats()
        for watch in self.watches:
            if watch.topic is None:
                continue
            name = watch.topic.name
            published = stats[name].published if name in stats else 0
            last = self._topic_samples.get(name)
            if last is not None and now > last[0]:
                self._topic_rates[name] = (published - last[1]) / (now - last[0])
            self._topic_samples[name] = (now, published)

    # --- output ---------------------------------------------------------------------------------

    def entries(self) -> list[dict[str, Any]]:
        """One entry per part: ``{name, state, message, age_s, rate, counters: [...]}``."""
        now = self.clock.now()
        parts = self.part_states() if self.part_states is not None else None
        out = []
        covered: set[str] = set()
        for watch in self.watches:
            if watch.report is not None:
                covered.add(watch.report)
            entry = self._watched(watch, now, parts)
            if entry is not None:
                out.append(entry)
        for name, report in sorted(self.reports.items()):
            if name not in covered:
                out.append(self._reported(name, report, now))
        return out

    def _watched(self, watch: Watch, now: float,
                 parts: dict[str, str] | None) -> dict[str, Any] | None:
        report = self.reports.get(watch.report) if watch.report else None
        mine = {p: s for p, s in (parts or {}).items() if p in watch.parts}
        if parts is not None and watch.parts and not mine and report is None:
            return None  # not configured in this mode
        if parts is None and watch.topic is None and report is None:
            return None
        findings: list[tuple[str, str]] = []
        ages: list[float] = []
        for part, state in sorted(mine.items()):
            if state != "running":
                findings.append(("error", f"task {part} {state}"))
        rate = None
        if watch.topic is not None:
            rate = self._topic_rates.get(watch.topic.name)
            findings.append(self._output(watch, now, ages))
        if report is not None:
            findings.append(self._report_state(report, now))
            ages.append(now - report.stamp)
        if not ages and mine and all(s == "running" for s in mine.values()):
            ages.append(0.0)  # nothing published yet, but its task runs right now
        state, message = _worst(findings)
        entry = {"name": watch.name, "state": state, "message": message,
                 "age_s": round(min(ages), 2) if ages else None,
                 "rate": None if rate is None else round(rate, 2), "what": watch.what,
                 "counters": self._counters(report) if report is not None else []}
        return entry

    def _output(self, watch: Watch, now: float, ages: list[float]) -> tuple[str, str]:
        """The state of a watch's output: ok, idle (no goal), starting, stale or missing."""
        assert watch.topic is not None
        msg = self.bus.latest(watch.topic)
        stamp: float | None = getattr(msg, "stamp", None) if msg is not None else None
        one = watch.what[:-1] if watch.what.endswith("s") else watch.what
        if stamp is not None:
            ages.append(max(0.0, now - stamp))
        if watch.while_goal and not self.goal_active:
            last = "" if stamp is None else f" (last {one} {_ago(now - stamp)})"
            return "idle", f"idle: no goal{last}"
        goal_s = self.goal_started_s if watch.while_goal else None
        if stamp is None or (goal_s is not None and stamp < goal_s):
            since = goal_s if goal_s is not None else self.started_s
            grace = max(watch.max_age_s, 2.0) if goal_s is not None else STARTUP_GRACE_S
            if now - since < grace:
                return "starting", f"waiting for the first {one}"
            after = " since the goal was given" if goal_s is not None else ""
            return "error", f"no {one} for {now - since:.0f} s{after}"
        age = now - stamp
        if age > watch.max_age_s:
            return "stale", f"stale: last {one} {_ago(age)}"
        return "ok", ""

    @staticmethod
    def _report_state(report: DriverHealth, now: float) -> tuple[str, str]:
        age = now - report.stamp
        if age > REPORT_STALE_S:
            return "stale", f"stale: no report for {age:.0f} s (last said {report.state})"
        return report.state, report.message

    def _reported(self, name: str, report: DriverHealth, now: float) -> dict[str, Any]:
        state, message = self._report_state(report, now)
        return {"name": name, "state": state, "message": message,
                "age_s": round(now - report.stamp, 2), "rate": None, "what": "",
                "counters": self._counters(report)}

    def _counters(self, report: DriverHealth) -> list[dict[str, Any]]:
        """The report's counters, explained; totals with their rate per second."""
        previous = self._previous_reports.get(report.name)
        dt = report.stamp - previous.stamp if previous is not None else 0.0
        out = []
        for key, value in sorted(report.counters.items()):
            label, kind, unit = counter_info(key)
            item: dict[str, Any] = {"key": key, "label": label, "kind": kind, "unit": unit,
                                    "value": value if math.isfinite(value) else None}
            if kind == "total" and previous is not None and dt > 0 \
                    and key in previous.counters:
                item["rate_per_s"] = round((value - previous.counters[key]) / dt, 3)
            out.append(item)
        return out


def _worst(findings: list[tuple[str, str]]) -> tuple[str, str]:
    """The most severe (state, message) of the findings; messages of equal severity joined."""
    if not findings:
        return "ok", ""
    worst = max(SEVERITY.get(s, 2) for s, _ in findings)
    states = [s for s, _ in findings if SEVERITY.get(s, 2) == worst]
    messages = [m for s, m in findings if SEVERITY.get(s, 2) == worst and m]
    return states[0], "; ".join(dict.fromkeys(messages))


def _ago(age_s: float) -> str:
    if age_s < 1.0:
        return "just now"
    if age_s < 90.0:
        return f"{age_s:.0f} s ago"
    return f"{age_s / 60.0:.0f} min ago"
