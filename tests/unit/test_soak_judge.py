"""The soak's fault judge: a full disk is recovered by writer threads that retry on the wall
clock (every 5 s and 2 s), while the soak's simulated clock runs 15–70× faster — so its
deadline also waits ``wall_deadline_s`` of wall time. Before, a quiet machine judged a disk
that the rover recovered 3–5 wall seconds after it had room as "failed" (40 simulated seconds
had gone by)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from curio.core.geometry import Pose2D
from curio.soak.faults import Injection
from curio.soak.judge import FaultRun, FaultRunner
from curio.soak.plan import PlannedFault


def _runner() -> tuple[FaultRunner, list[dict[str, Any]]]:
    sent: list[dict[str, Any]] = []
    runner = FaultRunner.__new__(FaultRunner)
    runner.app = SimpleNamespace(bus=SimpleNamespace(latest=lambda topic: None), eventlog=None,
                                 world=SimpleNamespace(truth_twist=(0.0, 0.0)))
    runner.link = SimpleNamespace(send=lambda t, **kw: sent.append(kw))
    runner.states, runner.health_seen = {"recorder": "error", "eventlog": "error"}, {}
    runner.help_open_s = None
    runner.judged = 0
    runner.tree_lost = False
    return runner, sent


def _disk_run(wall_deadline_s: float | None) -> FaultRun:
    inj = Injection(("recorder", "eventlog"), (), None, 40.0, wall_deadline_s=wall_deadline_s)
    run = FaultRun(PlannedFault(1, "disk_full", 0.0), inj, injected_s=0.0, injected_wall_s=0.0)
    run.cleared_s, run.log_s = 10.0, 5.0
    return run


def test_a_full_disk_waits_for_the_writers_wall_clock_retries() -> None:
    runner, sent = _runner()
    run = _disk_run(wall_deadline_s=20.0)
    run.cleared_wall_s = float("inf")  # the disk got its room just now (wall clock)
    runner.current = run
    runner._judge(run, now=60.0)  # 50 simulated seconds later: past the 40 s deadline
    assert runner.current is run and not sent, "judged before the writers could retry"
    runner.states.update(recorder="ok", eventlog="ok")
    runner.health_seen.update(recorder=61.0, eventlog=61.0)
    runner._judge(run, now=61.5)
    runner._judge(run, now=63.0)  # ok for a second: recovered
    assert sent and sent[0]["outcome"] == "recovered", sent


def test_without_the_wall_deadline_the_same_run_failed() -> None:
    runner, sent = _runner()
    run = _disk_run(wall_deadline_s=None)
    run.cleared_wall_s = float("inf")
    runner.current = run
    runner._judge(run, now=60.0)
    assert sent and sent[0]["outcome"] == "failed"


def test_only_collisions_the_rover_caused_fail_the_soak() -> None:
    """A visitor walking into a rover that was not moving towards them is counted, not failed;
    any contact the rover made by moving fails the check."""
    from curio.soak.verdict import collision_check

    def rep(*faults: str) -> dict:
        listed = [{"with": ["visitor:3"], "fault": f, "sim_s": 10.0} for f in faults]
        return {"metrics": {"collisions": len(listed),
                            "collisions_rover_at_fault": sum(f != "person" for f in faults),
                            "collisions_person_at_fault": sum(f == "person" for f in faults)},
                "collision_list": listed}

    assert collision_check(rep())["ok"]
    ok = collision_check(rep("person", "person"))
    assert ok["ok"] and "2 by visitors" in ok["detail"]
    bad = collision_check(rep("person", "rover"))
    assert not bad["ok"] and bad["detail"].startswith("1 by the rover")


def test_a_parked_kidnap_waits_for_the_rover_to_stand_and_never_starts_a_tour() -> None:
    """``kidnap_parked`` needs the rover still: held while it drives or turns, injected once
    it stands; unlike a fault that needs driving, it never makes the soak start a tour."""
    runner, _ = _runner()
    published: list[Any] = []
    runner.app.bus = SimpleNamespace(latest=lambda topic: None,
                                     publish=lambda topic, msg: published.append(msg))
    runner.clock = SimpleNamespace(wall_time=lambda: 1000.0)
    runner.plan = [PlannedFault(1, "kidnap_parked", 900.0, {"seed": 1})]
    runner._nudged_s, runner._waiting_since_s = -1e9, None
    for twist in ((0.3, 0.0), (0.0, 0.4)):
        runner.app.world.truth_twist = twist
        assert runner._next_ready() is None
        for now in (0.0, 200.0, 400.0):
            runner._nudge(now)
    assert not published, "a tour was started for a fault that needs the rover still"
    runner.app.world.truth_twist = (0.0, 0.0)
    assert runner._next_ready() is runner.plan[0]


def test_a_kidnap_is_recovered_when_the_tree_is_back_at_work_not_only_the_localiser() -> None:
    """The localiser found the pose in seconds, but the tree stayed lost (out of service,
    asking for help) for the rest of the day: that was judged "recovered" before."""
    runner, _ = _runner()
    runner.localised = lambda: True  # type: ignore[method-assign]
    runner.states, runner.health_seen = {"localization": "ok"}, {"localization": 5.0}
    inj = Injection(("localization",), ("localization.lost",), None, 60.0)
    run = FaultRun(PlannedFault(1, "kidnap", 0.0), inj, injected_s=0.0, injected_wall_s=0.0)
    runner.tree_lost = True
    assert not runner._recovered(run, 6.0) and not runner._recovered(run, 8.0)
    runner.tree_lost = False
    assert not runner._recovered(run, 9.0)
    assert runner._recovered(run, 10.0)  # found, for a second


def test_visitors_walk_in_the_soak_by_default() -> None:
    """The issue's soak has visitors walking: ``--visitors`` (default 6) reaches the rover's
    configuration; CI's one-hour soak asks for none."""
    from curio.soak.orchestrator import Orchestrator, SoakOptions

    assert "sim.crowd.visitors=6" in Orchestrator(SoakOptions())._overrides()
    assert "sim.crowd.visitors=0" in Orchestrator(SoakOptions(visitors=0))._overrides()


