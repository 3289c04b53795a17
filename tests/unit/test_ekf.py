"""EKF: wheel odometry + gyro fusion, gyro bias, wheel slip, Mahalanobis gating, heading."""

from __future__ import annotations

import math

import numpy as np
import pytest

from curio.core.config import EkfConfig
from curio.core.geometry import Pose2D, wrap_angle, yaw_to_quat
from curio.core.messages import Imu, Odometry
from curio.estimation.ekf import OdomEkf


def _run(ekf: OdomEkf, seconds: float, v: float, w_true: float, *, gyro_bias: float = 0.0,
         wheel_w_error: float = 0.0, rng: np.random.Generator | None = None,
         heading: bool = False, t0: float = 0.0, start: Pose2D = Pose2D()) -> Pose2D:
    """Drive at (v, w_true) feeding 30 Hz wheel odometry and 100 Hz gyro; return the truth."""
    truth = start
    wheel = ekf._last_wheel.pose if ekf._last_wheel is not None else Pose2D()
    dt = 0.01
    steps = round(seconds / dt)
    for i in range(1, steps + 1):
        t = t0 + i * dt
        truth = truth @ Pose2D(v * dt, 0.0, w_true * dt)
        wheel = wheel @ Pose2D(v * dt, 0.0, (w_true + wheel_w_error) * dt)
        noise = rng.normal(0, 0.002) if rng is not None else 0.0
        ekf.add_imu(Imu(t, orientation_xyzw=yaw_to_quat(truth.yaw),
                        angular_velocity_radps=(0.0, 0.0, w_true + gyro_bias + noise),
                        orientation_valid=heading, calibration=(3, 3, 3, 3)))
        if i % 3 == 0:
            ekf.add_wheel_odometry(Odometry(t, wheel, v, w_true + wheel_w_error))
    return truth


def test_straight_drive_integrates_the_wheel_speed() -> None:
    ekf = OdomEkf(EkfConfig())
    truth = _run(ekf, 10.0, 0.3, 0.0)
    pose = ekf.pose()
    assert pose.x == pytest.approx(truth.x, abs=0.02)
    assert abs(pose.y) < 0.01
    assert ekf.x[3] == pytest.approx(0.3, abs=0.01)


def test_gyro_bias_is_estimated_and_does_not_turn_the_rover() -> None:
    ekf = OdomEkf(EkfConfig())
    rng = np.random.default_rng(1)
    _run(ekf, 30.0, 0.3, 0.0, gyro_bias=0.01, rng=rng)
    # A 0.01 rad/s bias integrated blindly would be 17° after 30 s.
    assert abs(ekf.pose().yaw) < math.radians(2.0)
    assert ekf.x[5] == pytest.approx(0.01, abs=0.003)


def test_wheel_slip_burst_is_outweighed_by_the_gyro() -> None:
    """Slipping wheels claim a 0.3 rad/s turn for 2 s that the gyro does not see."""
    ekf = OdomEkf(EkfConfig())
    _run(ekf, 5.0, 0.3, 0.0)
    assert ekf.rejected["bias"] == 0
    _run(ekf, 2.0, 0.3, 0.0, wheel_w_error=0.3, t0=5.0)
    _run(ekf, 3.0, 0.3, 0.0, t0=7.0)
    wheel_only = 0.3 * 2.0
    assert abs(ekf.pose().yaw) < 0.1 * wheel_only
    # The wheels-vs-gyro comparison over the slip windows is rejected, so the bias is not
    # dragged towards the slip.
    assert ekf.rejected["bias"] > 0
    assert abs(ekf.x[5]) < 0.01


def test_gate_rejects_an_outlier_wheel_message() -> None:
    ekf = OdomEkf(EkfConfig())
    _run(ekf, 2.0, 0.2, 0.1)
    before = ekf.rejected["wheel"]
    yaw_before = ekf.pose().yaw
    last = ekf._last_wheel
    assert last is not None
    # A glitch: 2 m and 90° in one 33 ms interval.
    glitch = Odometry(last.stamp + 0.033, last.pose @ Pose2D(2.0, 0.0, math.pi / 2))
    ekf.add_wheel_odometry(glitch)
    assert ekf.rejected["wheel"] > before
    assert abs(ekf.x[3] - 0.2) < 0.05
    assert abs(ekf.pose().yaw - yaw_before) < 0.05


