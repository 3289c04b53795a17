"""Dispatch: the best rover gets the tour; failures, outages and low batteries re-dispatch."""

from __future__ import annotations

from typing import Any

import pytest

from curio.core.config import FleetManagerConfig
from curio.fleet.manager.dispatch import Dispatcher
from curio.fleet.manager.roster import Roster, RoverState

T0 = 1_000.0
FIRST_STOP = (10.0, 0.0)


def status(**kw: Any) -> dict[str, Any]:
    base = {"ready": True, "battery_v": 8.0, "state": "idle", "tour": None,
            "tour_phase": "idle"}
    return {**base, **kw}


class Fleet:
    """A roster, a dispatcher and what it sent."""

    def __init__(self, **cfg: Any) -> None:
        self.cfg = FleetManagerConfig(**cfg)
        self.roster = Roster()
        self.sent: list[tuple[str, dict[str, Any]]] = []
        self.notes: list[tuple[str, dict[str, Any]]] = []
        self.d = Dispatcher(self.cfg, self.roster, self.distance, self.tour_def,
                            lambda r, c: self.sent.append((r, c)),
                            lambda k, d: self.notes.append((k, d)))

    @staticmethod
    def distance(r: RoverState, tour_id: int) -> float:
        assert r.pose is not None
        return abs(r.pose[0] - FIRST_STOP[0]) + abs(r.pose[1] - FIRST_STOP[1])

    @staticmethod
    def tour_def(tour_id: int) -> dict[str, Any]:
        if tour_id != 1:
            raise KeyError(tour_id)
        return {"id": 1, "name": "T", "revision": 1, "stops": []}

    def rover(self, name: str, x: float, now: float = T0, **st: Any) -> RoverState:
        self.roster.heard(name, "status", status(**st), now)
        self.roster.heard(name, "pose", {"x": x, "y": 0.0, "yaw": 0.0}, now)
        return self.roster.get(name)

    def started(self, rover: str, job: Any, now: float) -> None:
        self.d.on_event(rover, {"kind": "tour.started",
                                "detail": {"request_id": job.request_id}}, now)

    def running_on_a(self) -> Any:
        """Rovers a (nearer) and b, one job given to a and started there."""
        self.rover("a", 9.0)
        self.rover("b", 0.0)
        job = self.d.request(1, "T", "operator", T0)
        self.d.tick(T0)
        self.started("a", job, T0 + 1)
        return job


def test_the_nearest_ready_charged_rover_gets_the_tour() -> None:
    f = Fleet()
    f.rover("far", 0.0)
    f.rover("near_low", 9.0, battery_v=6.9)
    f.rover("near_busy", 9.5, ready=False, state="moving")
    f.rover("near", 7.0)
    job = f.d.request(1, "T", "operator", T0)
    f.d.tick(T0)
    assert (job.state, job.rover) == ("sent", "near")
    rover, cmd = f.sent[-1]
    assert rover == "near" and cmd["action"] == "start_tour" and cmd["tour"]["id"] == 1
    assert cmd["request_id"] == job.request_id
    f.started("near", job, T0 + 1)
    assert job.state == "running"
    f.d.on_event("near", {"kind": "tour.finished",
                          "detail": {"request_id": job.request_id}}, T0 + 100)
    assert job.state == "done"


def test_a_second_tour_goes_to_the_next_best_rover_and_a_third_waits() -> None:
    f = Fleet(start_window_s=60.0)
    f.rover("a", 8.0)
    f.rover("b", 0.0)
    jobs = [f.d.request(1, "T", "schedule", T0) for _ in range(3)]
    f.d.tick(T0)
    assert [j.rover for j in jobs] == ["a", "b", None]
    f.d.tick(T0 + 61.0)
    assert jobs[2].state == "dropped" and "no rover was ready" in jobs[2].reason


def test_a_refusal_and_a_silent_rover_send_the_tour_elsewhere() -> None:
    f = Fleet(ack_timeout_s=20.0)
    f.rover("a", 9.0)
    f.rover("b", 0.0)
    job = f.d.request(1, "T", "operator", T0)
    f.d.tick(T0)
    f.d.on_reply("a", {"ok": False, "reason": "e-stop", "request_id": job.request_id}, T0 + 1)
    assert job.state == "queued" and "a" in job.excluded
    f.d.tick(T0 + 2)
    assert job.rover == "b"
    f.rover("b", 0.0, now=T0 + 25.0)
    f.d.tick(T0 + 25.0)
    assert job.state == "dropped" or job.rover is None
    assert any(c["action"] == "stop_tour" for r, c in f.sent if r == "b")