def _lost_run(runner: FaultRunner, turn: dict[str, Any]) -> FaultRun:
    """A kidnap 60 s past its clearing, never found, a help request open; ``turn['cmd']`` is
    the last drive command on ``/cmd_vel_nav``."""
    from curio.core.config import load_config
    from curio.core.topics import CMD_VEL_NAV

    runner.app.cfg = load_config(None, [])
    runner.app.bus = SimpleNamespace(
        latest=lambda topic: turn.get("cmd") if topic == CMD_VEL_NAV else None,
        publish=lambda topic, msg: None)
    runner.app.world.truth_pose = Pose2D(1.0, 2.0, 0.0)
    runner.help_open_s = 30.0
    inj = Injection(("localization",), ("localization.lost",), None, 60.0)
    run = FaultRun(PlannedFault(1, "kidnap", 0.0), inj, injected_s=0.0, injected_wall_s=0.0)
    run.cleared_s, run.log_s = 0.0, 1.0
    runner.current = run
    return run


def test_a_lost_rover_turning_at_the_deadline_is_judged_when_its_turn_ends() -> None:
    """Seed 3: an operator's Resume started the lost rover's relocalisation turn again and
    the deadline came while it turned in place, help asked: judged "failed" for moving.
    The deadline waits for the bounded turn; standing and asking after it, it stopped
    safely."""
    from curio.core.messages import Twist

    runner, sent = _runner()
    runner.localised = lambda: False  # type: ignore[method-assign]
    turn: dict[str, Any] = {}
    run = _lost_run(runner, turn)
    now = 60.0
    while now < 66.0:  # turning past the deadline
        runner.app.world.truth_twist = (0.0, 0.4)
        turn["cmd"] = Twist(now, 0.0, 0.4, source="relocalise")
        runner._judge(run, now)
        now += 0.25
    assert not sent, "judged while the lost rover turned in place"
    runner.app.world.truth_twist = (0.0, 0.0)  # the turn is over: it stands and asks
    turn["cmd"] = Twist(now, 0.0, 0.0, source="relocalise")
    runner._judge(run, now + 1.0)
    assert sent and sent[0]["outcome"] == "stopped_safely", sent
    assert sent[0]["waited_for_turn_s"] == 6.0


def test_a_turn_that_never_ends_is_not_waited_for_ever() -> None:
    from curio.core.messages import Twist

    runner, sent = _runner()
    runner.localised = lambda: False  # type: ignore[method-assign]
    turn: dict[str, Any] = {}
    run = _lost_run(runner, turn)
    runner.app.world.truth_twist = (0.0, 0.4)
    now = 60.0
    while not sent and now < 200.0:
        turn["cmd"] = Twist(now, 0.0, 0.4, source="relocalise")
        runner._judge(run, now)
        now += 0.25
    turn_s = 6.3 / 0.4 + 2.0
    assert sent and sent[0]["outcome"] == "failed"
    assert abs(now - 60.0 - turn_s) <= 0.5, now