def test_gate_can_be_opened() -> None:
    ekf = OdomEkf(EkfConfig(gate_mahalanobis=1e9))
    _run(ekf, 2.0, 0.2, 0.1)
    last = ekf._last_wheel
    assert last is not None
    ekf.add_wheel_odometry(Odometry(last.stamp + 0.033, last.pose @ Pose2D(2.0, 0.0, 0.0)))
    assert ekf.rejected["wheel"] == 0
    assert ekf.x[3] > 1.0


def test_absolute_heading_corrects_a_drifting_yaw_when_enabled() -> None:
    cfg = EkfConfig(use_imu_heading=True)
    ekf = OdomEkf(cfg)
    # Gyro and wheels both under-read the turn by 10 %; the heading is right.
    truth = Pose2D()
    wheel = Pose2D()
    for i in range(1, 2001):
        t = i * 0.01
        truth = truth @ Pose2D(0.003, 0.0, 0.005)
        wheel = wheel @ Pose2D(0.003, 0.0, 0.0045)
        ekf.add_imu(Imu(t, orientation_xyzw=yaw_to_quat(truth.yaw + 1.0),
                        angular_velocity_radps=(0.0, 0.0, 0.45), orientation_valid=True,
                        calibration=(3, 3, 3, 3)))
        if i % 3 == 0:
            ekf.add_wheel_odometry(Odometry(t, wheel))
    err = abs(math.remainder(ekf.pose().yaw - truth.yaw, 2 * math.pi))
    assert err < math.radians(3.0)
    assert ekf.accepted["heading"] > 1000


def test_heading_ignored_when_uncalibrated() -> None:
    ekf = OdomEkf(EkfConfig(use_imu_heading=True))
    ekf.add_imu(Imu(0.0, orientation_xyzw=yaw_to_quat(1.0), orientation_valid=True,
                    calibration=(0, 3, 3, 0)))
    ekf.add_imu(Imu(0.01, orientation_xyzw=yaw_to_quat(1.0), orientation_valid=True,
                    calibration=(0, 3, 3, 0)))
    assert ekf.accepted["heading"] == 0


def test_odometry_extrapolates_without_changing_the_state() -> None:
    ekf = OdomEkf(EkfConfig())
    _run(ekf, 3.0, 0.3, 0.0)
    x_before = ekf.x.copy()
    assert ekf.t_s is not None
    ahead = ekf.odometry_at(ekf.t_s + 0.2)
    assert ahead.pose.x == pytest.approx(x_before[0] + 0.06, abs=0.005)
    # A dead sensor: the pose holds after 0.25 s instead of running away.
    stale = ekf.odometry_at(ekf.t_s + 10.0)
    assert stale.pose.x == pytest.approx(x_before[0] + 0.075, abs=0.005)
    assert np.array_equal(ekf.x, x_before)
    assert ahead.frame_id == "odom" and ahead.child_frame_id == "base_link"



def test_bias_updates_do_not_make_the_odom_position_jump() -> None:
    """REP-105: ``odom`` is continuous. After driving with a gyro bias, the position is
    correlated with the bias; the wheel-vs-gyro bias correction must change the bias (and the
    heading) but not the position (a full Kalman update moved it 0.29 m at the end of a run)."""
    ekf = OdomEkf(EkfConfig())
    _run(ekf, 3.0, 0.3, 0.2, gyro_bias=0.0)
    p = ekf.P
    assert abs(p[0, 5]) + abs(p[1, 5]) > 0.0  # the pose is correlated with the bias
    before = ekf.x
    h = np.zeros((1, 6))
    h[0, 5] = 1.0
    assert ekf._update_bias_only(np.array([0.01]), h, np.array([[0.005**2]]))
    after = ekf.x
    assert after[0] == before[0] and after[1] == before[1] and after[3] == before[3]
    assert after[5] > before[5] + 0.002