def test_an_offline_rover_keeps_its_tour_for_a_while_then_loses_it() -> None:
    f = Fleet(offline_after_s=5.0, redispatch_after_s=60.0)
    job = f.running_on_a()
    f.roster.get("a").alive = False  # its token went
    for t in (T0 + 10, T0 + 40):
        f.rover("b", 0.0, now=t)
        f.roster.update_online(t, 5.0)
        f.d.tick(t)
    assert job.rover == "a" and job.state == "running"  # within the grace: still a's
    f.rover("b", 0.0, now=T0 + 71)
    f.roster.update_online(T0 + 71, 5.0)
    f.d.tick(T0 + 71)
    assert job.rover == "b" and "offline" in job.history[-2]
    # a comes back still running that tour: it is told to stop and go home.
    f.rover("a", 9.0, now=T0 + 80, tour=1, ready=False, tour_phase="moving")
    f.roster.get("a").alive = True
    for name in f.roster.update_online(T0 + 80, 5.0):
        f.d.rover_back(name, T0 + 80)
    assert [c["action"] for r, c in f.sent if r == "a"][-2:] == ["stop_tour", "go_home"]


def test_low_battery_and_a_failed_tour_hand_the_tour_over() -> None:
    f = Fleet(low_battery_v=6.8, failed_tour_s=30.0)
    job = f.running_on_a()
    f.rover("a", 9.0, now=T0 + 5, battery_v=6.7, ready=False, tour=1, tour_phase="moving")
    f.d.tick(T0 + 5)
    assert job.rover == "b" and "battery is low" in job.reason  # handed over at once
    assert [c["action"] for r, c in f.sent if r == "a"][-2:] == ["stop_tour", "go_home"]
    f.started("b", job, T0 + 7)
    f.rover("b", 0.0, now=T0 + 8, ready=False, tour=1, tour_phase="failed")
    f.d.tick(T0 + 8)
    f.rover("b", 0.0, now=T0 + 40, ready=False, tour=1, tour_phase="failed")
    f.d.tick(T0 + 40)
    assert "failed on b" in job.reason


def test_a_deleted_tour_is_dropped() -> None:
    f = Fleet()
    f.rover("a", 0.0)
    job = f.d.request(2, "gone", "operator", T0)
    f.d.tick(T0)
    assert job.state == "dropped" and "no longer exists" in job.reason


@pytest.mark.parametrize("max_attempts", [1, 2])
def test_attempts_are_bounded(max_attempts: int) -> None:
    f = Fleet(max_attempts=max_attempts)
    for i, name in enumerate("abc"):
        f.rover(name, float(i))
    job = f.d.request(1, "T", "operator", T0)
    for k in range(3):
        f.d.tick(T0 + k)
        if job.state == "sent":
            f.d.on_reply(job.rover or "", {"ok": False, "reason": "no",
                                           "request_id": job.request_id}, T0 + k)
    assert job.attempts == max_attempts and job.state == "dropped"


def test_equally_near_rovers_share_the_work_by_battery_and_unreachable_ones_wait() -> None:
    f = Fleet()
    f.rover("a", 9.0, battery_v=7.6)
    f.rover("b", 8.0, battery_v=8.0)  # 1 m further: as near, fuller
    job = f.d.request(1, "T", "operator", T0)
    f.d.tick(T0)
    assert job.rover == "b"
    g = Fleet()
    g.rover("a", 0.0)
    g.distance = lambda r, t: float("inf")  # type: ignore[method-assign, assignment]
    g.d.distance = g.distance
    job = g.d.request(1, "T", "operator", T0)
    g.d.tick(T0)
    assert job.state == "queued"


DOCK = {"state": "idle", "charging": False, "attempt": 0, "detail": ""}


def test_the_power_model_decides_who_is_charged() -> None:
    """With the rovers' state of charge reported, the fuller pack (not the higher voltage
    reading) gets the tour, and a rover under ``min_soc`` gets none however high its voltage."""
    f = Fleet(min_soc=0.3)
    f.rover("a", 9.0, battery_v=8.2, soc=0.25)   # nearest, high reading, nearly empty pack
    f.rover("b", 8.0, battery_v=7.4, soc=0.55)
    f.rover("c", 8.5, battery_v=7.9, soc=0.45)
    job = f.d.request(1, "T", "operator", T0)
    f.d.tick(T0)
    assert job.rover == "b"
    assert [n for *_, n in f.d.candidates(f.d.request(1, "T", "op", T0), T0)] == ["c"]


def test_a_rover_running_low_on_charge_docks_and_its_tour_moves() -> None:
    f = Fleet(low_soc=0.15)
    f.rover("a", 9.0, soc=0.8, dock=DOCK)
    f.rover("b", 0.0, soc=0.9)
    job = f.d.request(1, "T", "operator", T0)
    f.d.tick(T0)
    f.started("a", job, T0 + 1)
    f.rover("a", 9.0, now=T0 + 5, soc=0.12, battery_v=7.2, dock=DOCK, ready=False, tour=1,
            tour_phase="moving")
    f.rover("b", 0.0, now=T0 + 5, soc=0.9)
    f.d.tick(T0 + 5)
    assert job.rover == "b" and "12% charge" in job.reason
    assert [c["action"] for r, c in f.sent if r == "a"][-2:] == ["stop_tour", "dock"]
