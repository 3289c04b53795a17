"""EKF prediction: the in-place Jacobian and process noise give the bits of the plain formulas."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from curio.core.config import EkfConfig
from curio.core.geometry import wrap_angle
from curio.estimation.ekf import MAX_EXTRAPOLATION_S, OdomEkf

F64 = npt.NDArray[np.float64]


def _reference_predict(cfg: EkfConfig, s: F64, p: F64, dt: float) -> tuple[F64, F64]:
    """The prediction written out plainly: new arrays for F and Q, ``F P Fᵀ + Q``."""
    x, y, yaw, v, w, b = s.tolist()
    mid = yaw + 0.5 * w * dt
    c, sn = math.cos(mid), math.sin(mid)
    out = np.array([x + v * dt * c, y + v * dt * sn, yaw + w * dt, v, w, b])
    f = np.array([
        [1.0, 0.0, -v * dt * sn, dt * c, -v * dt * sn * 0.5 * dt, 0.0],
        [0.0, 1.0, v * dt * c, dt * sn, v * dt * c * 0.5 * dt, 0.0],
        [0.0, 0.0, 1.0, 0.0, dt, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    ])
    qa = cfg.process_accel_sigma_mps2**2
    qw = cfg.process_yaw_accel_sigma_radps2**2
    q = np.zeros((6, 6))
    q[3, 3] = qa * dt
    q[4, 4] = qw * dt
    q[2, 2] = qw * dt**3 / 3
    q[2, 4] = q[4, 2] = qw * dt**2 / 2
    q[0, 0] = q[1, 1] = qa * dt**3 / 3 + 1e-8 * dt
    q[5, 5] = cfg.gyro_bias_walk_radps**2 * dt
    return out, f @ p @ f.T + q


def _random_state(rng: np.random.Generator) -> tuple[F64, F64]:
    x = rng.normal(0.0, 3.0, 6)
    x[3] = rng.choice([0.0, -0.0, float(rng.normal(0.0, 1.0))])  # v: standing still too
    a = rng.normal(0.0, 0.3, (6, 6))
    p = a @ a.T + np.diag(rng.uniform(1e-6, 0.1, 6))
    p[0, 3] += 1e-17  # break the exact symmetry the way rounding does
    p *= 10.0 ** rng.uniform(-8.0, 0.0)  # small too: the bits of Q then show
    if rng.uniform() < 0.2:  # the start's diagonal, with signed zeros around it
        p = np.diag(np.diag(p)) * rng.choice([1.0, -1.0], (6, 6))
    return x, p


def test_predict_and_extrapolation_are_the_plain_formulas_to_the_last_bit() -> None:
    rng = np.random.default_rng(11)
    cfg = EkfConfig(process_accel_sigma_mps2=0.7, process_yaw_accel_sigma_radps2=2.3,
                    gyro_bias_walk_radps=0.0013)
    ekf = OdomEkf(cfg)
    for _ in range(100):
        x, p = _random_state(rng)
        ekf._x, ekf._p, ekf.t_s = x.copy(), p.copy(), 10.0
        ref_x, ref_p = x, p
        t = 10.0
        for _ in range(4):  # successive steps: the scratch arrays are reused
            dt = float(rng.uniform(1e-4, 1.0))  # not beyond 1 s: no speed reset
            # Extrapolation first (it must not change the filter), then the prediction.
            t_pub = t + float(rng.uniform(0.0, 0.4))
            odom = ekf.odometry_at(t_pub)
            if t_pub > t:
                ex, ep = _reference_predict(cfg, ref_x, ref_p, min(t_pub - t, MAX_EXTRAPOLATION_S))
            else:
                ex, ep = ref_x, ref_p
            got = [odom.pose.x, odom.pose.y, odom.pose.yaw, odom.linear_mps, odom.angular_radps]
            want = [ex[0], ex[1], wrap_angle(float(ex[2])), ex[3], ex[4]]
            assert np.array(got).tobytes() == np.array(want).tobytes()
            assert all(type(c) is float for c in odom.covariance)
            assert np.array(odom.covariance).tobytes() == ep[:3, :3].tobytes()
            t_new = t + dt
            ekf.predict_to(t_new)
            ref_x, ref_p = _reference_predict(cfg, ref_x, ref_p, t_new - t)
            t = t_new
            assert ekf._x.tobytes() == ref_x.tobytes()
            assert ekf._p.tobytes() == ref_p.tobytes()
