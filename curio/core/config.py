"""Typed, validated configuration (``config.toml`` plus ``--set KEY=VALUE`` overrides).

One pydantic model per section; every key carries its unit in its name. Unknown keys, wrong
types and out-of-range values raise :class:`ConfigError` with a message that names the key, the
value and what is allowed (the CLI turns it into exit code 2). Relative paths in the file are
resolved against the directory of the config file.
"""

from __future__ import annotations

import copy
import difflib
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from curio.core.errors import SetupError

__all__ = ["Config", "ConfigError", "config_from_data", "default_config_path", "dump_config",
           "load_config"]

REPO_ROOT = Path(__file__).resolve().parents[2]


class ConfigError(SetupError):
    """A configuration problem, phrased for the person who has to fix it."""


class Section(BaseModel):
    """Base of every section: unknown keys are errors, assignments are validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


Point2 = tuple[float, float]


class RobotConfig(Section):
    """The rover's geometry and limits (hardware.md §2)."""

    name: str = "curio"
    footprint: list[Point2] = Field(
        default_factory=lambda: [(0.33, 0.31), (0.33, -0.31), (-0.33, -0.31), (-0.33, 0.31)],
        description="footprint polygon in base_link, metres (counter-clockwise or clockwise)",
    )
    wheel_radius_m: float = Field(0.060, gt=0.0, le=0.5)
    mid_wheel_track_m: float = Field(0.52, gt=0.0, le=2.0)
    corner_wheel_track_m: float = Field(0.47, gt=0.0, le=2.0,
                                        description="lateral separation of front/back wheels")
    front_wheel_lon_m: float = Field(0.28, gt=0.0, le=2.0,
                                     description="front axle ahead of the mid axle")
    back_wheel_lon_m: float = Field(0.25, gt=0.0, le=2.0,
                                    description="back axle behind the mid axle")
    wheel_radius_multiplier: float = Field(1.04, gt=0.5, le=1.5)
    mid_wheel_track_multiplier: float = Field(0.96875, gt=0.5, le=1.5)
    max_wheel_speed_mps: float = Field(0.37, gt=0.0, le=2.0)
    max_angular_radps: float = Field(1.45, gt=0.0, le=10.0)
    laser_pose: tuple[float, float, float] = Field(
        (0.152, 0.078, 0.0), description="laser in base_link: x m, y m, yaw rad"
    )
    imu_pose: tuple[float, float, float] = Field(
        (0.110, -0.043, 0.0), description="imu_link in base_link: x m, y m, yaw rad"
    )
    home: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="home pose in map: x m, y m, yaw rad"
    )

    @field_validator("footprint")
    @classmethod
    def _footprint_is_polygon(cls, value: list[Point2]) -> list[Point2]:
        if len(value) < 3:
            raise ValueError("a footprint needs at least 3 points [[x, y], ...] in metres")
        return value


class ArduinoConfig(Section):
    """The Arduino Mega base controller link."""

    port: str = "/dev/curio-arduino"
    baud: int = Field(115200, gt=0)
    cmd_timeout_s: float = Field(0.5, gt=0.0, le=5.0)
    boot_wait_s: float = Field(2.0, ge=0.0, le=10.0)
    feedback_rate_hz: float = Field(30.0, gt=0.0, le=40.0, description="SERVO_POS rate")
    cmd_rate_hz: float = Field(20.0, gt=0.0, le=50.0, description="SERVO_CMD send rate")
    mcu_cmd_timeout_s: float = Field(
        0.5, ge=0.05, le=5.0, description="firmware motion watchdog (wheels stop)"
    )
    link_timeout_s: float = Field(
        0.5, gt=0.0, le=10.0, description="no frame from the Mega this long: reconnect"
    )
    reconnect_max_s: float = Field(2.0, gt=0.0, le=60.0, description="reconnect back-off cap")
    wheel_ids: list[int] = Field(default_factory=lambda: [11, 12, 13, 21, 22, 23])
    steer_ids: list[int] = Field(default_factory=lambda: [111, 131, 211, 231])
    steer_trim: list[int] = Field(
        default_factory=lambda: [-10, -5, 40, 20], description="LX-16A units, 0.24° each"
    )
    steer_move_ms: int = Field(50, ge=0, le=30000)
    low_battery_v: float = Field(6.6, ge=0.0, le=20.0)
    persist_steer_trim: bool = Field(False, description="also save trims in servo EEPROM")
    rc_enabled: bool = Field(
        False, description="RC transmitter teleop: the Mega reports the receiver's channels and "
        "the driver publishes them on /cmd_vel_teleop (1100..1900 us -> full speed)"
    )
    rc_linear_channel: int = Field(0, ge=0, le=15, description="raw receiver order, 0-based")
    rc_angular_channel: int = Field(1, ge=0, le=15, description="raw receiver order, 0-based")
    rc_enable_channel: int = Field(4, ge=0, le=15, description="above 1800 us: teleop off")
    rc_angular_sign: Literal[-1, 1] = 1


