"""Mid-wheel odometry (hardware.md §2.4) and the LX-16A dead-zone filter (§4.5)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curio.core.clock import SimClock
from curio.core.config import Config
from curio.core.messages import ServoCommand, WheelEncoders
from curio.core.topics import SERVO_CMD, WHEEL_ODOM, make_bus
from curio.drivers.odometry import EncoderFilter, MidWheelOdometry, WheelOdometry
from curio.robot import RobotModel

R = 0.060 * 1.04
B = 0.52 * 0.96875
K = 2 * math.pi / 1500 * R  # metres per count


def test_effective_parameters_from_config() -> None:
    odo = WheelOdometry(RobotModel.from_config(Config().robot), make_bus(), SimClock())
    assert odo.odom.wheel_radius_m == pytest.approx(0.0624)
    assert odo.odom.track_m == pytest.approx(0.50375)


def test_straight_line_by_hand() -> None:
    odo = MidWheelOdometry(R, B)
    odo.update(0, 0, 0.0)
    # Left +750 counts (half a turn), right −750 (mirrored): both wheels forward by π·R′.
    st = odo.update(750, -750, 1.0)
    assert st.pose.x == pytest.approx(math.pi * R)
    assert st.pose.y == pytest.approx(0.0)
    assert st.pose.yaw == pytest.approx(0.0)
    assert st.linear_mps == pytest.approx(math.pi * R)
    assert st.angular_radps == pytest.approx(0.0)


def test_in_place_turn_by_hand() -> None:
    odo = MidWheelOdometry(R, B)
    odo.update(0, 0, 0.0)
    # Left back 100 counts, right forward 100 counts (read as −100): Δψ = 2·100·K / B′.
    st = odo.update(-100, -100, 0.5)
    dpsi = 2 * 100 * K / B
    assert st.pose.yaw == pytest.approx(dpsi)
    assert st.pose.x == pytest.approx(0.0, abs=1e-12)
    assert st.angular_radps == pytest.approx(dpsi / 0.5)


def test_exact_arc_by_hand() -> None:
    odo = MidWheelOdometry(R, B)
    odo.update(0, 0, 0.0)
    st = odo.update(300, -500, 1.0)  # left 300·K, right 500·K forward
    d_l, d_r = 300 * K, 500 * K
    dd, dpsi = (d_l + d_r) / 2, (d_r - d_l) / B
    rho = dd / dpsi
    assert st.pose.x == pytest.approx(rho * math.sin(dpsi))
    assert st.pose.y == pytest.approx(rho * (1 - math.cos(dpsi)))
    assert st.pose.yaw == pytest.approx(dpsi)


def test_twist_is_mean_of_last_five_and_skips_tiny_dt() -> None:
    odo = MidWheelOdometry(R, B)
    odo.update(0, 0, 0.0)
    counts = [10, 30, 60, 100, 150, 210]  # per-step increments 10, 20, 30, 40, 50, 60
    for i, c in enumerate(counts, start=1):
        st = odo.update(c, -c, i * 0.1)
    speeds = [d * K / 0.1 for d in (20, 30, 40, 50, 60)]
    assert st.linear_mps == pytest.approx(sum(speeds) / 5)
    before = st.linear_mps
    st = odo.update(300, -300, 0.6 + 5e-5)  # dt < 1e-4: pose integrates, twist does not
    assert st.linear_mps == pytest.approx(before)
    assert st.pose.x == pytest.approx(300 * K)


def _feed(f: EncoderFilter, raws: list[int | None], duty: float, dt: float = 1 / 30) -> list[float]:
    return [f.update(r, i * dt, duty * 1.5) for i, r in enumerate(raws)]


def test_filter_forward_through_dead_zone_and_wrap() -> None:
    # True counts advance 40 per sample from 1100; readings in 1190..1310 are garbage that
    # sticks at 1185..1194, and the counts wrap at 1500.
    true = [1100 + 40 * i for i in range(12)]
    raws: list[int | None] = []
    for c in true:
        m = c % 1500
        raws.append(1188 if 1190 <= m < 1310 else m)
    f = EncoderFilter()
    out = _feed(f, raws, duty=800.0)
    for got, want in zip(out, true, strict=True):
        assert got == pytest.approx(want - 1100, abs=45)
    # Once past the zone and the wrap, the count is exact again.
    assert out[-1] == pytest.approx(true[-1] - 1100)
    assert f.suspect_readings >= 3


def test_filter_reverse_wrap() -> None:
    true = [100 - 35 * i for i in range(14)]  # 100 → −355: wraps to 1145 through the zone
    raws = [c % 1500 for c in true]
    raws = [1190 if 1190 <= r < 1310 else r for r in raws]
    f = EncoderFilter()
    out = _feed(f, raws, duty=-700.0)
    assert out[-1] == pytest.approx(true[-1] - 100)


def test_filter_rejects_a_wild_jump_and_missing_readings() -> None:
    f = EncoderFilter()
    raws: list[int | None] = [0, 20, 40, 60, 900, None, 120, 140]
    out = _feed(f, raws, duty=400.0)
    assert out[4] == pytest.approx(80, abs=5)  # 900 is implausible: predicted instead
    assert out[5] == pytest.approx(100, abs=5)
    assert out[-1] == pytest.approx(140)
    assert f.rejected_readings == 1


def test_filter_believes_persistent_readings() -> None:
    f = EncoderFilter(max_rejects=2)
    out = _feed(f, [0, 0, 0, 500, 505, 510, 515], duty=0.0)  # wheel really was turned by hand
    assert out[-1] == pytest.approx(515)


def test_filter_waits_for_a_valid_first_reading() -> None:
    f = EncoderFilter()
    assert f.update(1200, 0.0) == 0.0 and not f.initialized
    assert f.update(None, 0.1) == 0.0 and not f.initialized
    f.update(1320, 0.2)
    assert f.initialized
    assert f.update(1340, 0.3) == pytest.approx(20)


async def test_component_publishes_wheel_odom() -> None:
    bus = make_bus()
    odo = WheelOdometry(RobotModel.from_config(Config().robot), bus, SimClock())
    sub = bus.subscribe(WHEEL_ODOM, maxsize=10)
    bus.publish(SERVO_CMD, ServoCommand(0.0, (500, 500, 500, -500, -500, -500), (500,) * 4))
    assert odo.handle(WheelEncoders(0.0, (0, 0, 0, 0, 0, 0))) is not None
    out = odo.handle(WheelEncoders(0.1, (0, 75, 0, 0, 1425, 0)))
    assert out is not None
    assert out.frame_id == "odom" and out.child_frame_id == "base_link"
    assert out.pose.x == pytest.approx(75 * K)
    assert out.pose.yaw == pytest.approx(0.0)
    assert len(sub.drain()) == 2


@settings(max_examples=100, deadline=None)
@given(left=st.integers(-600, 600), right=st.integers(-600, 600), steps=st.integers(1, 12))
def test_constant_arc_is_independent_of_sampling(left: int, right: int, steps: int) -> None:
    """Exact-arc integration: one step or many give the same pose on a constant arc."""
    one = MidWheelOdometry(R, B)
    one.update(0, 0, 0.0)
    a = one.update(left * steps, -right * steps, 1.0).pose
    many = MidWheelOdometry(R, B)
    many.update(0, 0, 0.0)
    for k in range(1, steps + 1):
        b = many.update(left * k, -right * k, k / steps).pose
    assert b.x == pytest.approx(a.x, abs=1e-9)
    assert b.y == pytest.approx(a.y, abs=1e-9)
    assert math.remainder(b.yaw - a.yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
