"""Replay: recorded inputs back onto a bus, at the clock times they were published.

:class:`ReplaySource` is the part that stands in for the simulator and the device drivers in a
replayed application (``App(inputs=...)``): it publishes the sensor streams and the operator's
commands (``REPLAY_INPUTS`` of :mod:`curio.record.codec`: ``/scan``, ``/wheels``, ``/imu``,
``/battery``, ``/servo_cmd``, ``/operator``, ``/initialpose``, ``/cmd_vel_teleop``) each at
its recorded ``publish_time``, and gives the navigator the goals a script gave it (``/goal``).
Everything else — the EKF, localisation, costmaps, planning, control, the tree, the safety
stage — runs again on those inputs; its outputs are compared with the recorded ones
(:mod:`curio.record.compare`). The rover does not move: the recorded sensors are what it saw.

Order at equal times: each distinct time's inputs are scheduled ``LOOKAHEAD_S`` ahead, so on a
:class:`~curio.core.clock.SimClock` they fire before the application's own timers due at the
same instant — as the simulator's and the scenario script's did, having registered early too.
Inputs of one instant keep their recorded order (``sequence``).

:func:`recording_inputs` turns a recording into those inputs and collects, on the way, the
recorded outputs to compare with (:class:`Recorded`). With a start later than the run's, the
inputs before it are skipped and the localiser is seeded with the recorded pose at the start (an
``/initialpose`` with its covariance).
"""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from curio.core.bus import Bus, Topic
from curio.core.clock import Clock
from curio.core.messages import NavGoal, Odometry, Path, PoseWithCovariance, Twist
from curio.core.parts import Part, Parts
from curio.core.topics import GOAL, INITIAL_POSE
from curio.record.codec import REPLAY_INPUTS, decode
from curio.record.reader import Recording

__all__ = ["Recorded", "ReplaySource", "TimedInput", "recording_inputs"]

LOOKAHEAD_S = 2.0
COMPARED = ("/pose", "/plan", "/cmd_vel", "/cmd_vel_nav", "/ground_truth")


@dataclass(frozen=True, slots=True)
class TimedInput:
    """One message to publish at clock time ``t_s`` (``seq`` orders equal times)."""

    t_s: float
    seq: int
    topic: Topic[Any]
    msg: Any


@dataclass
class Recorded:
    """The recorded outputs a replay is compared with, ``(t_s, message)`` in clock time."""

    poses: list[tuple[float, PoseWithCovariance]] = field(default_factory=list)
    plans: list[tuple[float, Path]] = field(default_factory=list)
    cmd_vel: list[tuple[float, Twist]] = field(default_factory=list)
    cmd_vel_nav: list[tuple[float, Twist]] = field(default_factory=list)
    truth: list[tuple[float, Odometry]] = field(default_factory=list)
    last_t: float | None = None
    inputs: Counter[str] = field(default_factory=Counter)
    seeded_from: PoseWithCovariance | None = None

    def add(self, channel: str, t: float, msg: Any) -> None:
        """File one recorded output."""
        stores: dict[str, list[tuple[float, Any]]] = {
            "/pose": self.poses, "/plan": self.plans, "/cmd_vel": self.cmd_vel,  # type: ignore[dict-item]
            "/cmd_vel_nav": self.cmd_vel_nav, "/ground_truth": self.truth}  # type: ignore[dict-item]
        stores[channel].append((t, msg))

    def until(self, t_s: float) -> None:
        """Forget the recorded outputs after clock time ``t_s`` (a replay ended early)."""
        for name in ("poses", "plans", "cmd_vel", "cmd_vel_nav", "truth"):
            setattr(self, name, [(t, m) for t, m in getattr(self, name) if t <= t_s])


def recording_inputs(rec: Recording, start_s: float, end_s: float | None, run_start_s: float,
                     recorded: Recorded) -> Iterator[TimedInput]:
    """The inputs of ``rec`` between ``start_s`` and ``end_s`` (clock seconds), in publish
    order, filing the outputs to compare in ``recorded`` on the way.

    Raises:
        ValueError: a payload that does not decode (a corrupt or foreign file).
    """
    last_pose: PoseWithCovariance | None = None
    started = False
    for m in rec.messages():
        if m.channel not in REPLAY_INPUTS and m.channel not in COMPARED:
            continue
        t = m.publish_ns / 1e9
        if end_s is not None and t > end_s:
            break
        decoded = decode(m.channel, m.data)
        if decoded is None:
            continue
        topic, msg = decoded
        if t < start_s:
            if m.channel == "/pose":
                last_pose = msg
            continue
        if not started:
            started = True
            if start_s > run_start_s + 1e-9 and last_pose is not None:
                recorded.seeded_from = last_pose
                yield TimedInput(start_s, -1, INITIAL_POSE,
                                 PoseWithCovariance(start_s, last_pose.pose,
                                                    last_pose.covariance))
        recorded.last_t = t
        if m.channel in COMPARED:
            recorded.add(m.channel, t, msg)
        else:
            recorded.inputs[m.channel] += 1
            yield TimedInput(t, m.seq, topic, msg)


class ReplaySource:
    """The part that publishes recorded inputs (see the module docstring).

    Args:
        inputs: what to publish, in time order.
        on_goal: gives a ``/goal`` to the navigator (set once the application exists).
    """

    def __init__(self, inputs: Iterator[TimedInput],
                 on_goal: Callable[[NavGoal], None] | None = None) -> None:
        self._inputs = inputs
        self.on_goal = on_goal
        self.published: Counter[str] = Counter()
        self.done = False
        self.error: BaseException | None = None
        self._bus: Bus | None = None
        self._clock: Clock | None = None

    def register(self, bus: Bus, clock: Clock, parts: Parts) -> None:
        """``App(inputs=source.register)``: register the part ``replay``."""
        self._bus, self._clock = bus, clock
        parts.add(Part("replay", run=self.run))

    async def run(self) -> None:
        """Schedule every input ``LOOKAHEAD_S`` ahead of its time; finish when all are out."""
        assert self._clock is not None
        clock = self._clock
        tasks: list[asyncio.Task[None]] = []
        batch: list[TimedInput] = []
        try:
            for item in self._inputs:
                if batch and item.t_s != batch[0].t_s:
                    tasks.append(asyncio.create_task(self._publish_at(batch)))
                    batch = []
                    if len(tasks) > 1000:
                        tasks = [t for t in tasks if not t.done()]
                if item.t_s - clock.now() > LOOKAHEAD_S:
                    await clock.sleep_until(item.t_s - LOOKAHEAD_S)
                batch.append(item)
            if batch:
                tasks.append(asyncio.create_task(self._publish_at(batch)))
            await asyncio.gather(*tasks)
        except ValueError as exc:
            self.error = exc
        finally:
            self.done = True

    async def _publish_at(self, batch: list[TimedInput]) -> None:
        assert self._clock is not None and self._bus is not None
        await self._clock.sleep_until(batch[0].t_s)
        for item in batch:
            self._bus.publish(item.topic, item.msg)
            self.published[item.topic.name] += 1
            if item.topic is GOAL and self.on_goal is not None:
                self.on_goal(item.msg)