class LidarConfig(Section):
    """The RPLidar A1."""

    port: str = "/dev/curio-lidar"
    baud: int = Field(115200, gt=0)
    stall_timeout_s: float = Field(1.0, gt=0.0, le=10.0)
    reply_timeout_s: float = Field(1.0, gt=0.0, le=10.0, description="GET_INFO/HEALTH answer")
    reset_wait_s: float = Field(0.5, ge=0.0, le=5.0, description="after RESET (A1 banner)")
    reconnect_s: float = Field(1.0, gt=0.0, le=30.0, description="between session attempts")
    beams: int = Field(360, ge=90, le=2000, description="fixed angle bins per LaserScan")
    range_min_m: float = Field(0.15, gt=0.0)
    range_max_m: float = Field(12.0, gt=0.0, le=40.0)
    angle_offset_rad: float = Field(
        0.0, ge=-6.3, le=6.3, description="added to pi - raw angle (mounting, hardware.md §8)"
    )
    min_nodes_per_scan: int = Field(20, ge=1, description="shorter revolutions are dropped")
    read_interval_s: float = Field(
        0.04, ge=0.0, le=0.05, description="batch serial reads (CPU); 0 = every chunk"
    )


class ImuConfig(Section):
    """The BNO055 on I2C."""

    i2c_bus: int = Field(1, ge=0)
    address: int = Field(0x28, description="0x28 (ADR low) or 0x29 (ADR high)")
    rate_hz: float = Field(100.0, gt=0.0, le=200.0)
    calibration_file: str = "bno055_calibration.json"
    mode: Literal["imu", "ndof"] = Field(
        "imu", description="imu: accel+gyro, relative heading (no magnetometer near servos)"
    )
    axis_map_config: int = Field(0x24, ge=0, le=0x3F, description="AXIS_MAP_CONFIG (0x24 = P1)")
    axis_map_sign: int = Field(0x00, ge=0, le=0x07, description="AXIS_MAP_SIGN")
    external_crystal: bool = Field(False, description="board has the 32.768 kHz crystal")
    boot_timeout_s: float = Field(2.0, gt=0.0, le=10.0, description="wait for CHIP_ID 0xA0")
    reconnect_s: float = Field(1.0, gt=0.0, le=30.0)
    max_consecutive_errors: int = Field(10, ge=1, description="failed reads before re-init")
    error_rate_warn: float = Field(0.01, ge=0.0, le=1.0, description="health degraded above")
    samples_per_wakeup: int = Field(
        4, ge=1, le=10, description="readings per I/O-thread trip (paced in the thread)"
    )

    @field_validator("address")
    @classmethod
    def _address(cls, value: int) -> int:
        if value not in (0x28, 0x29):
            raise ValueError("the BNO055 answers at 0x28 (40) or 0x29 (41)")
        return value


class DriversConfig(Section):
    """Which drivers run: simulator messages, real drivers on emulators, or hardware."""

    mode: Literal["sim", "emulated", "real"] = "sim"
    arduino: ArduinoConfig = Field(default_factory=ArduinoConfig)
    lidar: LidarConfig = Field(default_factory=LidarConfig)
    imu: ImuConfig = Field(default_factory=ImuConfig)


class SimNoiseConfig(Section):
    """Simulator noise and imperfections."""

    odom_scale_error: float = Field(0.05, ge=0.0, le=0.5, description="wheel scale error")
    odom_heading_drift_rad_per_m: float = Field(math.radians(2.0), ge=0.0, le=1.0)
    wheel_slip: float = Field(0.0, ge=0.0, le=0.5)
    lidar_range_sigma_m: float = Field(0.02, ge=0.0, le=1.0)
    lidar_dropout_fraction: float = Field(0.02, ge=0.0, le=1.0)
    lidar_invalid_fraction: float = Field(0.005, ge=0.0, le=1.0)
    gyro_bias_radps: float = Field(0.005, ge=-1.0, le=1.0)
    gyro_sigma_radps: float = Field(0.002, ge=0.0, le=1.0)
    accel_sigma_mps2: float = Field(0.05, ge=0.0, le=10.0)


class SimConfig(Section):
    """The built-in simulator."""

    world: str = "maps/curio_building.yaml"
    seed: int = Field(1, ge=0, description="random seed of the simulated world (>= 0)")
    start: tuple[float, float, float] | None = Field(
        None, description="start pose in map (x m, y m, yaw rad); default robot.home"
    )
    physics_rate_hz: float = Field(50.0, ge=10.0, le=1000.0)
    lidar_rate_hz: float = Field(10.0, ge=5.5, le=10.0)
    lidar_beams: int = Field(360, ge=90, le=2000)
    lidar_range_min_m: float = Field(0.15, gt=0.0)
    lidar_range_max_m: float = Field(12.0, gt=0.0, le=40.0)
    imu_rate_hz: float = Field(100.0, gt=0.0, le=400.0)
    wheel_feedback_rate_hz: float = Field(30.0, gt=0.0, le=200.0)
    steer_slew_radps: float = Field(math.radians(60.0) / 0.16, gt=0.0)
    speed: float | None = Field(
        None, gt=0.0, description="sim clock speed for `curio run`: None = real time"
    )
    noise: SimNoiseConfig = Field(default_factory=SimNoiseConfig)


class EkfConfig(Section):
    """Odometry + IMU fusion (the EKF of ``curio/estimation/ekf.py``)."""

    enabled: bool = True
    rate_hz: float = Field(50.0, gt=0.0, le=500.0)
    use_imu_heading: bool = False
    odom_yaw_rate_sigma_radps: float = Field(0.05, gt=0.0)
    imu_yaw_rate_sigma_radps: float = Field(0.01, gt=0.0)
    imu_heading_sigma_rad: float = Field(0.02, gt=0.0)
    gate_mahalanobis: float = Field(5.0, gt=0.0, description="reject measurements beyond this")
    odom_speed_sigma_mps: float = Field(0.02, gt=0.0)
    process_accel_sigma_mps2: float = Field(1.0, gt=0.0)
    process_yaw_accel_sigma_radps2: float = Field(3.0, gt=0.0)
    gyro_bias_walk_radps: float = Field(0.0005, ge=0.0, description="per sqrt(s)")


