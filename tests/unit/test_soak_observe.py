"""The soak's own judging of commands and restarts (found by the 24-hour soak of seed 2 on
2026-12-01): an answer seen live and again in a lookup counted as two answers, and a rover the
soak carried away right after a restart counted as a rover that moved by itself."""

from __future__ import annotations

from typing import Any

from curio.soak.clients import answer_in_event, answer_in_lookup
from curio.soak.ledger import Ledger
from curio.soak.observe import Observations, RestartWatch

WALL = 1_748_893_198.4
RESTART_ANSWER = "Not confirmed: the rover restarted before answering this command."


def _ledger_with(rid: str) -> Ledger:
    ledger = Ledger()
    ledger.sent(rid, "operator:op5#5", "pause", "answer", 0.0)
    ledger.acked(rid, duplicate=False)
    return ledger


def test_the_same_answer_live_and_in_a_lookup_is_one_answer() -> None:
    ledger = _ledger_with("c5-2")
    # live: the hub's event record (its stamp on the simulated clock, its wall time) ...
    live = {"stamp": 1568.5, "wall": WALL + 0.0004, "kind": "bt.command_rejected",
            "detail": {"request_id": "c5-2", "message": RESTART_ANSWER}}
    # ... and the journal's lookup of the same answer (wall time to the millisecond)
    looked_up = {"request_id": "c5-2", "state": "answered",
                 "answer": {"kind": "bt.command_rejected", "message": RESTART_ANSWER,
                            "wall_s": round(WALL, 3)}}
    for answer, via in ((answer_in_event(live), "ws"),
                        (answer_in_lookup("c5-2", looked_up), "lookup")):
        assert answer is not None
        ledger.answer(*answer, via)
    counts = ledger.summary()["counts"]
    assert counts["answered"] == 1 and "double_answered" not in counts


def test_two_different_answers_are_still_a_double_answer() -> None:
    ledger = _ledger_with("c5-3")
    ledger.answer("c5-3", "bt.command_accepted", "Paused.", WALL, "ws")
    ledger.answer("c5-3", "bt.command_rejected", RESTART_ANSWER, WALL + 20.0, "lookup")
    assert ledger.summary()["counts"]["double_answered"] == 1


def _answered_by_the_rover_at(stamp_s: float) -> Ledger:
    """A start_tour the rover published in run 14 and accepted at ``stamp_s`` (simulated s),
    its client never told; the final lookup found it still pending."""
    ledger = _ledger_with("c8-231")
    ledger.rover_event(14, "operator", {"request_id": "c8-231"}, 17355.17)
    ledger.rover_event(14, "bt.command_accepted", {"request_id": "c8-231",
                                                    "message": "Tour started: 2 stops."},
                       stamp_s)
    ledger.commands["c8-231"].lookups.append("pending")
    return ledger


def test_an_answer_in_the_rovers_last_moment_is_not_a_lost_command() -> None:
    """Seed 2 (2026-12-03): a docked rover answered "Tour started" after backing out, 6 s
    after the command and in the same step as it reached the soak's end; the clients had
    stopped listening: judged lost."""
    counts = _answered_by_the_rover_at(17361.5).summary(end=(14, 17361.5))["counts"]
    assert counts.get("lost", 0) == 0 and counts["answered_at_end"] == 1


def test_an_answer_the_client_never_got_earlier_is_still_lost() -> None:
    ledger = _answered_by_the_rover_at(17300.0)
    assert ledger.summary(end=(14, 17361.5))["counts"]["lost"] == 1
    assert ledger.summary(end=(13, 17301.0))["counts"]["lost"] == 1  # another run's end
    assert _answered_by_the_rover_at(17361.5).summary()["counts"]["lost"] == 1  # no end


def _pending_since(published_s: float, lookup: str = "pending") -> Ledger:
    """A start_tour the rover published in run 14 at ``published_s`` and never answered; the
    final lookup said ``lookup``."""
    ledger = _ledger_with("c5-168")
    ledger.rover_event(14, "operator", {"request_id": "c5-168"}, published_s)
    ledger.commands["c5-168"].lookups.append(lookup)
    return ledger