def test_a_batch_of_gyro_samples_carries_the_information_of_separate_updates() -> None:
    """Fusing n samples as their mean with variance σ²/n gives the state and covariance of n
    sequential updates (same stamp: the linear update is exact)."""
    rates = [0.31, 0.29, 0.33, 0.27]
    one_by_one, batched = OdomEkf(EkfConfig()), OdomEkf(EkfConfig())
    samples = [Imu(1.0, angular_velocity_radps=(0.0, 0.0, r)) for r in rates]
    for ekf in (one_by_one, batched):
        ekf.predict_to(0.0)
        ekf.predict_to(1.0)
    for imu in samples:
        one_by_one.add_imu(imu)
    for imu in samples:
        batched.note_imu(imu)
    assert batched.fuse_imu(samples)
    assert batched.accepted["gyro"] == 1 and one_by_one.accepted["gyro"] == 4
    assert np.allclose(batched.x, one_by_one.x, atol=1e-12)
    assert np.allclose(batched.P, one_by_one.P, atol=1e-12)
    assert 0.25 < batched.x[4] + batched.x[5] < 0.35  # omega + bias near the mean rate


def _random_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A state and a symmetric positive-definite covariance, not exactly symmetric (as a
    propagated covariance is not)."""
    x = rng.normal(0.0, 1.0, 6)
    a = rng.normal(0.0, 0.3, (6, 6))
    p = a @ a.T + np.diag(rng.uniform(1e-6, 0.1, 6))
    p[0, 3] += 1e-17  # break the exact symmetry the way rounding does
    return x, p


@pytest.mark.parametrize("rows", [[(3,)], [(4, 5)], [(2,)], [(3,), (4,)]])
def test_kalman_update_is_filterpys_to_the_last_bit(rows: list[tuple[int, ...]]) -> None:
    """The Joseph update Curio does itself is filterpy's ExtendedKalmanFilter.update,
    operation for operation (filterpy is a test dependency only)."""
    from filterpy.kalman import ExtendedKalmanFilter

    from curio.estimation.ekf import kalman_update

    rng = np.random.default_rng(7)
    for _ in range(200):
        x, p = _random_state(rng)
        h = np.zeros((len(rows), 6))
        for i, cols in enumerate(rows):
            h[i, list(cols)] = 1.0
        z = rng.normal(0.0, 1.0, len(rows))
        r = np.diag(rng.uniform(1e-4, 0.1, len(rows)))
        angle_rows = (0,) if rows == [(2,)] else ()
        kf = ExtendedKalmanFilter(dim_x=6, dim_z=len(rows))
        kf.x, kf.P = x.copy(), p.copy()

        def residual(a: np.ndarray, b: np.ndarray,
                     angle_rows: tuple[int, ...] = angle_rows) -> np.ndarray:
            out = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
            for i in angle_rows:
                out[i] = wrap_angle(float(out[i]))
            return out

        kf.update(z, HJacobian=lambda _x, h=h: h, Hx=lambda s, h=h: h @ np.asarray(s),
                  R=r, residual=residual)
        x2, p2 = kalman_update(x, p, z, h, r, angle_rows)
        assert np.array_equal(np.asarray(kf.x).reshape(6), x2)
        assert np.array_equal(kf.P, p2)


@pytest.mark.parametrize(("cols", "angle"), [((3,), False), ((4, 5), False), ((2,), True)])
def test_the_scalar_update_equals_the_matrix_update_to_the_last_bit(
        cols: tuple[int, ...], angle: bool) -> None:
    rng = np.random.default_rng(3)
    for _ in range(300):
        x, p = _random_state(rng)
        z = float(rng.normal(0.0, 1.0))
        r = float(rng.uniform(1e-4, 0.1))
        matrix, scalar = OdomEkf(EkfConfig()), OdomEkf(EkfConfig())
        for ekf in (matrix, scalar):
            ekf._x, ekf._p = x.copy(), p.copy()
        h = np.zeros((1, 6))
        h[0, list(cols)] = 1.0
        ok = matrix._update("wheel", np.array([z]), h, np.array([[r]]),
                            angle_rows=(0,) if angle else ())
        assert scalar._update_unit("wheel", z, cols, r, angle=angle) == ok
        assert np.array_equal(matrix.x, scalar.x)
        assert np.array_equal(matrix.P, scalar.P)