class LocalizationConfig(Section):
    """Particle-filter localisation in the known map (AMCL-class)."""

    enabled: bool = True
    map_yaml: str | None = Field(
        None, description="navigation map (map_server YAML); default sim.world"
    )
    mode: Literal["localize", "map"] = Field(
        "localize", description="localize in map_yaml, or map a new building while driven"
    )
    mapping_out: str = Field(
        "map.yaml", description="mode=map: where the map is saved at shutdown (in data_dir)"
    )
    min_particles: int = Field(200, ge=10)
    max_particles: int = Field(3000, ge=10)
    update_min_d_m: float = Field(0.02, ge=0.0, description="filter update after this travel")
    update_min_a_rad: float = Field(0.02, ge=0.0, description="or after this rotation")
    laser_beams: int = Field(60, ge=8, le=2000)
    laser_sigma_hit_m: float = Field(0.1, gt=0.0)
    laser_z_hit: float = Field(0.9, ge=0.0, le=1.0)
    laser_z_rand: float = Field(0.1, ge=0.0, le=1.0)
    laser_likelihood_max_dist_m: float = Field(2.0, gt=0.0)
    kld_err: float = Field(0.01, gt=0.0, lt=1.0)
    kld_z: float = Field(0.99, gt=0.0, lt=1.0)
    recovery_alpha_slow: float = Field(0.001, ge=0.0, le=1.0)
    recovery_alpha_fast: float = Field(0.1, ge=0.0, le=1.0)
    initial_std_xy_m: float = Field(0.25, gt=0.0)
    initial_std_yaw_rad: float = Field(0.2, gt=0.0)
    odom_alpha1: float = Field(0.05, ge=0.0, description="rotation noise from rotation")
    odom_alpha2: float = Field(0.01, ge=0.0, description="rotation noise from translation")
    odom_alpha3: float = Field(0.01, ge=0.0, description="translation noise from translation")
    odom_alpha4: float = Field(0.01, ge=0.0, description="translation noise from rotation")
    scan_match: bool = Field(True, description="refine the best cluster by Gauss-Newton")
    scan_match_beams: int = Field(180, ge=8, le=2000)
    scan_match_max_residual_m: float = Field(0.15, gt=0.0)
    inlier_distance_m: float = Field(0.12, gt=0.0, description="beam counts as fitting the map")
    lost_inlier_fraction: float = Field(0.45, ge=0.0, le=1.0)
    ok_inlier_fraction: float = Field(
        0.7, ge=0.0, le=1.0, description="'ok' needs this share of beams on the map")
    recheck_after_scans: int = Field(
        20, ge=1, description="middling fit this many updates in a row: search the map")
    lost_std_xy_m: float = Field(0.6, gt=0.0)
    lost_after_scans: int = Field(5, ge=1, description="poor scans in a row before 'lost'")
    auto_relocalize: bool = Field(True, description="global search when lost")
    global_step_m: float = Field(0.3, gt=0.0)
    global_yaw_step_rad: float = Field(0.17, gt=0.0)
    global_poses_per_scan: int = Field(
        20000, ge=1000, description="global search: poses scored per scan (~25 ms per 20000)")
    global_std_xy_m: float = Field(
        50.0, gt=0.0, description="an INITIAL_POSE std above this asks for global localisation"
    )


class CostmapConfig(Section):
    """Global and local costmaps."""

    obstacle_range_m: float = Field(5.5, gt=0.0)
    raytrace_range_m: float = Field(6.0, gt=0.0)
    static_mark_tolerance_cells: int = Field(
        1, ge=0, le=5, description="returns this close to a mapped wall are the wall (noise)")
    inflation_radius_m: float = Field(0.55, gt=0.0)
    cost_scaling_factor: float = Field(10.0, gt=0.0)
    footprint_padding_m: float = Field(0.01, ge=0.0)
    local_window_m: float = Field(6.0, gt=1.0)
    update_rate_hz: float = Field(5.0, gt=0.0)
    global_publish_rate_hz: float = Field(1.0, gt=0.0, description="COSTMAP at most this often")
    inf_is_valid: bool = Field(True, description="an inf range clears the whole ray")


class PlannerConfig(Section):
    """Global planner."""

    replan_rate_hz: float = Field(1.0, ge=0.0, description="0 = only when needed")
    blocked_confirm_s: float = Field(
        0.5, ge=0.0, description="replan at once when the plan has been blocked this long "
        "(filters single-scan lidar noise in narrow passages)")
    goal_nearest_free: bool = True
    goal_nearest_free_max_m: float = Field(0.5, ge=0.0)
    heuristic_weight: float = Field(
        1.2, ge=1.0, le=5.0,
        description="weighted A*: path cost at most this × the optimum; 1 = optimal, slower")
    cost_penalty: float = Field(
        3.0, ge=0.0, le=50.0,
        description="traversal cost per metre = 1 + cost_penalty * cost / 252 (keeps off walls)")
    narrow_penalty: float = Field(
        3.0, ge=0.0, le=50.0, description="extra traversal cost per metre (rising to this at "
        "the inscribed radius) where the centre is nearer an obstacle than the footprint's "
        "circumscribed radius: narrow passages are crossed straight and centred")
    allow_unknown: bool = Field(False, description="plan through unknown (255) cells")
    path_step_m: float = Field(0.05, gt=0.0, le=1.0, description="spacing of the output poses")
    smooth: bool = Field(True, description="shortcut and smooth the grid path")


