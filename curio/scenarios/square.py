"""The ``square`` scenario: drive a 2 m square open loop and score odometry against truth.

The script publishes velocity commands on ``/cmd_vel_nav`` at 20 Hz (the safety stage forwards
them to ``/cmd_vel``): four times "drive ``side_m`` forward at ``speed_mps``, settle, turn 90°
left in place at ``turn_radps``, settle", with each leg's duration computed from the nominal
speeds (open loop: no feedback from any estimate). The rover's real motion differs from the
commands (acceleration limits, steering slew, the simulator's wheel scale error and heading
drift); what is scored is how well odometry followed the real motion.

Metrics (``report["metrics"]``), every pose compared relative to where it was at the start:

* ``wheel_odom_final_error_m`` / ``wheel_odom_final_heading_error_rad`` — ``/wheel_odom``;
* ``odom_final_error_m`` / ``odom_final_heading_error_rad`` — the fused ``/odom`` (if any);
* ``wheel_odom_side_errors_m`` — the position error after each side;
* ``truth_final_offset_m`` — how far the rover really ended from its start (open-loop closure);
* ``bound_position_m`` / ``bound_heading_rad`` — the bounds checked (below).

Checks: no collision; the wheel-odometry error within the bound the simulator's noise model
allows: heading ≤ ``drift·L + scale_error·Θ + 4·0.05`` rad and position
≤ ``(scale_error + ½·heading_bound + 0.03)·L``, with ``L`` the distance driven (8 m), ``Θ`` the
rotation commanded (2π), ``scale_error = cfg.sim.noise.odom_scale_error`` (the true wheel radius
differs from the calibrated one by up to that fraction, which also scales every turn) and
``drift = cfg.sim.noise.odom_heading_drift_rad_per_m`` (a heading drift no wheel sees); 0.05 rad
per turn is the scrub while the corner servos swing.
"""

from __future__ import annotations

import math

from curio.core.bus import Topic
from curio.core.config import Config
from curio.core.geometry import Pose2D, angle_diff
from curio.core.messages import Odometry, Twist
from curio.core.topics import CMD_VEL_NAV, GROUND_TRUTH, ODOM, WHEEL_ODOM
from curio.scenarios.base import Scenario, ScenarioArgs, ScenarioContext, ScenarioFailed

__all__ = ["SquareScenario"]

RATE_HZ = 20.0
# Heading odometry cannot see while the corner servos swing between straight and in-place
# angles (the wheels scrub): measured ≈ 0.024 rad per 90° turn with the noise switched off.
TURN_SCRUB_RAD = 0.05