def test_a_command_still_carried_out_at_the_end_is_not_a_lost_command() -> None:
    """Seed 2 (2026-12-03, again): a docked rover got "start tour" 4.6 s before the soak's end
    and was still backing out of the dock (it answers once out, some 6 s later): judged
    lost."""
    counts = _pending_since(16601.93).summary(end=(14, 16606.5))["counts"]
    assert counts.get("lost", 0) == 0 and counts["pending_at_end"] == 1


def test_a_command_pending_long_before_the_end_or_unknown_is_still_lost() -> None:
    assert _pending_since(16500.0).summary(end=(14, 16606.5))["counts"]["lost"] == 1
    assert _pending_since(16601.93, "unknown").summary(end=(14, 16606.5))["counts"][
        "lost"] == 1
    assert _pending_since(16601.93).summary(end=(13, 16606.5))["counts"]["lost"] == 1
    assert _pending_since(16601.93).summary()["counts"]["lost"] == 1  # no end


def _watched(obs: Observations, boot: int) -> RestartWatch:
    watch = RestartWatch(boot, 7, "corrupt_file", 100.0, WALL, [12.0, 0.2, 0.0], None, False)
    obs.restart_begins(watch)
    return watch


def _beat(boot: int, sim_s: float, x: float, y: float) -> dict[str, Any]:
    return {"t": "beat", "boot": boot, "sim_s": sim_s, "truth": [x, y, 0.0], "estop": False,
            "pose": [x, y, 0.0]}


def _fault(obs: Observations, fid: int, kind: str, sim_s: float) -> None:
    obs.take({"t": "fault", "phase": "injected", "boot": 12, "id": fid, "kind": kind,
              "sim_s": sim_s})


def _restarted_then(kind: str) -> tuple[Observations, RestartWatch]:
    """Run 12 watched after its restart, standing at its first beat, then fault ``kind``."""
    obs = Observations(Ledger())
    watch = _watched(obs, 12)
    obs.take(_beat(12, 14225.0, 12.17, 0.22))
    _fault(obs, 8, kind, 14238.0)
    return obs, watch


def test_a_rover_the_soak_carried_off_after_a_restart_did_not_move_by_itself() -> None:
    obs, watch = _restarted_then("kidnap_parked")
    obs.take(_beat(12, 14238.5, 6.0, 2.8))  # put down 6.3 m away
    obs.take(_beat(12, 14239.0, 6.01, 2.8))  # the search turn: in place
    assert watch.moved_m < 0.05


def test_a_rover_that_drives_off_after_a_restart_is_still_caught() -> None:
    obs, watch = _restarted_then("lidar_unplug")
    obs.take(_beat(12, 14240.0, 11.0, 0.22))  # 1.2 m, no kidnap, no permit
    assert watch.moved_m > 1.0
    _fault(obs, 9, "kidnap", 14241.0)
    obs.take(_beat(12, 14241.5, 3.0, 3.0))
    assert 1.0 < watch.moved_m < 1.3  # what it drove before the carry still counts


def _beats(obs: Observations, t0: float, t1: float, xy: tuple[float, float], status: str,
           boot: int = 0) -> None:
    t = t0
    while t <= t1:
        obs.take({"t": "beat", "boot": boot, "sim_s": t, "truth": [xy[0], xy[1], 0.0],
                  "status": status})
        t += 0.5


def test_a_rover_standing_with_a_tour_to_give_is_out_of_service() -> None:
    """Standing still (within 0.5 m) while it has a tour, a path or home to drive to counts,
    paused or idle time does not, and moving, a new process or a kidnap start afresh; the
    check fails over STILL_BUDGET_S (the soaks of 2026-12-02: a rover wedged along a wall for
    1.6 simulated hours, another and a walker waiting for each other, every other check
    passing)."""
    from curio.soak.verdict import STILL_BUDGET_S, in_service_check

    obs = Observations(Ledger())
    _beats(obs, 0.0, 100.0, (1.0, 1.0), "tour")  # yielding, recovering: 100 s
    _beats(obs, 100.5, 1000.0, (1.2, 1.0), "paused")  # paused: not counted
    assert obs.still.longest_s == 100.0
    _beats(obs, 1000.5, 1100.0, (1.3, 1.0), "going_home")  # the same spot: 100 s more
    assert obs.still.longest_s == 200.0
    _beats(obs, 1100.5, 1200.0, (3.0, 1.0), "moving")  # it drove off: afresh
    obs.take({"t": "fault", "phase": "injected", "id": 1, "kind": "kidnap"})
    _beats(obs, 1200.5, 1300.0, (3.1, 1.0), "tour")
    _beats(obs, 1300.5, 1400.0, (3.1, 1.0), "tour", boot=1)  # a restart: afresh
    assert obs.still.longest_s == 200.0

    def check(longest: float) -> dict[str, Any]:
        return in_service_check({"metrics": {"longest_still_driving_s": longest}})

    assert check(200.0)["ok"]
    _beats(obs, 1400.5, 1400.5 + STILL_BUDGET_S + 10.0, (3.1, 1.0), "tour", boot=1)
    assert obs.still.longest_s > STILL_BUDGET_S
    assert obs.still.longest_at is not None and obs.still.longest_at["boot"] == 1
    assert not check(obs.still.longest_s)["ok"]