class ControllerConfig(Section):
    """Local controller (defaults from the original's tuned values, original-system.md §6)."""

    rate_hz: float = Field(10.0, gt=0.0, le=100.0)
    max_speed_mps: float = Field(0.3, gt=0.0, le=1.0)
    max_angular_radps: float = Field(1.0, gt=0.0, le=4.0)
    max_accel_mps2: float = Field(0.8, gt=0.0)
    max_angular_accel_radps2: float = Field(3.0, gt=0.0)
    xy_goal_tolerance_m: float = Field(0.15, gt=0.0)
    yaw_goal_tolerance_rad: float = Field(0.2, gt=0.0)
    lookahead_m: float = Field(0.6, gt=0.0)
    progress_timeout_s: float = Field(10.0, gt=0.0)
    progress_min_distance_m: float = Field(0.1, gt=0.0)
    min_lookahead_m: float = Field(0.35, gt=0.0, description="lookahead near the goal / slow")
    rotate_enter_rad: float = Field(
        0.8, gt=0.0, le=math.pi, description="heading error above which Curio turns in place")
    rotate_exit_rad: float = Field(0.25, gt=0.0, le=math.pi)
    min_turning_radius_m: float = Field(
        0.45, ge=0.0, description="arcs tighter than this are not driven (Curio's corner servos "
        "swing 180 deg when the radius crosses 0.235 m); turn in place instead")
    max_curvature_rate_per_s: float = Field(
        4.0, gt=0.0, description="how fast the commanded curvature (1/m) may change per second "
        "(the steering servos need time to swing)")
    steer_settle_s: float = Field(
        0.3, ge=0.0, description="pause between turning in place and driving off")
    approach_decel_mps2: float = Field(
        0.3, gt=0.0, description="speed profile towards the goal: v <= sqrt(2 a d)")
    min_speed_mps: float = Field(0.05, ge=0.0)
    slow_clearance_m: float = Field(
        0.15, ge=0.0, description="slow down when an obstacle is nearer than this to the "
        "footprint")
    slow_min_fraction: float = Field(0.6, gt=0.0, le=1.0)
    collision_horizon_s: float = Field(1.2, gt=0.0)
    blocked_timeout_s: float = Field(
        3.0, gt=0.0, description="no admissible command for this long: the path is blocked")
    lost_timeout_s: float = Field(
        10.0, gt=0.0, description="while localisation is lost (or no pose comes) the rover "
        "holds still with the goal kept active; still lost after this long, the goal aborts")
    narrow_ahead_m: float = Field(
        1.0, ge=0.0, description="look this far along the plan for a narrow passage (where the "
        "centre is nearer an obstacle than the footprint's circumscribed radius); 0 = off")
    narrow_lookahead_m: float = Field(
        0.3, gt=0.0, description="pure-pursuit lookahead in and before a narrow passage (track "
        "the centred plan tightly so the rover enters aligned with it)")
    narrow_rotate_enter_rad: float = Field(
        0.45, gt=0.0, le=math.pi, description="heading error above which Curio turns in place "
        "in and before a narrow passage")


class SafetyConfig(Section):
    """The safety stage in front of the motors."""

    max_speed_mps: float = Field(0.37, gt=0.0, le=1.0)
    max_angular_radps: float = Field(1.45, gt=0.0, le=4.0)
    max_accel_mps2: float = Field(0.8, gt=0.0)
    max_angular_accel_radps2: float = Field(3.0, gt=0.0)
    stop_distance_m: float = Field(0.10, ge=0.0, description="margin around the footprint")
    slow_distance_m: float = Field(
        0.3, ge=0.0, description="approached obstacles nearer than this ahead slow the rover")
    lookahead_s: float = Field(1.0, gt=0.0)
    cmd_timeout_s: float = Field(0.5, gt=0.0)
    teleop_timeout_s: float = Field(0.5, gt=0.0)
    rate_hz: float = Field(20.0, gt=0.0, le=200.0)
    max_brake_mps2: float = Field(
        2.0, gt=0.0, description="deceleration allowed when the stop zone or e-stop brakes"
    )
    contact_margin_m: float = Field(
        0.02, ge=0.0, description="margin for points already inside stop_distance_m and for "
        "turning in place (the stop zone then only prevents contact)"
    )
    slow_min_fraction: float = Field(
        0.4, gt=0.0, le=1.0, description="speed fraction kept when approaching within "
        "slow_distance_m"
    )
    require_scan: bool = Field(
        True, description="stop when no lidar scan has arrived for scan_timeout_s"
    )
    scan_timeout_s: float = Field(1.0, gt=0.0)


RecoveryStep = Literal["clear_costmap", "step_back", "rotate", "wait"]
_DEFAULT_LADDER: tuple[RecoveryStep, ...] = ("clear_costmap", "step_back", "rotate", "wait")