class SquareScenario(Scenario):
    """Open-loop 2 m square; odometry error against ground truth."""

    name = "square"
    description = "drive a 2 m square open loop and report odometry error against ground truth"
    default_duration_s = 180.0
    side_m = 2.0
    speed_mps = 0.3
    turn_radps = 0.6
    settle_s = 0.6

    def configure(self, cfg: Config, args: ScenarioArgs) -> Config:
        """Run as configured (the behaviour tree does not move the rover on its own)."""
        return cfg

    async def _hold(self, ctx: ScenarioContext, v: float, w: float, duration_s: float) -> None:
        end = ctx.now() + duration_s
        while ctx.now() < end - 1e-9:
            ctx.bus.publish(CMD_VEL_NAV, Twist(ctx.now(), v, w, source="scenario"))
            await ctx.sleep(min(1.0 / RATE_HZ, end - ctx.now()))

    async def run(self, ctx: ScenarioContext) -> None:
        """Drive the square and score the odometry."""
        if not await ctx.wait_until(
                lambda: ctx.bus.latest(GROUND_TRUTH) is not None
                and ctx.bus.latest(WHEEL_ODOM) is not None, 5.0, 0.05):
            raise ScenarioFailed("no /ground_truth or /wheel_odom within 5 s: is the simulator"
                                 " running (drivers.mode = sim or emulated)?")
        await ctx.sleep(0.5)
        truth0 = _pose(ctx, GROUND_TRUTH)
        wodom0 = _pose(ctx, WHEEL_ODOM)
        odom0 = _pose_or_none(ctx, ODOM)
        side_errors: list[float] = []
        for side in range(4):
            await self._hold(ctx, self.speed_mps, 0.0, self.side_m / self.speed_mps)
            await self._hold(ctx, 0.0, 0.0, self.settle_s)
            await self._hold(ctx, 0.0, self.turn_radps, (math.pi / 2) / self.turn_radps)
            await self._hold(ctx, 0.0, 0.0, self.settle_s)
            err = _relative_error(ctx, truth0, wodom0, WHEEL_ODOM)
            side_errors.append(round(err[0], 4))
            ctx.record("square.side", side=side + 1, wheel_odom_error_m=round(err[0], 4))
        await self._hold(ctx, 0.0, 0.0, 1.0)

        length = 4 * self.side_m
        noise = ctx.cfg.sim.noise
        drift = noise.odom_heading_drift_rad_per_m
        rotation = 4 * math.pi / 2
        bound_yaw = (drift * length + noise.odom_scale_error * rotation
                     + TURN_SCRUB_RAD * 4)
        bound_pos = (noise.odom_scale_error + 0.5 * bound_yaw + 0.03) * length
        pos_err, yaw_err = _relative_error(ctx, truth0, wodom0, WHEEL_ODOM)
        truth_end = _pose(ctx, GROUND_TRUTH)
        m = ctx.metrics
        m["distance_commanded_m"] = length
        m["wheel_odom_final_error_m"] = round(pos_err, 4)
        m["wheel_odom_final_heading_error_rad"] = round(yaw_err, 4)
        m["wheel_odom_side_errors_m"] = side_errors
        m["truth_final_offset_m"] = round(truth0.distance_to(truth_end), 4)
        m["truth_final_heading_change_rad"] = round(angle_diff(truth_end.yaw, truth0.yaw), 4)
        m["bound_position_m"] = round(bound_pos, 4)
        m["bound_heading_rad"] = round(bound_yaw, 4)
        if odom0 is not None and ctx.bus.latest(ODOM) is not None:
            o_pos, o_yaw = _relative_error(ctx, truth0, odom0, ODOM)
            m["odom_final_error_m"] = round(o_pos, 4)
            m["odom_final_heading_error_rad"] = round(o_yaw, 4)
        world = ctx.world
        if world is not None:
            m["sim_wheel_scale_error"] = round(world.scale_error, 5)
        ctx.check("no_collision", world is None or world.collisions == 0,
                  f"{0 if world is None else world.collisions} collisions")
        ctx.check("wheel_odom_position_within_bound", pos_err <= bound_pos,
                  f"{pos_err:.3f} m <= {bound_pos:.3f} m")
        ctx.check("wheel_odom_heading_within_bound", abs(yaw_err) <= bound_yaw,
                  f"{abs(yaw_err):.3f} rad <= {bound_yaw:.3f} rad")


def _pose(ctx: ScenarioContext, topic: Topic[Odometry]) -> Pose2D:
    pose = _pose_or_none(ctx, topic)
    if pose is None:
        raise ScenarioFailed("a pose topic went silent")
    return pose


def _pose_or_none(ctx: ScenarioContext, topic: Topic[Odometry]) -> Pose2D | None:
    msg = ctx.bus.latest(topic)
    return None if msg is None else msg.pose


def _relative_error(ctx: ScenarioContext, truth0: Pose2D, est0: Pose2D,
                    topic: Topic[Odometry]) -> tuple[float, float]:
    """Position (m) and heading (rad) error of the estimate's motion since the start."""
    truth_rel = _pose(ctx, GROUND_TRUTH).relative_to(truth0)
    est_rel = _pose(ctx, topic).relative_to(est0)
    return (truth_rel.distance_to(est_rel), angle_diff(est_rel.yaw, truth_rel.yaw))
