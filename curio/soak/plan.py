"""The fault campaign: which faults, when, with what parameters — drawn from the seed.

Every kind of :data:`KINDS` comes once first (when the campaign has room for them all), the
rest are drawn by weight. Faults that need the rover moving (``moving``) or a tour running
(``tour``) are placed during scheduled tours (``TOUR_OFFSET_S`` after a tour's start); the
others anywhere in the soak's time. The rover takes them in time order, one at a time: a fault
that needs motion waits for it, and each is judged before the next is injected.

Times are the building's clock (UNIX seconds); parameters are plain JSON, drawn here so a seed
gives the same campaign whatever happens during the run.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

__all__ = ["KIDNAP_KINDS", "KINDS", "KindSpec", "PlannedFault", "draw_campaign"]

Need = Literal["any", "moving", "still", "tour"]


@dataclass(frozen=True)
class KindSpec:
    """One kind of fault.

    Attributes:
        name: the kind (the report's key).
        need: ``any`` (inject whenever), ``moving`` (while the rover drives), ``still`` (while
            it stands: not held for a tour, never a reason to start one), ``tour`` (in the
            middle of a tour).
        weight: how often it is drawn after the first round.
        restart: it kills the rover process (the orchestrator does it).
        what: one line for the report and docs.
    """

    name: str
    need: Need
    weight: float
    restart: bool = False
    what: str = ""


KINDS: dict[str, KindSpec] = {k.name: k for k in (
    KindSpec("lidar_unplug", "any", 1.0, what="the lidar's USB cable pulled, put back later"),
    KindSpec("lidar_garbage", "any", 1.0, what="random bytes in the lidar's stream"),
    KindSpec("arduino_reset", "moving", 1.0, what="the Arduino resets while driving"),
    KindSpec("crc_burst", "moving", 1.0,
             what="a burst of corrupted frames both ways on the Arduino link"),
    KindSpec("i2c_errors", "any", 1.0, what="the IMU's I2C bus fails a share of transactions"),
    KindSpec("imu_stuck", "any", 0.7, what="the BNO055's output freezes until it is reset"),
    KindSpec("loop_stall", "any", 0.7, what="a part blocks the event loop for 2 s"),
    KindSpec("disk_full", "any", 0.5, what="the data disk fills up (recorder, event log)"),
    KindSpec("kidnap", "moving", 0.7, what="the rover is carried elsewhere while driving"),
    KindSpec("kidnap_parked", "still", 0.35,
             what="the rover is lifted and put down elsewhere while it stands still"),
    KindSpec("corrupt_file", "any", 0.25, restart=True,
             what="kill -9, then a corrupt tours/paths/schedules file at the restart"),
    KindSpec("kill9", "tour", 0.35, restart=True, what="kill -9 in the middle of a tour"),
)}

KIDNAP_KINDS = ("kidnap", "kidnap_parked")  # the rover carried away: judged by localisation
TOUR_OFFSET_S = (30.0, 170.0)
MIN_GAP_S = 45.0


@dataclass
class PlannedFault:
    """One fault of the campaign.

    Attributes:
        id: its number (1, 2, ...).
        kind: a key of :data:`KINDS`.
        at_wall_s: when it is due (building clock, UNIX seconds).
        params: its parameters (see :func:`_params`).
    """

    id: int
    kind: str
    at_wall_s: float
    params: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON."""
        return asdict(self)

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> PlannedFault:
        """From :meth:`to_json`."""
        return cls(int(obj["id"]), str(obj["kind"]), float(obj["at_wall_s"]),
                   dict(obj.get("params") or {}))


def _params(kind: str, rng: np.random.Generator) -> dict[str, Any]:
    """The drawn parameters of one fault of ``kind``."""
    u = rng.uniform
    if kind == "lidar_unplug":
        return {"down_s": round(float(u(2.0, 20.0)), 1)}
    if kind == "lidar_garbage":
        return {"bytes": int(rng.integers(64, 4096)), "bursts": int(rng.integers(1, 4))}
    if kind == "crc_burst":
        return {"tx_frames": int(rng.integers(5, 60)), "rx_s": round(float(u(0.3, 2.0)), 2)}
    if kind == "i2c_errors":
        return {"rate": round(float(u(0.2, 0.8)), 2), "duration_s": round(float(u(5.0, 30.0)), 1)}
    if kind == "loop_stall":
        return {"stall_s": 2.0}
    if kind == "disk_full":
        return {"duration_s": round(float(u(20.0, 150.0)), 1)}
    if kind == "corrupt_file":
        return {"file": str(rng.choice(["tours", "paths", "schedules"])),
                "how": str(rng.choice(["truncate", "garbage", "empty"]))}
    if kind in KIDNAP_KINDS:
        return {"seed": int(rng.integers(0, 2**31 - 1))}
    if kind == "kill9":
        return {"delay_ms": int(rng.integers(0, 300))}
    return {}


def draw_campaign(seed: int, start_wall_s: float, end_wall_s: float, count: int,
                  tour_starts: list[float], kinds: list[str] | None = None) -> list[PlannedFault]:
    """The campaign of ``count`` faults between ``start_wall_s`` and ``end_wall_s``.

    Args:
        seed: the soak's seed.
        start_wall_s, end_wall_s: the soak's span on the building clock.
        count: how many faults.
        tour_starts: the scheduled tours' start times within the span (building clock).
        kinds: the kinds allowed (default: all of :data:`KINDS`).
    """
    rng = np.random.default_rng([seed, 16])
    names = list(kinds if kinds is not None else KINDS)
    weights = np.array([KINDS[k].weight for k in names], dtype=float)
    chosen = list(rng.permutation(names))[:count]
    while len(chosen) < count:
        chosen.append(str(rng.choice(names, p=weights / weights.sum())))
    first, last = start_wall_s + 600.0, end_wall_s - 900.0
    tours = [t for t in tour_starts if first <= t <= last - 200.0]
    out: list[PlannedFault] = []
    for kind in chosen:
        spec = KINDS[kind]
        if spec.need in ("moving", "tour") and tours:
            at = float(rng.choice(tours)) + float(rng.uniform(*TOUR_OFFSET_S))
        else:
            at = float(rng.uniform(first, max(first + 1.0, last)))
        out.append(PlannedFault(0, str(kind), round(at, 1), _params(str(kind), rng)))
    out.sort(key=lambda f: f.at_wall_s)
    for i, fault in enumerate(out):
        if i and fault.at_wall_s < out[i - 1].at_wall_s + MIN_GAP_S \
                and KINDS[fault.kind].need in ("any", "still"):
            fault.at_wall_s = round(out[i - 1].at_wall_s + MIN_GAP_S, 1)
        fault.id = i + 1
    out.sort(key=lambda f: f.at_wall_s)
    for i, fault in enumerate(out):
        fault.id = i + 1
    return out