class RecoveryConfig(Section):
    """The recovery ladder tried before a goal is aborted."""

    ladder: list[RecoveryStep] = Field(
        default_factory=lambda: list(_DEFAULT_LADDER)
    )
    step_back_distance_m: float = Field(1.0, gt=0.0, le=3.0)
    step_back_speed_mps: float = Field(
        0.3, gt=0.0, description="at most robot.max_wheel_speed_mps")
    step_back_clearance_m: float = Field(0.5, ge=0.0)
    rotate_angle_rad: float = Field(math.pi / 2, gt=0.0)
    wait_s: float = Field(5.0, ge=0.0)
    clear_radius_m: float = Field(
        1.5, ge=0.0, description="clear_costmap forgets obstacle marks this near the rover")
    step_back_timeout_s: float = Field(15.0, gt=0.0)
    rotate_speed_radps: float = Field(
        0.6, gt=0.0, description="at most robot.max_angular_radps")
    rotate_timeout_s: float = Field(10.0, gt=0.0)
    rate_hz: float = Field(10.0, gt=0.0, le=50.0, description="command rate of the actions")
    max_rounds: int = Field(
        2, ge=1, description="how often the whole ladder may be climbed for one goal")
    goal_progress_timeout_s: float = Field(
        20.0, gt=0.0, description="no 0.3 m closer to the goal along the plan for this long: "
        "stuck (catches a rover dithering at a gap it cannot pass)")
    keep_out_radius_m: float = Field(
        0.3, ge=0.0, description="where the rover got stuck, replans avoid this radius")
    keep_out_s: float = Field(90.0, ge=0.0, description="how long a keep-out spot lasts")


class BlockedConfig(Section):
    """Blocked-path detection (the original's obstaclesdist.py, fixed)."""

    obstacle_distance_m: float = Field(1.1, gt=0.0)
    obstacle_angle_rad: float = Field(0.7, gt=0.0, le=math.pi)
    no_progress_s: float = Field(8.0, gt=0.0)
    progress_distance_m: float = Field(0.1, gt=0.0)
    corridor_margin_m: float = Field(
        0.1, ge=0.0, description="an obstacle counts only within the footprint's half width "
        "plus this of the line of travel (walls beside a corridor never block)")
    rate_hz: float = Field(5.0, gt=0.0, le=50.0, description="BLOCKED publish rate")
    group_distance_m: float = Field(
        0.1, gt=0.0, description="extraction: neighbouring points closer than this (plus "
        "distance_proportion x range) form one group")
    distance_proportion: float = Field(0.00628, ge=0.0)
    min_group_points: int = Field(5, ge=2)
    split_distance_m: float = Field(0.04, gt=0.0, description="split-and-merge tolerance")
    max_circle_radius_m: float = Field(0.3, gt=0.0, description="shorter groups are circles")
    radius_enlargement_m: float = Field(0.05, ge=0.0)


class NavConfig(Section):
    """Navigation stack."""

    costmap: CostmapConfig = Field(default_factory=CostmapConfig)
    planner: PlannerConfig = Field(default_factory=PlannerConfig)
    controller: ControllerConfig = Field(default_factory=ControllerConfig)
    safety: SafetyConfig = Field(default_factory=SafetyConfig)
    recovery: RecoveryConfig = Field(default_factory=RecoveryConfig)
    blocked: BlockedConfig = Field(default_factory=BlockedConfig)


class PathConfig(Section):
    """One path of the path manager: points in map (metres) and optional headings (deg)."""

    name: str = ""
    points: list[Point2]
    yaw_deg: list[float] | None = None

    @field_validator("yaw_deg")
    @classmethod
    def _one_yaw_per_point(cls, value: list[float] | None, info: Any) -> list[float] | None:
        points = info.data.get("points")
        if value is not None and points is not None and len(value) != len(points):
            raise ValueError(f"yaw_deg needs one heading per point ({len(points)}), "
                             f"got {len(value)}")
        return value


def _default_paths() -> list[PathConfig]:
    return [
        PathConfig(name="Home", points=[(0.0, 0.0)], yaw_deg=[0.0]),
        PathConfig(name="Path 1", points=[(0.2, 0.0), (-0.2, 0.0), (0.5, 0.0)],
                   yaw_deg=[90.0, 0.0, 180.0]),
        PathConfig(name="Path 2", points=[(1.0, 1.0), (2.0, 2.0), (3.0, 4.0)],
                   yaw_deg=[0.0, 0.0, 0.0]),
    ]


class TourStopConfig(Section):
    """A stop of the tour: where, how long to dwell, what to tell the visitors."""

    name: str
    x_m: float
    y_m: float
    yaw_deg: float | None = None
    dwell_s: float = Field(10.0, ge=0.0)
    message: str = ""


class BtConfig(Section):
    """Behaviour tree."""

    tree: Literal["follow_path", "two_step", "tour"] = "follow_path"
    tick_hz: float = Field(2.0, gt=0.0, le=100.0)
    autostart_path: int | None = Field(
        None, description="path to start on at boot (the original drove path 1 at once)"
    )
    help_timeout_s: float = Field(120.0, gt=0.0)
    help_timeout_action: Literal["replan", "go_home", "keep_waiting"] = "replan"
    help_clear_s: float = Field(2.0, ge=0.0, description="way must stay clear this long")
    help_rearm_s: float = Field(
        15.0, ge=0.0,
        description="after a help episode that ended without the way clearing (help_done, "
        "timeout, pre-emption), ignore BLOCKED this long unless it first reports clear",
    )
    low_battery_v: float = Field(6.6, ge=0.0)
    battery_ok_v: float = Field(7.0, ge=0.0)
    speak: bool = True
    two_step_goals: list[tuple[float, float, float]] = Field(
        default_factory=lambda: [(1.0, 1.0, 0.0), (2.0, 2.0, 0.0)]
    )
    paths: list[PathConfig] = Field(default_factory=_default_paths)
    paths_file: str = "paths.json"
    tour_stops: list[TourStopConfig] = Field(default_factory=list)
    tour_loop: bool = False


