"""Odometry + IMU fusion: an extended Kalman filter in ``odom``.

State (``odom`` frame, REP-105): ``x`` m, ``y`` m, ``yaw`` rad, ``v`` m/s (forward speed in
``base_link``), ``omega`` rad/s (yaw rate) and ``b_gyro`` rad/s (the gyro's z bias, so a biased
BNO055 does not turn the estimate when the wheels say the rover drives straight).

Process: constant velocity and yaw rate with white acceleration noise
(``process_accel_sigma_mps2``, ``process_yaw_accel_sigma_radps2``), a slow random walk of the
bias. Measurements, each gated by its Mahalanobis distance (``gate_mahalanobis``):

* wheel odometry (``WHEEL_ODOM``): the average forward speed over the interval since the previous
  message, from the pose increment (``odom_speed_sigma_mps``); the yaw rate too
  (``odom_yaw_rate_sigma_radps``) only while no gyro is heard (``IMU`` silent for
  ``GYRO_TIMEOUT_S``) — with a gyro, the wheels' per-message yaw rate is too jumpy (encoder dead
  zone, skid) to fuse every 20 ms: its errors bias the gyro-bias estimate and turn the rover.
* the gyro bias from a window comparison: every ``BIAS_WINDOW_S`` of wheel odometry, the gyro's
  integrated raw rate minus the wheels' yaw increment over the same interval, divided by its
  length, measures ``b_gyro`` (standard deviation ``BIAS_WINDOW_YAW_SIGMA_RAD`` / T plus
  ``BIAS_SKID_FRACTION`` of the turn / T), in windows where the gyro saw less than
  ``BIAS_MAX_TURN_RAD`` of turn (in turns the wheels' yaw lags, jumps and skids). A slipping
  wheel set that claims a turn the gyro does not see is rejected by the gate.
* the BNO055 (``IMU``): z angular rate = ``omega + b_gyro`` (``imu_yaw_rate_sigma_radps``; the
  samples that arrive between two EKF cycles are fused as one mean at their mean stamp); with
  ``use_imu_heading`` and a calibrated magnetometer, the absolute heading too
  (``imu_heading_sigma_rad``), offset so that the first accepted heading matches the filter's yaw.

The Kalman update is the Joseph form of filterpy's ``ExtendedKalmanFilter.update``, operation for
operation (a test checks that the two agree to the last bit): filterpy's generic update (copies,
a deep copy of every measurement, SciPy's checked inverse) cost more than the rest of the
filter, at 80 updates a second, and importing it pulled in ``scipy.stats``. A 1 × 1 innovation
covariance is inverted by one division (what LAPACK computes for it); the state and covariance
are kept as plain arrays. :class:`EkfNode` connects the filter to the bus and publishes ``ODOM``
(``odom`` → ``base_link``) at ``rate_hz``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import EkfConfig
from curio.core.geometry import Pose2D, quat_to_yaw, wrap_angle
from curio.core.messages import Imu, Odometry
from curio.core.topics import IMU, ODOM, WHEEL_ODOM

__all__ = ["EkfNode", "OdomEkf"]

F64 = npt.NDArray[np.float64]

X, Y, YAW, V, W, B = range(6)
MAX_EXTRAPOLATION_S = 0.25
GYRO_TIMEOUT_S = 0.25  # no IMU for this long: the wheels' yaw rate is fused again
BIAS_WINDOW_S = 1.0  # wheel-vs-gyro comparison window for the bias, seconds
BIAS_WINDOW_YAW_SIGMA_RAD = 0.01  # wheel + gyro yaw-increment error over one window
BIAS_SKID_FRACTION = 0.05  # extra yaw-increment error per radian turned (skid steering)
BIAS_MAX_TURN_RAD = 0.2  # windows in which the gyro saw a larger turn are not compared
_I6 = np.eye(6)
_I6.flags.writeable = False


def _inverse(s: F64) -> F64:
    """The inverse of the innovation covariance ``s`` (1 × 1: one division, as LAPACK does)."""
    if s.shape == (1, 1):
        return np.array([[1.0 / s[0, 0]]])
    from scipy import linalg  # filterpy's inverse; here: only when the gyro is silent (26 MB)

    return np.asarray(linalg.inv(s), dtype=np.float64)


def kalman_update(x: F64, p: F64, z: F64, h: F64, r: F64,
                  angle_rows: tuple[int, ...] = ()) -> tuple[F64, F64]:
    """One Kalman update of ``(x, p)`` with the linear measurement ``z = h @ x``, covariance
    ``r``, in Joseph form; return the new state and covariance (the inputs are not changed).

    The operations, and their order, are those of filterpy's ``ExtendedKalmanFilter.update``
    (``residual`` wraps the ``angle_rows`` of the innovation), so the result is the same to
    the last bit.
    """
    pht = np.dot(p, h.T)
    k = pht.dot(_inverse(np.dot(h, pht) + r))
    y = np.asarray(z, dtype=np.float64) - np.asarray(h @ x, dtype=np.float64)
    for i in angle_rows:
        y[i] = wrap_angle(float(y[i]))
    x_new = x + np.dot(k, y)
    i_kh = _I6 - np.dot(k, h)
    p_new = np.dot(i_kh, p).dot(i_kh.T) + np.dot(k, r).dot(k.T)
    return x_new, p_new


class OdomEkf:
    """The fusion filter, free of any bus or clock: feed it timestamped measurements.

    Attributes:
        t_s: the time of the state, seconds (None before the first measurement).
        rejected: measurements rejected by the Mahalanobis gate, by kind.
        accepted: measurements fused, by kind.
    """

    def __init__(self, cfg: EkfConfig, imu_yaw_in_base_rad: float = 0.0) -> None:
        self.cfg = cfg
        self._x: F64 = np.zeros(6)  # the state (owned: replaced, never handed out)
        self._p: F64 = np.diag([1e-9, 1e-9, 1e-9, 0.01, 0.01, 0.01**2])  # its covariance
        self.t_s: float | None = None
        self.imu_yaw_in_base_rad = imu_yaw_in_base_rad
        self._heading_offset: float | None = None
        self._last_wheel: Odometry | None = None
        self.rejected: dict[str, int] = {"wheel": 0, "gyro": 0, "heading": 0, "bias": 0}
        self.accepted: dict[str, int] = {"wheel": 0, "gyro": 0, "heading": 0, "bias": 0}
        self._last_imu_t: float | None = None
        self._last_imu_rate = 0.0
        # Bias window: gyro integral (rad) since wheel message ``_win_start`` (stamp, yaw).
        self._win_start: tuple[float, float] | None = None
        self._win_gyro_rad = 0.0
        # Read once from ``cfg`` (the same expressions as before, not re-evaluated per call).
        self._qa = cfg.process_accel_sigma_mps2**2  # (m/s²)² per Hz
        self._qw = cfg.process_yaw_accel_sigma_radps2**2  # (rad/s²)² per Hz
        self._qb = cfg.gyro_bias_walk_radps**2  # (rad/s)² per s
        self._r_v = cfg.odom_speed_sigma_mps**2  # (m/s)²
        # Scratch matrices, rewritten in place: the Jacobian (identity but for its motion
        # entries) and Q (zero but for its 8 process-noise entries); never handed out.
        self._f: F64 = np.eye(6)
        self._qm: F64 = np.zeros((6, 6))

    # --- state access ------------------------------------------------------------------------
    @property
    def x(self) -> F64:
        """The state vector (x, y, yaw, v, omega, b_gyro) — a copy."""
        return self._x.copy()

    @property
    def P(self) -> F64:
        """The state covariance — a copy."""
        return self._p.copy()

    @property
    def last_wheel_stamp(self) -> float | None:
        """Stamp of the last wheel-odometry message, seconds (None before the first)."""
        return None if self._last_wheel is None else self._last_wheel.stamp

    def pose(self) -> Pose2D:
        """``base_link`` in ``odom``."""
        s = self._x
        return Pose2D(float(s[X]), float(s[Y]), wrap_angle(float(s[YAW])))

    def odometry_at(self, t_s: float) -> Odometry:
        """The state extrapolated to ``t_s`` (without changing the filter) as an Odometry.

        The extrapolation stops ``MAX_EXTRAPOLATION_S`` after the last measurement, so a dead
        sensor freezes the pose instead of driving it away.
        """
        if self.t_s is not None and t_s > self.t_s:
            dt = min(t_s - self.t_s, MAX_EXTRAPOLATION_S)
            s = self._propagate_list(self._x.tolist(), dt)
            f = self._f
            c = (f @ self._p @ f.T)[:3, :3].ravel().tolist()
            q = self._q(dt)[:3, :3].ravel().tolist()
            # + Q's upper-left 3 × 3, element by element as the matrix sum does (its zeros
            # too: they turn a -0.0 into 0.0).
            cov: tuple[float, ...] = tuple(ci + qi for ci, qi in zip(c, q, strict=True))
        else:
            s = self._x.tolist()
            cov = tuple(self._p[:3, :3].ravel().tolist())
        x, y, yaw, v, w, _ = s
        return Odometry(t_s, Pose2D(x, y, wrap_angle(yaw)), v, w, cov)

    # --- prediction --------------------------------------------------------------------------
    def _propagate_list(self, s: list[float], dt: float) -> list[float]:
        """Constant (v, omega) motion of the state ``s`` over ``dt`` seconds; return the new
        state and write its Jacobian into ``self._f`` (valid until the next call)."""
        x, y, yaw, v, w, b = s
        mid = yaw + 0.5 * w * dt  # midpoint integration (exact enough at 50 Hz)
        c, sn = math.cos(mid), math.sin(mid)
        vdt = v * dt
        vc = vdt * c
        vs = vdt * sn  # -vs is -v * dt * sn to the bit (negation and rounding commute)
        f = self._f
        f[0, 2] = -vs
        f[0, 3] = dt * c
        f[0, 4] = -vs * 0.5 * dt
        f[1, 2] = vc
        f[1, 3] = dt * sn
        f[1, 4] = vc * 0.5 * dt
        f[2, 4] = dt
        return [x + vc, y + vs, yaw + w * dt, v, w, b]

    def _q(self, dt: float) -> F64:
        """The process noise over ``dt`` seconds (a scratch array, valid until the next call)."""
        qa, qw = self._qa, self._qw
        q = self._qm  # its other entries stay 0
        # White-acceleration model for (pos, v) and (yaw, omega).
        q[V, V] = qa * dt
        q[W, W] = qw * dt
        q[YAW, YAW] = qw * dt**3 / 3
        q[YAW, W] = q[W, YAW] = qw * dt**2 / 2
        q[X, X] = q[Y, Y] = qa * dt**3 / 3 + 1e-8 * dt
        q[B, B] = self._qb * dt
        return q

    def predict_to(self, t_s: float) -> None:
        """Advance the state to ``t_s`` (no-op for the first call or a stamp in the past)."""
        if self.t_s is None:
            self.t_s = t_s
            return
        dt = t_s - self.t_s
        if dt <= 0:
            return
        if dt > 1.0:  # a long gap (paused sensors): do not extrapolate old speeds far
            self._x[V] = 0.0
            self._x[W] = 0.0
        self._x = np.array(self._propagate_list(self._x.tolist(), dt))
        f = self._f
        p = f @ self._p @ f.T
        p += self._q(dt)
        self._p = p
        self.t_s = t_s

    # --- measurements ------------------------------------------------------------------------
    def _update(self, kind: str, z: F64, h: F64, r: F64, angle_rows: tuple[int, ...] = ()) -> bool:
        """Linear measurement ``z = h @ x`` with covariance ``r``, gated; return if fused."""
        y = z - h @ self._x
        for i in angle_rows:
            y[i] = wrap_angle(float(y[i]))
        cov = h @ self._p @ h.T + r
        if len(y) == 1:  # the usual case: a scalar measurement
            d2 = float(y[0] * y[0] / cov[0, 0]) if cov[0, 0] > 0.0 else math.inf
        else:
            try:
                d2 = float(y @ np.linalg.solve(cov, y))
            except np.linalg.LinAlgError:
                self.rejected[kind] += 1
                return False
        if not math.isfinite(d2) or math.sqrt(max(d2, 0.0)) > self.cfg.gate_mahalanobis:
            self.rejected[kind] += 1
            return False
        self._x, self._p = kalman_update(self._x, self._p, z, h, r, angle_rows)
        self._x[YAW] = wrap_angle(float(self._x[YAW]))
        self.accepted[kind] += 1
        return True

    def _update_unit(self, kind: str, z: float, cols: tuple[int, ...], r: float,
                     angle: bool = False) -> bool:
        """The usual measurement: the sum of one or two state entries ``cols`` (``h`` a row of
        ones there), variance ``r``, gated; return if fused. ``angle``: compare on the circle.

        The same result as :meth:`_update` with that ``h``, to the last bit: every sum it
        forms has at most two nonzero terms (exact in any order, fused or not), so it is done
        on Python floats; only the Joseph covariance product stays a matrix product.
        """
        x = self._x.tolist()
        a = cols[0]
        b = cols[1] if len(cols) > 1 else -1
        hx = x[a] if b < 0 else x[a] + x[b]
        y = z - hx
        if angle:
            y = wrap_angle(y)
        p = self._p
        pa = p[:, a].tolist()  # P's column a: pa[i] = P[i, a]
        if b < 0:  # h P hᵀ, summed as (h P) hᵀ; then the gain's P hᵀ and h (P hᵀ)
            cov = pa[a] + r
            pht = pa
            s_inv = 1.0 / cov  # pht[a] + r
        else:
            pb = p[:, b].tolist()
            cov = (pa[a] + pa[b]) + (pb[a] + pb[b]) + r
            pht = [ra + rb for ra, rb in zip(pa, pb, strict=True)]
            s_inv = 1.0 / ((pht[a] + pht[b]) + r)
        d2 = y * y / cov if cov > 0.0 else math.inf
        if not math.isfinite(d2) or math.sqrt(max(d2, 0.0)) > self.cfg.gate_mahalanobis:
            self.rejected[kind] += 1
            return False
        k = np.array(pht) * s_inv
        x_new = self._x + k * y
        i_kh = _I6.copy()
        for col in cols:
            i_kh[:, col] -= k
        p_new = np.dot(i_kh, p).dot(i_kh.T)
        p_new += (k * r)[:, None] * k  # np.outer(k * r, k)
        self._p = p_new
        x_new[YAW] = wrap_angle(float(x_new[YAW]))
        self._x = x_new
        self.accepted[kind] += 1
        return True

    def _update_bias_only(self, z: F64, h: F64, r: F64) -> bool:
        """Gated Schmidt update of ``b_gyro`` and ``yaw`` only (the other states' gains are 0).

        A full update would also move the position through its correlation with the bias (the
        past heading integrated the old bias): a jump of the ``odom`` position, which REP-105
        forbids (0.29 m at the end of a run was seen). The heading takes its share of the
        correction (a small rotation in place); the position's past error stays. The Joseph
        form keeps ``P`` consistent with the suboptimal gain.
        """
        p = self.P
        s_cov = h @ p @ h.T + r
        y = z - h @ self.x
        try:
            s_inv = np.linalg.inv(s_cov)
        except np.linalg.LinAlgError:
            self.rejected["bias"] += 1
            return False
        d2 = float(y @ s_inv @ y)
        if not math.isfinite(d2) or math.sqrt(max(d2, 0.0)) > self.cfg.gate_mahalanobis:
            self.rejected["bias"] += 1
            return False
        k = p @ h.T @ s_inv
        keep = np.zeros((6, 1))
        keep[B] = 1.0
        keep[YAW] = 1.0
        k = k * keep
        x = self.x + k @ y
        x[YAW] = wrap_angle(float(x[YAW]))
        ikh = np.eye(6) - k @ h
        self._x = x
        self._p = ikh @ p @ ikh.T + k @ r @ k.T
        self.accepted["bias"] += 1
        return True

    def add_wheel_odometry(self, odom: Odometry) -> bool:
        """Fuse one wheel-odometry message (the increment since the previous one)."""
        prev = self._last_wheel
        self._last_wheel = odom
        if prev is None:
            self.predict_to(odom.stamp)
            return False
        dt = odom.stamp - prev.stamp
        if dt <= 0:
            return False
        d = prev.pose.inverse() @ odom.pose
        v = math.copysign(math.hypot(d.x, d.y), d.x) / dt
        w = d.yaw / dt
        # The average over [prev, now] is the rate at the interval's middle.
        self.predict_to(odom.stamp - 0.5 * dt)
        r_v = self._r_v
        if self._gyro_alive(odom.stamp):
            ok = self._update_unit("wheel", v, (V,), r_v)
        else:
            h = np.zeros((2, 6))
            h[0, V] = 1.0
            h[1, W] = 1.0
            r = np.diag([r_v, self.cfg.odom_yaw_rate_sigma_radps**2])
            ok = self._update("wheel", np.array([v, w]), h, r)
            if not ok:
                # The yaw rate is the usual culprit (slip); keep the speed if it alone is sane.
                ok = self._update_unit("wheel", v, (V,), r_v)
        self.predict_to(odom.stamp)
        self._bias_window(odom)
        return ok

    def _gyro_alive(self, t_s: float) -> bool:
        return self._last_imu_t is not None and t_s - self._last_imu_t <= GYRO_TIMEOUT_S

    def _bias_window(self, odom: Odometry) -> None:
        """Close the wheel-vs-gyro window at ``odom`` when it is long enough (see module doc)."""
        yaw = odom.pose.yaw
        if self._win_start is None or not self._gyro_alive(odom.stamp):
            self._win_start = (odom.stamp, yaw)
            self._win_gyro_rad = 0.0
            return
        t0, yaw0 = self._win_start
        span = odom.stamp - t0
        if span < BIAS_WINDOW_S:
            return
        # The gyro integral runs to the last IMU sample: extend it to the wheel stamp.
        assert self._last_imu_t is not None
        gyro = self._win_gyro_rad + self._last_imu_rate * (odom.stamp - self._last_imu_t)
        turn = wrap_angle(yaw - yaw0)
        if abs(gyro - float(self._x[B]) * span) <= BIAS_MAX_TURN_RAD:
            # In turns the wheels' yaw lags and jumps (encoder dead zone) and skids: only
            # windows of (nearly) straight driving or standing still calibrate the gyro.
            z = (gyro - turn) / span
            sigma = math.hypot(BIAS_WINDOW_YAW_SIGMA_RAD, BIAS_SKID_FRACTION * abs(turn)) / span
            h = np.zeros((1, 6))
            h[0, B] = 1.0
            self._update_bias_only(np.array([z]), h, np.array([[sigma**2]]))
        self._win_start = (odom.stamp, yaw)
        self._win_gyro_rad = -self._last_imu_rate * (odom.stamp - self._last_imu_t)

    def add_imu(self, imu: Imu) -> bool:
        """Fuse one BNO055 sample: its z rate (and the heading, when enabled and calibrated)."""
        self.note_imu(imu)
        return self.fuse_imu([imu])

    def note_imu(self, imu: Imu) -> None:
        """Book one IMU sample (stamp order) for the bias window's gyro integral; no update.

        Every sample must be noted, in stamp order with the wheel messages, before it is
        fused with :meth:`fuse_imu`.
        """
        rate = float(imu.angular_velocity_radps[2])
        if self._last_imu_t is not None and self._win_start is not None:
            gap = imu.stamp - self._last_imu_t
            if 0.0 < gap <= GYRO_TIMEOUT_S:
                self._win_gyro_rad += 0.5 * (rate + self._last_imu_rate) * gap  # trapezoid
        if self._last_imu_t is None or imu.stamp >= self._last_imu_t:
            self._last_imu_t = imu.stamp
            self._last_imu_rate = rate

    def fuse_imu(self, samples: list[Imu]) -> bool:
        """Fuse consecutive, noted IMU samples as one gyro measurement; return if fused.

        The z rates of ``n`` samples a few milliseconds apart measure ``omega + b_gyro`` at their
        mean stamp with variance ``imu_yaw_rate_sigma_radps² / n`` — the information of ``n``
        separate updates under the constant-rate model, for one filter update. The heading
        (when enabled) is fused from the last sample, when it is calibrated.
        """
        if not samples:
            return False
        rate_sum = sum(float(imu.angular_velocity_radps[2]) for imu in samples)
        n = len(samples)
        self.predict_to(sum(imu.stamp for imu in samples) / n)
        ok = self._update_unit("gyro", rate_sum / n, (W, B),
                               self.cfg.imu_yaw_rate_sigma_radps**2 / n)
        last = samples[-1]
        if self.cfg.use_imu_heading and last.orientation_valid and self._calibrated(last):
            self.predict_to(last.stamp)
            yaw_base = wrap_angle(quat_to_yaw(last.orientation_xyzw) - self.imu_yaw_in_base_rad)
            if self._heading_offset is None:
                self._heading_offset = wrap_angle(float(self._x[YAW]) - yaw_base)
            z = wrap_angle(yaw_base + self._heading_offset)
            # The filter's yaw is unwrapped-by-wrap: compare on the circle.
            self._update_unit("heading", z, (YAW,), self.cfg.imu_heading_sigma_rad**2,
                              angle=True)
        return ok

    @staticmethod
    def _calibrated(imu: Imu) -> bool:
        """BNO055 levels (sys, gyro, accel, mag): gyro and magnetometer at 2 or better."""
        _, gyro, _, mag = imu.calibration
        return gyro >= 2 and mag >= 2


class EkfNode:
    """Bus adapter: ``WHEEL_ODOM`` + ``IMU`` → ``ODOM`` at ``rate_hz``."""

    def __init__(self, bus: Bus, clock: Clock, ekf: OdomEkf) -> None:
        self.bus = bus
        self.clock = clock
        self.ekf = ekf

    def _drain(self, wheel_sub: object, imu_sub: object) -> None:
        msgs: list[Odometry | Imu] = [*wheel_sub.drain(), *imu_sub.drain()]  # type: ignore[attr-defined]
        msgs.sort(key=lambda m: m.stamp)
        # The gyro is fused once per batch of samples (at their mean stamp), not per sample: a
        # batch goes in before a wheel message whose interval middle comes after it.
        pending: list[Imu] = []
        for m in msgs:
            if isinstance(m, Odometry):
                prev = self.ekf.last_wheel_stamp
                mid = m.stamp if prev is None else 0.5 * (prev + m.stamp)
                if pending and sum(i.stamp for i in pending) / len(pending) <= mid:
                    self.ekf.fuse_imu(pending)
                    pending = []
                self.ekf.add_wheel_odometry(m)
            else:
                self.ekf.note_imu(m)
                pending.append(m)
        self.ekf.fuse_imu(pending)

    async def run(self) -> None:
        """Fuse what arrived and publish ``ODOM`` every period."""
        wheel_sub = self.bus.subscribe(WHEEL_ODOM, maxsize=256)
        imu_sub = self.bus.subscribe(IMU, maxsize=512)
        try:
            async for t in self.clock.every(1.0 / self.ekf.cfg.rate_hz):
                self._drain(wheel_sub, imu_sub)
                if self.ekf.t_s is None:
                    continue
                self.bus.publish(ODOM, self.ekf.odometry_at(max(t, self.ekf.t_s)))
        finally:
            wheel_sub.close()
            imu_sub.close()
