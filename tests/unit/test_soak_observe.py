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