class ToursConfig(Section):
    """Tours as data, their schedules and the tour guide's product behaviour (curio/tours)."""

    file: str = Field("tours.json", description="the tours, in data_dir (a .bak beside it)")
    schedules_file: str = Field("schedules.json", description="the schedules, in data_dir")
    timezone: str = Field("UTC", description="the building's IANA time zone for schedules "
                          "and daily reports, e.g. Europe/London")
    start_window_s: float = Field(
        120.0, ge=0.0, le=3600.0,
        description="a scheduled tour whose rover is not ready at its time may still start "
        "this long after it; then it is skipped with the reason")
    min_battery_v: float = Field(7.0, ge=0.0, description="scheduled tours start only at or "
                                 "above this supply voltage")
    schedule_gap_s: float = Field(
        300.0, ge=0.0, le=7200.0,
        description="two scheduled tours overlap when the second starts before the first's "
        "estimated duration plus this gap (time to get home) has passed")
    check_period_s: float = Field(1.0, gt=0.0, le=60.0, description="scheduler check period")
    return_home: bool = Field(True, description="drive home when a tour has finished")
    announce_next_stop: bool = Field(True, description="say where the rover goes next when "
                                     "it leaves a stop")
    estimate_speed_mps: float = Field(0.2, gt=0.0, le=2.0, description="average speed for "
                                      "tour duration estimates (stops included separately)")
    estimate_detour_factor: float = Field(1.4, ge=1.0, le=5.0, description="route length / "
                                          "straight-line distance, for duration estimates")

    @field_validator("timezone")
    @classmethod
    def _known_zone(cls, value: str) -> str:
        from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

        try:
            ZoneInfo(value)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"unknown time zone {value!r}; use an IANA name such as "
                             "'Europe/London' or 'UTC' (the names under /usr/share/zoneinfo)"
                             ) from None
        return value


class EventLogConfig(Section):
    """The lasting event log (SQLite in data_dir; curio/eventlog)."""

    enabled: bool = True
    file: str = Field("events.sqlite3", description="the database, in data_dir")
    max_age_days: float = Field(400.0, gt=0.0, description="older records are deleted")
    max_rows: int = Field(500_000, ge=1000, description="the oldest records beyond this are "
                          "deleted")
    batch_rows: int = Field(500, ge=1, le=100_000, description="most records per transaction")
    motion_summary_s: float = Field(60.0, gt=0.0, le=3600.0, description="distance and time "
                                    "moving are logged this often while they change")
    ignore_kinds: list[str] = Field(default_factory=list, description="event kinds (or "
                                    "prefixes ending in '.') that are not logged")


class WebConfig(Section):
    """The dashboard server."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = Field(8080, ge=0, le=65535)
    token_file: str = "web_token"
    require_token: bool = True
    max_message_bytes: int = Field(65536, ge=256)
    max_messages_per_s: float = Field(50.0, gt=0.0)
    client_rate_hz: float = Field(10.0, gt=0.0, le=60.0)
    allowed_origins: list[str] = Field(default_factory=list)


class RecordConfig(Section):
    """The flight recorder (``curio/record/``): the bus's topics to MCAP files.

    Files go to ``<data_dir>/<directory>/`` named by their start time, a new one after
    ``max_file_mb`` or ``max_file_s``; the oldest are deleted once all of them exceed
    ``max_total_mb``. A writer thread encodes and writes; the queue in front of it is bounded by
    ``queue_messages`` and ``queue_mb`` and drops its oldest messages (counted) when full.
    """

    enabled: bool = Field(True, description="record every run (curio sim records only with "
                          "--record FILE.mcap)")
    directory: str = Field("recordings", description="in data_dir unless absolute")
    file: str | None = Field(
        None, description="record into this one file instead (no rotation, no budget); "
        "`curio sim --record` sets it")
    max_file_mb: float = Field(64.0, gt=0.0, le=4096.0, description="start a new file beyond")
    max_file_s: float = Field(900.0, gt=0.0, description="start a new file after this long")
    max_total_mb: float = Field(
        2048.0, gt=0.0, description="disk budget of the directory: oldest files deleted first")
    flush_s: float = Field(
        1.0, gt=0.0, le=5.0, description="written to disk at least this often: a crash or "
        "kill -9 loses about this much (plus the writer's 0.05 s wake-up)")
    queue_messages: int = Field(20000, ge=100, description="unwritten messages held at most")
    queue_mb: float = Field(32.0, gt=0.0, le=1024.0, description="unwritten bytes held at most")
    local_costmap_rate_hz: float = Field(
        1.0, gt=0.0, le=50.0, description="/local_costmap recorded at most this often")
    costmap_rate_hz: float = Field(
        0.2, gt=0.0, le=50.0, description="/costmap (the whole building) at most this often; "
        "every /map is recorded")
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    exclude: list[str] = Field(
        default_factory=list, description="bus topics not recorded, e.g. [\"/imu\"]")
    log_level: Literal["debug", "info", "warning", "error"] = Field(
        "info", description="Python log records at or above this level go to /log")

    @field_validator("exclude")
    @classmethod
    def _known_topics(cls, value: list[str]) -> list[str]:
        from curio.core.topics import ALL_TOPICS

        names = sorted(t.name for t in ALL_TOPICS)
        unknown = [v for v in value if v not in names]
        if unknown:
            raise ValueError(f"unknown topic {unknown[0]!r}; topics: {', '.join(names)}")
        return value

    @model_validator(mode="after")
    def _file_fits_budget(self) -> RecordConfig:
        if self.max_file_mb > self.max_total_mb:
            raise ValueError(f"record.max_file_mb = {self.max_file_mb:g} is more than "
                             f"record.max_total_mb = {self.max_total_mb:g}; allowed: "
                             "max_file_mb <= max_total_mb")
        return self


class FoxgloveConfig(Section):
    """Live Foxglove / Lichtblick server (optional extra ``curio[foxglove]``): the recorder's
    channels live over ``foxglove-sdk``'s WebSocket server."""

    enabled: bool = False
    host: str = Field("127.0.0.1", description="bind address; reach it by an SSH tunnel, or "
                      "bind the LAN on purpose")
    port: int = Field(8765, ge=0, le=65535, description="0 picks a free port (tests)")
    teleop: bool = Field(
        True, description="accept /cmd_vel_teleop (geometry_msgs/Twist JSON) from a client that "
        "has set the parameter operator_token to the dashboard's token; through the safety stage")


