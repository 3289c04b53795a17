"""Mid-wheel odometry from LX-16A wheel positions (hardware.md §2.4, §4.5).

Three pieces:

* :class:`EncoderFilter` — turns one wheel servo's raw ``POS_READ`` values (counts mod 1500,
  garbage inside the continuous-rotation dead zone) into a continuous, unwrapped count. No ML
  model: readings inside the suspect band 1150..1310 (mod 1500), missing readings, and jumps
  that disagree with the prediction are replaced by dead reckoning from the last measured
  wheel rate (or the commanded duty when the wheel is starting, stopping or reversing); the
  first plausible reading outside the band re-anchors the count. Wraps are taken along the
  shortest way round (at ≥ 15 Hz a wheel turns < 100 counts per sample), checked against the
  prediction.
* :class:`MidWheelOdometry` — the pure integrator: ``θ = 2π·count/1500``, right counts inverted,
  ``s = θ·R′`` with ``R′ = R·wheel_radius_multiplier``, ``Δd = (Δs_R + Δs_L)/2``,
  ``Δψ = (Δs_R − Δs_L)/B′`` with ``B′ = track·mid_wheel_track_multiplier``; midpoint (RK2) when
  ``|Δψ| < 1e-6`` else the exact arc; the twist is the mean of the last five ``Δd/dt``,
  ``Δψ/dt`` (not updated when ``dt < 1e-4 s``).
* :class:`WheelOdometry` — the component: subscribes ``/wheels`` (and reads the latest
  ``/servo_cmd`` for the commanded duties), publishes ``/wheel_odom`` (``odom`` → ``base_link``).

Units: counts, seconds, metres, radians; frames ``odom`` and ``base_link`` (REP-105).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.geometry import Pose2D, wrap_angle
from curio.core.messages import DriverHealth, Odometry, WheelEncoders
from curio.core.topics import HEALTH, SERVO_CMD, WHEEL_ODOM, WHEELS
from curio.robot import RobotModel

__all__ = ["EncoderFilter", "MidWheelOdometry", "OdomState", "WheelOdometry"]

COUNTS_PER_REV = 1500
HALF_REV = COUNTS_PER_REV // 2
SUSPECT_BAND = (1150, 1310)  # counts (mod 1500) treated as possibly garbage
COUNTS_PER_S_PER_DUTY = COUNTS_PER_REV / 1000.0  # duty ±1000 ↔ ±1 rev/s (2π rad/s)
ML, MR = 1, 4  # indices of the mid wheels in WHEEL_NAMES


class EncoderFilter:
    """Continuous count of one LX-16A wheel through its dead zone (see module docstring).

    Args:
        suspect_band: counts (mod 1500) whose readings are not trusted.
        tolerance_counts: how far a valid reading may differ from the prediction.
        max_rejects: after this many implausible readings in a row, the next one is believed
            (the prediction must have been wrong, e.g. a blocked wheel).
    """

    def __init__(self, suspect_band: tuple[int, int] = SUSPECT_BAND,
                 tolerance_counts: float = 120.0, max_rejects: int = 3) -> None:
        self.suspect_band = suspect_band
        self.tolerance_counts = tolerance_counts
        self.max_rejects = max_rejects
        self.initialized = False
        self.count = 0.0  # output: unwrapped count since the first valid reading
        self.rate_cps = 0.0  # measured wheel rate, counts/s
        self._anchor_raw = 0
        self._anchor_count = 0.0
        self._anchor_stamp = 0.0
        self._last_stamp = 0.0
        self._rejects = 0
        self._has_rate = False
        self.suspect_readings = 0
        self.rejected_readings = 0

    def _suspect(self, raw: int) -> bool:
        lo, hi = self.suspect_band
        return lo <= raw < hi

    def _predicted_rate(self, commanded_cps: float | None) -> float:
        if commanded_cps is None:
            return self.rate_cps
        measured = self.rate_cps
        if commanded_cps == 0.0:
            return 0.0
        if measured * commanded_cps > 0.0 and abs(measured) > 0.3 * abs(commanded_cps):
            return measured
        return commanded_cps

    def update(self, raw: int | None, stamp: float, commanded_cps: float | None = None) -> float:
        """Feed one reading (``None`` = no answer) taken at ``stamp``; return the count.

        Args:
            raw: the servo's position reading (any integer; taken mod 1500).
            stamp: when it was read, seconds.
            commanded_cps: the commanded wheel rate in counts/s (``duty · 1.5``), if known.
        """
        if raw is not None:
            raw %= COUNTS_PER_REV
        if not self.initialized:
            if raw is None or self._suspect(raw):
                return self.count
            self.initialized = True
            self._anchor_raw, self._anchor_count = raw, 0.0
            self._anchor_stamp = self._last_stamp = stamp
            return self.count
        dt = max(0.0, stamp - self._last_stamp)
        self._last_stamp = stamp
        rate = self._predicted_rate(commanded_cps)
        predicted = self.count + rate * dt
        if raw is None or self._suspect(raw):
            self.suspect_readings += 1
            # Dead-reckon, but never further than the width of the band from the anchor.
            limit = (self.suspect_band[1] - self.suspect_band[0]) + 40.0
            self.count = min(max(predicted, self._anchor_count - limit),
                             self._anchor_count + limit)
            return self.count
        delta = (raw - self._anchor_raw + HALF_REV) % COUNTS_PER_REV - HALF_REV
        candidate = self._anchor_count + delta
        if abs(candidate - predicted) > self.tolerance_counts + abs(rate * dt):
            self._rejects += 1
            self.rejected_readings += 1
            if self._rejects <= self.max_rejects:
                self.count = predicted
                return self.count
        self._rejects = 0
        span = stamp - self._anchor_stamp
        if span > 1e-4:
            inst = (candidate - self._anchor_count) / span
            smooth = self._has_rate and span <= 0.2
            self.rate_cps = 0.5 * (self.rate_cps + inst) if smooth else inst
            self._has_rate = True
        self._anchor_raw, self._anchor_count, self._anchor_stamp = raw, candidate, stamp
        self.count = candidate
        return self.count


@dataclass(frozen=True, slots=True)
class OdomState:
    """One odometry output: pose in ``odom`` and twist in ``base_link``."""

    stamp: float
    pose: Pose2D
    linear_mps: float
    angular_radps: float


class MidWheelOdometry:
    """The integrator of hardware.md §2.4 (pure; counts in, pose out).

    Args:
        wheel_radius_m: R′, the effective radius (R · wheel_radius_multiplier).
        track_m: B′, the effective mid-wheel track (track · mid_wheel_track_multiplier).
        window: how many recent velocities the twist averages (5 as the original).
    """

    def __init__(self, wheel_radius_m: float, track_m: float, window: int = 5) -> None:
        self.wheel_radius_m = wheel_radius_m
        self.track_m = track_m
        self.x = self.y = self.yaw = 0.0
        self._last: tuple[float, float, float] | None = None  # stamp, s_left, s_right
        self._v: deque[float] = deque(maxlen=window)
        self._w: deque[float] = deque(maxlen=window)

    def reset(self, pose: Pose2D | None = None) -> None:
        """Restart at ``pose`` (default the origin); the next update only re-references."""
        p = pose or Pose2D()
        self.x, self.y, self.yaw = p.x, p.y, p.yaw
        self._last = None
        self._v.clear()
        self._w.clear()

    def update(self, left_count: float, right_count: float, stamp: float) -> OdomState:
        """Integrate the mid wheels' unwrapped counts (right as read: it is inverted here)."""
        k = 2.0 * math.pi / COUNTS_PER_REV * self.wheel_radius_m
        s_left, s_right = left_count * k, -right_count * k
        if self._last is None:
            self._last = (stamp, s_left, s_right)
            return self.state(stamp)
        t0, l0, r0 = self._last
        self._last = (stamp, s_left, s_right)
        d_left, d_right = s_left - l0, s_right - r0
        dd = 0.5 * (d_right + d_left)
        dpsi = (d_right - d_left) / self.track_m
        if abs(dpsi) < 1e-6:
            self.x += dd * math.cos(self.yaw + 0.5 * dpsi)
            self.y += dd * math.sin(self.yaw + 0.5 * dpsi)
            self.yaw += dpsi
        else:
            rho = dd / dpsi
            yaw1 = self.yaw + dpsi
            self.x += rho * (math.sin(yaw1) - math.sin(self.yaw))
            self.y -= rho * (math.cos(yaw1) - math.cos(self.yaw))
            self.yaw = yaw1
        self.yaw = wrap_angle(self.yaw)
        dt = stamp - t0
        if dt >= 1e-4:
            self._v.append(dd / dt)
            self._w.append(dpsi / dt)
        return self.state(stamp)

    def state(self, stamp: float) -> OdomState:
        """The current pose and averaged twist."""
        v = sum(self._v) / len(self._v) if self._v else 0.0
        w = sum(self._w) / len(self._w) if self._w else 0.0
        return OdomState(stamp, Pose2D(self.x, self.y, self.yaw), v, w)