def _ev(boot: int, sim_s: float, kind: str, **detail: Any) -> dict[str, Any]:
    return {"t": "ev", "boot": boot, "sim_s": sim_s, "kind": kind, "detail": detail}


def test_a_docked_rover_that_backs_out_for_a_scheduled_tour_was_told_to() -> None:
    """With a dock, a restarted rover on it answers the schedule's start_tour only once it has
    backed out (0.7 m, 6 s): the command permits from when it was sent (the 3-hour soak
    with dock.enabled of 2026-12-02 called that 0.74 m "moved by itself")."""
    obs, watch = _restarted_then("lidar_unplug")
    obs.take(_ev(12, 14240.0, "operator", action="start_tour", request_id="schedule-1-9",
                 source="scheduler"))
    obs.take(_beat(12, 14243.0, 11.8, 0.22))  # backing out of the dock
    obs.take(_beat(12, 14246.0, 11.47, 0.22))
    obs.take(_ev(12, 14246.0, "bt.command_accepted", action="start_tour",
                 request_id="schedule-1-9", message="Tour started: 2 stops."))
    assert watch.permitted == "bt.command_accepted" and watch.moved_m < 0.05


def test_a_command_refused_or_accepted_later_does_not_excuse_moving_before_it() -> None:
    obs, watch = _restarted_then("lidar_unplug")
    obs.take(_beat(12, 14239.0, 11.5, 0.22))  # 0.67 m before any command
    obs.take(_ev(12, 14240.0, "operator", action="start_tour", request_id="c1-4",
                 source="web:op1"))
    obs.take(_ev(12, 14240.5, "bt.command_accepted", action="start_tour", request_id="c1-4"))
    assert watch.moved_m > 0.6


def test_a_tour_refused_while_backing_out_of_the_dock_excused_the_backing_out() -> None:
    """Seed 3, run 8 (2026-12-03): the schedule's start_tour backed the rover out of its
    dock (0.29 m), an operator paused it, and the tour was refused ("paused before it
    started"): the restart check called the backing out "moved by itself"."""
    obs, watch = _restarted_then("lidar_unplug")
    obs.take(_ev(12, 14240.0, "operator", action="start_tour", request_id="schedule-2-9",
                 source="scheduler"))
    obs.take(_beat(12, 14241.0, 12.04, 0.22))
    obs.take(_beat(12, 14242.0, 11.88, 0.22))
    obs.take(_ev(12, 14242.3, "bt.command_rejected", action="start_tour",
                 request_id="schedule-2-9", message="The rover was paused before it started"))
    assert watch.moved_m < 0.05 and watch.excused == ["schedule-2-9"]
    assert watch.permitted is None  # refused: it permits nothing after it
    obs.take(_beat(12, 14242.5, 11.87, 0.22))  # braking: the new place to stand
    obs.take(_beat(12, 14250.0, 11.87, 0.22))
    assert watch.moved_m < 0.05
    obs.take(_beat(12, 14251.0, 11.2, 0.22))  # then driving off on its own is caught
    assert watch.moved_m > 0.6


def test_a_command_refused_at_once_excuses_nothing() -> None:
    obs, watch = _restarted_then("lidar_unplug")
    obs.take(_ev(12, 14240.0, "operator", action="start_tour", request_id="c1-5",
                 source="web:op1"))
    obs.take(_ev(12, 14240.5, "bt.command_rejected", action="start_tour", request_id="c1-5"))
    obs.take(_beat(12, 14241.0, 11.5, 0.22))  # moving after the refusal: its own doing
    assert watch.moved_m > 0.6 and watch.excused == []