class Config(Section):
    """The whole application configuration."""

    data_dir: str = Field("var", description="where paths, tokens and calibrations are kept")
    numba_cache_dir: str | None = Field(
        None, description="where the compiled kernels are cached (NUMBA_CACHE_DIR); must be "
        "writable by the user running curio (deploy/: /var/cache/curio/numba). None: next to "
        "the sources (a development checkout), or NUMBA_CACHE_DIR from the environment")
    robot: RobotConfig = Field(default_factory=RobotConfig)
    drivers: DriversConfig = Field(default_factory=DriversConfig)
    sim: SimConfig = Field(default_factory=SimConfig)
    ekf: EkfConfig = Field(default_factory=EkfConfig)
    localization: LocalizationConfig = Field(default_factory=LocalizationConfig)
    nav: NavConfig = Field(default_factory=NavConfig)
    bt: BtConfig = Field(default_factory=BtConfig)
    web: WebConfig = Field(default_factory=WebConfig)
    tours: ToursConfig = Field(default_factory=ToursConfig)
    eventlog: EventLogConfig = Field(default_factory=EventLogConfig)
    record: RecordConfig = Field(default_factory=RecordConfig)
    foxglove: FoxgloveConfig = Field(default_factory=FoxgloveConfig)

    # Where relative paths are resolved; not a config key.
    base_dir: Path = Field(default_factory=lambda: REPO_ROOT, exclude=True)

    @model_validator(mode="after")
    def _within_the_robot(self) -> Config:
        """Speeds that other sections ask of the robot must be within the robot's limits."""
        robot, rec = self.robot, self.nav.recovery
        if rec.step_back_speed_mps > robot.max_wheel_speed_mps:
            raise ValueError(
                f"nav.recovery.step_back_speed_mps = {rec.step_back_speed_mps:g} is faster than "
                f"the robot can drive (robot.max_wheel_speed_mps = {robot.max_wheel_speed_mps:g}); "
                "allowed: 0 < step_back_speed_mps <= robot.max_wheel_speed_mps")
        if rec.rotate_speed_radps > robot.max_angular_radps:
            raise ValueError(
                f"nav.recovery.rotate_speed_radps = {rec.rotate_speed_radps:g} is faster than the "
                f"robot can turn (robot.max_angular_radps = {robot.max_angular_radps:g}); "
                "allowed: 0 < rotate_speed_radps <= robot.max_angular_radps")
        return self

    def resolve(self, path_str: str) -> Path:
        """Resolve a path from the config against the config file's directory."""
        path = Path(path_str).expanduser()
        return path if path.is_absolute() else (self.base_dir / path)

    def data_path(self, name: str) -> Path:
        """A file inside ``data_dir`` (created on demand)."""
        directory = self.resolve(self.data_dir)
        directory.mkdir(parents=True, exist_ok=True)
        return directory / name


def default_config_path() -> Path | None:
    """``./config.toml`` if present, else the repository's shipped ``config.toml``."""
    for candidate in (Path.cwd() / "config.toml", REPO_ROOT / "config.toml"):
        if candidate.is_file():
            return candidate
    return None


def _fields_of(model: type[BaseModel]) -> list[str]:
    return [name for name, f in model.model_fields.items() if not f.exclude]


def _model_at(path: list[str]) -> type[BaseModel] | None:
    """The section model at a dotted path, or None if the path ends on a leaf."""
    model: type[BaseModel] = Config
    for part in path:
        field = model.model_fields.get(part)
        if field is None:
            return None
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            model = annotation
        else:
            return None
    return model


# Keys that older Curio versions accepted: an unknown-key error says what became of them.
REMOVED_KEYS: dict[str, str] = {
    "ekf.odom_position_sigma_m": "it was never used (the EKF fuses wheel speed, "
    "ekf.odom_speed_sigma_mps); delete the line",
    "log_level": "it was never used; use `curio -v` for debug logging; delete the line",
}


def _removed_hint(dotted: str) -> str:
    why = REMOVED_KEYS.get(dotted)
    return f" '{dotted}' was removed: {why}." if why else ""


