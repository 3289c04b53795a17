"""Every operator command gets exactly one answer with its request id (found by ``curio
soak``: the e-stop, its release and a single goal sent while no route ran were never
answered, so a page could not tell they had been carried out)."""

from __future__ import annotations

import pytest

from curio.core.geometry import Pose2D

from .bt_fakes import make_harness

ANSWERS = ("bt.command_accepted", "bt.command_rejected")


def answers_for(h, rid: str) -> list[str]:  # type: ignore[no-untyped-def]
    return [e.kind for e in h.events if e.kind in ANSWERS and e.detail["request_id"] == rid]


@pytest.mark.parametrize("action,fields", [
    ("estop", {}), ("release_estop", {}), ("goto", {"goal": Pose2D(2.0, 1.0, 0.0)}),
    ("pause", {}), ("resume", {}), ("go_home", {}), ("cancel", {}), ("help_done", {}),
    ("select_path", {"path_id": 1}), ("toggle_pause", {}),
])
def test_each_action_is_answered_once(action: str, fields: dict[str, object]) -> None:
    h = make_harness()
    h.tick()
    h.press(action, request_id="r1", **fields)
    h.tick(4)
    assert len(answers_for(h, "r1")) == 1, h.kinds("bt.")


@pytest.mark.parametrize("first,second", [("pause", "pause"), ("pause", "resume"),
                                           ("resume", "pause"), ("toggle_pause", "pause")])
def test_two_pause_or_resume_commands_in_one_tick_are_each_answered_once(
        first: str, second: str) -> None:
    """Found by the 24-hour soak (seed 2, 2026-12-01): two operators pressed Pause within one
    tick; the later one was answered, the earlier never (it was overwritten)."""
    h = make_harness()
    h.tick()
    h.press(first, request_id="a")
    h.press(second, request_id="b")
    h.tick(3)
    assert len(answers_for(h, "a")) == 1 and len(answers_for(h, "b")) == 1, h.kinds("bt.")


def test_goto_while_idle_is_accepted_and_while_paused_rejected() -> None:
    h = make_harness()
    h.tick()
    h.press("goto", request_id="idle", goal=Pose2D(2.0, 1.0, 0.0))
    h.press("pause", request_id="p")
    h.tick(2)
    h.press("goto", request_id="paused", goal=Pose2D(2.0, 1.0, 0.0))
    h.tick(2)
    assert answers_for(h, "idle") == ["bt.command_accepted"]
    assert answers_for(h, "paused") == ["bt.command_rejected"]


def test_estop_and_release_answers_say_what_happened() -> None:
    h = make_harness()
    h.tick()
    h.press("estop", request_id="s")
    h.tick()
    h.press("release_estop", request_id="r")
    h.tick()
    accepted = {e.detail["request_id"]: e.detail["message"] for e in h.of("bt.command_accepted")}
    assert "stopped" in accepted["s"] and "released" in accepted["r"]


@pytest.mark.parametrize("tree", ["follow_path", "tour"])
@pytest.mark.parametrize("hold", ["pause", "estop", "safety_estop"])
def test_a_command_waiting_when_a_hold_begins_is_answered_at_once(tree: str, hold: str) -> None:
    """A path or tour pressed in the same tick as Pause (or just before an e-stop) used to wait
    unanswered for as long as the hold lasted (``curio soak``: a command lost at the end)."""
    from curio.core.config import REPO_ROOT, load_config

    shipped = load_config(REPO_ROOT / "config.toml", []).bt  # with its tour stops
    h = make_harness(shipped.model_copy(update={"speak": False, "tree": tree}))
    h.tick()
    if tree == "tour":
        h.press("start_tour", request_id="c")
    else:
        h.press("select_path", request_id="c", path_id=1)
    if hold == "safety_estop":
        h.estop(True)
    else:
        h.press(hold, request_id="x")
    h.tick(3)
    assert answers_for(h, "c") == ["bt.command_rejected"], h.kinds("bt.")
    rejected = {e.detail["request_id"]: e.detail["message"] for e in h.of("bt.command_rejected")}
    assert "send it again" in rejected["c"]
    h.tick(20)
    assert len(answers_for(h, "c")) == 1  # once