def test_a_driving_rover_at_the_deadline_is_not_waited_for() -> None:
    from curio.core.messages import Twist

    runner, sent = _runner()
    runner.localised = lambda: False  # type: ignore[method-assign]
    run = _lost_run(runner, {"cmd": Twist(60.0, 0.3, 0.0, source="nav")})
    runner.app.world.truth_twist = (0.3, 0.0)
    runner._judge(run, 60.0)
    assert sent and sent[0]["outcome"] == "failed"


def _hand_run(runner: FaultRunner, teleop_age_s: float, own_mps: float) -> FaultRun:
    """The lost rover asked for help; at the deadline (60 s) it moves, the last teleop
    command ``teleop_age_s`` old, the rover's own controller asking for ``own_mps``."""
    from curio.core.messages import Twist
    from curio.core.topics import CMD_VEL_NAV, CMD_VEL_TELEOP

    run = _lost_run(runner, {})
    # the tree's zero at the end of its turn, long ago; or a controller driving now
    own = Twist(45.0, 0.0, 0.0, source="relocalise") if own_mps == 0.0 else \
        Twist(59.95, own_mps, 0.0, source="nav")
    latest = {CMD_VEL_NAV: own,
              CMD_VEL_TELEOP: Twist(60.0 - teleop_age_s, 0.1, -0.15, source="web:op8")}
    runner.app.bus = SimpleNamespace(latest=latest.get, publish=lambda topic, msg: None)
    runner.app.world.truth_twist = (0.09, -0.13)
    return run


def test_a_lost_rover_driven_by_hand_after_asking_for_help_stopped_safely() -> None:
    """Seed 2 fault 97 and seed 3 fault 84 (2026-12-03): a carried rover stopped and asked
    for help ("I am lost"); an operator then drove it by hand in short bursts, and at the
    deadline it was moving (the base then executes ``safety:teleop``, or ramps down after a
    burst): judged "failed" for the operator's driving."""
    for age_s in (0.1, 0.7):  # in a burst; ramping down after one
        runner, sent = _runner()
        runner.localised = lambda: False  # type: ignore[method-assign]
        run = _hand_run(runner, teleop_age_s=age_s, own_mps=0.0)
        runner._judge(run, 60.0)
        assert sent and sent[0]["outcome"] == "stopped_safely", (age_s, sent)
        assert "driven by hand by an operator at the deadline" in sent[0]["notes"]


def test_a_rover_that_drives_itself_is_still_failed_after_a_teleop() -> None:
    for age_s, own_mps in ((0.1, 0.2), (3.0, 0.0)):  # its controller drives; teleop long ago
        runner, sent = _runner()
        runner.localised = lambda: False  # type: ignore[method-assign]
        run = _hand_run(runner, teleop_age_s=age_s, own_mps=own_mps)
        runner._judge(run, 60.0)
        assert sent and sent[0]["outcome"] == "failed", (age_s, own_mps)


def test_the_soak_compiles_missing_kernels_once_before_the_first_rover(
        monkeypatch: Any, tmp_path: Any) -> None:
    """Each rover starts as ``curio run`` does (the kernels loaded first); with a cold cache
    that start compiled for minutes and the orchestrator took the silent rover for hung. So
    the orchestrator runs ``curio warmup`` first, as after an install — only when some kernel
    has nothing cached."""
    import subprocess

    from curio import kernels
    from curio.soak.orchestrator import Orchestrator, SoakOptions

    ran: list[list[str]] = []
    monkeypatch.setattr(subprocess, "run", lambda args, **kw: ran.append(list(args))
                        or SimpleNamespace(returncode=0))
    orch = Orchestrator(SoakOptions(workdir=tmp_path))
    monkeypatch.setattr(kernels, "status", lambda: [kernels.KernelStatus("k", 1)])
    orch._warm_kernels()
    assert ran == []
    monkeypatch.setattr(kernels, "status", lambda: [kernels.KernelStatus("k", 1),
                                                    kernels.KernelStatus("cold", 0)])
    orch._warm_kernels()
    assert len(ran) == 1 and ran[0][1:4] == ["-m", "curio", "warmup"]
    assert any(a.startswith("--set=data_dir=") for a in ran[0])