def _suggest(word: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(word, choices, n=1, cutoff=0.5)
    hint = f" Did you mean '{close[0]}'?" if close else ""
    return f"{hint} Allowed keys here: {', '.join(sorted(choices))}."


def _check_key(dotted: str) -> None:
    """Raise ConfigError if ``dotted`` does not name a config key."""
    parts = dotted.split(".")
    model: type[BaseModel] = Config
    for i, part in enumerate(parts):
        fields = _fields_of(model)
        if part not in fields:
            where = ".".join(parts[:i]) or "the top level"
            raise ConfigError(f"unknown config key '{dotted}' ('{part}' is not a key of {where})."
                              + (_removed_hint(dotted) or _suggest(part, fields)))
        sub = _model_at(parts[: i + 1])
        if sub is None:
            if i != len(parts) - 1:
                raise ConfigError(f"unknown config key '{dotted}': '{'.'.join(parts[: i + 1])}' "
                                  "is a value, not a section.")
            return
        model = sub
    raise ConfigError(f"'{dotted}' is a section, not a key; set one of its keys: "
                      f"{', '.join(_fields_of(model))}.")


def _parse_value(text: str) -> Any:
    """Parse a ``--set`` value as TOML (numbers, booleans, arrays, strings); bare words are
    strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _apply_override(data: dict[str, Any], item: str) -> None:
    if "=" not in item:
        raise ConfigError(f"--set takes KEY=VALUE (e.g. drivers.mode=emulated), got '{item}'.")
    key, _, raw = item.partition("=")
    key = key.strip()
    _check_key(key)
    node = data
    parts = key.split(".")
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"cannot set '{key}': '{part}' is not a section in the file.")
        node = child
    node[parts[-1]] = _parse_value(raw.strip())


def _describe_errors(exc: ValidationError, source: str) -> str:
    lines = []
    for err in exc.errors():
        loc = [str(p) for p in err["loc"]]
        key = ".".join(loc)
        if err["type"] == "extra_forbidden":
            parent = _model_at([p for p in loc[:-1] if not p.isdigit()]) or Config
            lines.append(f"unknown config key '{key}' in {source}." +
                         (_removed_hint(key) or _suggest(loc[-1], _fields_of(parent))))
            continue
        if not loc:  # a check across sections: the message names the keys
            lines.append(f"{err['msg'].removeprefix('Value error, ')} (in {source}).")
            continue
        value = err.get("input")
        shown = repr(value) if not isinstance(value, dict) else "{...}"
        lines.append(f"{key} = {shown} in {source}: {err['msg']}.")
    return "config error:\n  " + "\n  ".join(lines)


def load_config(path: Path | str | None = None, overrides: list[str] | None = None) -> Config:
    """Load ``path`` (or the default config), apply ``overrides``, validate.

    Args:
        path: a TOML file; None means :func:`default_config_path` (or built-in defaults).
        overrides: ``KEY=VALUE`` strings; VALUE is parsed as a TOML value.

    Raises:
        ConfigError: unreadable file, TOML syntax error, unknown key, bad value.
    """
    data: dict[str, Any] = {}
    file_path = Path(path) if path is not None else default_config_path()
    source = str(file_path) if file_path else "the defaults"
    if file_path is not None:
        try:
            with open(file_path, "rb") as fh:
                data = tomllib.load(fh)
        except FileNotFoundError:
            raise ConfigError(f"config file not found: {file_path}") from None
        except PermissionError:
            raise ConfigError(f"config file not readable (permission denied): {file_path}") \
                from None
        except IsADirectoryError:
            raise ConfigError(f"config path is a directory, not a TOML file: {file_path}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {file_path} is not valid TOML: {exc}") from None
    base_dir = file_path.resolve().parent if file_path is not None else REPO_ROOT
    return config_from_data(data, base_dir, overrides, source)


def config_from_data(data: dict[str, Any], base_dir: Path, overrides: list[str] | None = None,
                     source: str = "the configuration") -> Config:
    """Validate configuration data (a parsed file, a recording's ``config``) with overrides.

    Args:
        data: nested sections and keys, as in the TOML file (not modified).
        base_dir: where relative paths are resolved.
        overrides: ``KEY=VALUE`` strings; VALUE is parsed as a TOML value.
        source: names the data in error messages.

    Raises:
        ConfigError: unknown key, bad value.
    """
    data = copy.deepcopy(data)
    for item in overrides or []:
        _apply_override(data, item)
    if overrides:
        source += " with --set " + " ".join(overrides)
    try:
        return Config.model_validate({**data, "base_dir": base_dir})
    except ValidationError as exc:
        raise ConfigError(_describe_errors(exc, source)) from None


def dump_config(cfg: Config) -> str:
    """Render the effective configuration as TOML text."""
    out: list[str] = []

    def fmt(value: Any) -> str:
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, str):
            return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(value, (list, tuple)):
            return "[" + ", ".join(fmt(v) for v in value) + "]"
        if isinstance(value, dict):
            return "{ " + ", ".join(f"{k} = {fmt(v)}" for k, v in value.items()) + " }"
        if value is None:
            return '"none"'
        return repr(value)

    def emit(prefix: str, model: BaseModel) -> None:
        scalars: list[str] = []
        tables: list[tuple[str, BaseModel]] = []
        arrays_of_tables: list[tuple[str, list[BaseModel]]] = []
        for name in _fields_of(type(model)):
            value = getattr(model, name)
            if isinstance(value, BaseModel):
                tables.append((name, value))
            elif isinstance(value, list) and value and all(isinstance(v, BaseModel) for v in value):
                arrays_of_tables.append((name, value))
            elif value is None:
                scalars.append(f"# {name} is unset")
            else:
                scalars.append(f"{name} = {fmt(value)}")
        if prefix and (scalars or not tables):
            out.append(f"\n[{prefix}]")
        out.extend(scalars)
        for name, items in arrays_of_tables:
            for item in items:
                out.append(f"\n[[{prefix + '.' if prefix else ''}{name}]]")
                out.extend(f"{k} = {fmt(v)}" for k, v in item.model_dump().items()
                           if v is not None)
        for name, sub in tables:
            emit(f"{prefix}.{name}" if prefix else name, sub)

    emit("", cfg)
    return "\n".join(out).lstrip() + "\n"