class WheelOdometry:
    """The odometry component: ``/wheels`` (+ ``/servo_cmd``) → ``/wheel_odom``."""

    def __init__(self, robot: RobotModel, bus: Bus, clock: Clock) -> None:
        self.bus = bus
        self.clock = clock
        self.odom = MidWheelOdometry(robot.odom_wheel_radius_m, robot.odom_track_m)
        self.filters = (EncoderFilter(), EncoderFilter())
        self.published = 0
        self._sub = bus.subscribe(WHEELS, maxsize=16)

    def handle(self, msg: WheelEncoders) -> Odometry | None:
        """Process one wheel reading; return (and publish) the odometry, if any yet."""
        cmd = self.bus.latest(SERVO_CMD)
        rates: tuple[float | None, float | None] = (None, None)
        if cmd is not None:
            rates = (cmd.wheel_duty[ML] * COUNTS_PER_S_PER_DUTY,
                     cmd.wheel_duty[MR] * COUNTS_PER_S_PER_DUTY)
        left_f, right_f = self.filters
        left = left_f.update(msg.positions[ML], msg.stamp, rates[0])
        right = right_f.update(msg.positions[MR], msg.stamp, rates[1])
        if not (left_f.initialized and right_f.initialized):
            return None
        st = self.odom.update(left, right, msg.stamp)
        out = Odometry(st.stamp, st.pose, st.linear_mps, st.angular_radps)
        self.bus.publish(WHEEL_ODOM, out)
        self.published += 1
        return out

    async def run(self) -> None:
        """Process every wheel reading as it arrives; report health once every 2 s."""
        next_health = self.clock.now()
        async for msg in self._sub:
            self.handle(msg)
            if msg.stamp >= next_health:
                next_health = msg.stamp + 2.0
                self._health(msg.stamp)

    def _health(self, stamp: float) -> None:
        left_f, right_f = self.filters
        counters = {
            "published": float(self.published),
            "suspect_readings": float(left_f.suspect_readings + right_f.suspect_readings),
            "rejected_readings": float(left_f.rejected_readings + right_f.rejected_readings),
        }
        state = "ok" if left_f.initialized and right_f.initialized else "starting"
        self.bus.publish(HEALTH, DriverHealth(stamp, "odometry", state, counters=counters))

    async def close(self) -> None:
        """Stop listening."""
        self._sub.close()
