"""Typed, validated configuration (``config.toml`` plus ``--set KEY=VALUE`` overrides).

One pydantic model per section; every key carries its unit in its name. Unknown keys, wrong
types and out-of-range values raise :class:`ConfigError` with a message that names the key, the
value and what is allowed (the CLI turns it into exit code 2). Relative paths in the file are
resolved against the directory of the config file.
"""

from __future__ import annotations

import copy
import difflib
import itertools
import math
import re
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
    adc_is_charger: bool = Field(
        False, description="A0 (BATTERY adc_mV) measures the dock's charging contacts through a "
        "divider: the rover knows when it is on its charger")
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
    max_scan_gap_deg: float = Field(
        15.0, gt=1.0, le=90.0, description="a revolution with a wider gap between its nodes is "
        "dropped (cut short: what it lacks would read as free space)")
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
    frozen_timeout_s: float = Field(
        2.0, ge=0.0, le=60.0, description="bit-identical readings this long mean the chip's "
        "output froze: re-initialise it (0 = never)")
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


class CrowdConfig(Section):
    """Simulated visitors: a social-force crowd (Helbing & Molnár) walking the simulated world.

    The behaviour mix is normalised (its fractions need not add up to 1): *wanderers* walk
    alone between points of interest and pause briefly, *groups* of ``group_size_min`` ..
    ``group_size_max`` walk together and stand at exhibits for ``dwell_min_s`` ..
    ``dwell_max_s``, *crossers* walk fast between far points (corridors, doorways) without
    stopping, *followers* follow the rover during a guided tour (wanderers otherwise).
    """

    visitors: int = Field(0, ge=0, le=100, description="how many visitors walk in the world")
    speed_mean_mps: float = Field(1.0, gt=0.0, le=2.5, description="mean desired walking speed")
    speed_sigma_mps: float = Field(0.25, ge=0.0, le=1.0)
    speed_min_mps: float = Field(0.5, gt=0.0, le=2.5)
    speed_max_mps: float = Field(1.5, gt=0.0, le=2.5)
    mix_wanderer: float = Field(0.35, ge=0.0, le=1.0, description="share of lone wanderers")
    mix_group: float = Field(0.35, ge=0.0, le=1.0, description="share of visitors in groups")
    mix_crosser: float = Field(0.2, ge=0.0, le=1.0, description="share of fast crossers")
    mix_follower: float = Field(0.1, ge=0.0, le=1.0, description="share following the tour")
    group_size_min: int = Field(2, ge=2, le=8)
    group_size_max: int = Field(4, ge=2, le=8)
    dwell_min_s: float = Field(10.0, ge=0.0, description="groups stand at an exhibit at least")
    dwell_max_s: float = Field(40.0, ge=0.0, description="... and at most this long")
    distracted_fraction: float = Field(
        0.15, ge=0.0, le=1.0, description="visitors who notice the rover only when its centre "
        "is within distracted_notice_m (looking at a phone, an exhibit)")
    distracted_notice_m: float = Field(1.5, ge=0.0, le=10.0)
    reaction_time_s: float = Field(
        0.5, ge=0.0, le=3.0, description="mean delay before a visitor reacts to the rover's "
        "motion (each visitor draws its own)")
    excuse_me_compliance: float = Field(
        0.8, ge=0.0, le=1.0, description="chance that a visitor in front of the rover steps "
        "aside when it says 'Excuse me'")
    body_radius_m: float = Field(0.2, gt=0.05, le=0.5, description="collision radius")
    lidar_model: Literal["legs", "body"] = Field(
        "legs", description="what the simulated lidar sees of a visitor: two legs (a low "
        "lidar, like Curio's) or one body circle")
    rate_hz: float = Field(20.0, ge=5.0, le=100.0, description="crowd update rate")
    pois: list[Point2] = Field(
        default_factory=list, description="points of interest [[x, y], ...] in map, metres; "
        "empty: the tour stops plus points spread over the map")

    @model_validator(mode="after")
    def _ranges(self) -> CrowdConfig:
        if self.speed_min_mps > self.speed_max_mps:
            raise ValueError("sim.crowd.speed_min_mps must be <= speed_max_mps")
        if self.group_size_min > self.group_size_max:
            raise ValueError("sim.crowd.group_size_min must be <= group_size_max")
        if self.dwell_min_s > self.dwell_max_s:
            raise ValueError("sim.crowd.dwell_min_s must be <= dwell_max_s")
        if self.mix_wanderer + self.mix_group + self.mix_crosser + self.mix_follower <= 0.0:
            raise ValueError("sim.crowd: at least one mix_* share must be > 0")
        return self


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
    crowd: CrowdConfig = Field(default_factory=CrowdConfig)


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
    stationary_check_s: float = Field(
        1.0, gt=0.0, description="standing still, the filter does not update; this often the "
        "scan is compared with the map at the estimate instead, and a poor fit updates the "
        "filter (a rover carried away while parked is noticed, lost after lost_after_scans)")
    laser_beams: int = Field(60, ge=8, le=2000)
    laser_sigma_hit_m: float = Field(0.1, gt=0.0)
    laser_z_hit: float = Field(0.9, ge=0.0, le=1.0)
    laser_z_rand: float = Field(0.1, ge=0.0, le=1.0)
    laser_likelihood_max_dist_m: float = Field(2.0, gt=0.0)
    kld_err: float = Field(0.01, gt=0.0, lt=1.0)
    kld_z: float = Field(0.99, gt=0.0, lt=1.0)
    recovery_alpha_slow: float = Field(0.001, ge=0.0, le=1.0)
    recovery_alpha_fast: float = Field(0.1, ge=0.0, le=1.0)
    resume_last_pose: bool = Field(
        True, description="start where the last run left the rover (data_dir/last_pose.json) "
        "instead of at robot.home / sim.start")
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
    recheck_after_set_m: float = Field(
        5.0, ge=0.0, description="after a pose is set (the operator on the map, or the "
        "tree's relocalisation) no such re-check until the rover has driven this far: where "
        "the map is wrong (furniture moved) a look-alike place elsewhere can fit better")
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


class PeopleConfig(Section):
    """People among whom the rover drives: tracking from the lidar, the people-aware stage of
    the local controller, the polite guide (docs/people.md).

    ``aware = false`` is the baseline: the tracker still runs (its tracks are published and
    measured) but people are plain obstacle marks in the costmap and the controller does not
    predict them (the behaviour before issue 14).
    """

    tracking: bool = Field(True, description="track people from the lidar (/people)")
    aware: bool = Field(
        True, description="predict tracked people in the controller, keep moving people out "
        "of the costmap, be a polite guide; false: the baseline (people are costmap marks)")
    # -- tracking ---------------------------------------------------------------------------
    max_range_m: float = Field(8.0, gt=0.5, le=40.0, description="track people this near")
    static_margin_m: float = Field(
        0.15, ge=0.0, le=1.0, description="returns this near a mapped obstacle are the map")
    segment_gap_m: float = Field(
        0.12, gt=0.0, le=1.0, description="neighbouring returns closer than this (plus 1 % of "
        "the range) form one segment")
    leg_pair_m: float = Field(0.45, ge=0.0, le=1.0, description="two leg-sized segments this "
                              "close are one person")
    leg_width_m: float = Field(0.25, gt=0.0, le=1.0, description="segments up to this wide may "
                               "be legs (wider ones are bodies)")
    max_width_m: float = Field(0.8, gt=0.0, le=3.0, description="wider clusters are not people")
    gate_m: float = Field(0.9, gt=0.0, le=5.0, description="association gate (distance)")
    confirm_hits: int = Field(3, ge=1, le=20, description="detections before a track is "
                              "confirmed (published)")
    tentative_coast_s: float = Field(0.35, gt=0.0, le=5.0, description="an unconfirmed track "
                                     "without detections is dropped after this")
    coast_s: float = Field(1.2, gt=0.0, le=10.0, description="a confirmed track without "
                           "detections is dropped after this")
    measurement_sigma_m: float = Field(0.06, gt=0.0, le=1.0)
    accel_sigma_mps2: float = Field(2.0, gt=0.0, le=20.0, description="process noise of the "
                                    "constant-velocity model")
    moving_speed_mps: float = Field(0.25, gt=0.0, le=2.0, description="a track is moving "
                                    "above this speed")
    # -- costmap ----------------------------------------------------------------------------
    standing_mark_s: float = Field(
        5.0, ge=0.0, description="a person who walked and now stands still this long is "
        "marked in the costmap like an obstacle (the planner routes around a standing group)")
    clear_radius_m: float = Field(0.35, ge=0.0, le=1.5, description="marks this near a "
                                  "walking person's positions are cleared (no ghost marks)")
    # -- controller stage ---------------------------------------------------------------------
    person_radius_m: float = Field(0.25, gt=0.0, le=1.0, description="body radius assumed "
                                   "around a track")
    passing_distance_m: float = Field(0.5, ge=0.0, le=3.0, description="comfortable distance "
                                      "when passing a person (footprint to body)")
    head_on_distance_m: float = Field(0.8, ge=0.0, le=5.0, description="comfortable distance "
                                      "in front of a person walking towards the rover")
    min_distance_m: float = Field(0.3, ge=0.0, le=2.0, description="the rover never drives "
                                  "closer than this to a person (unless stopping would be "
                                  "closer still)")
    horizon_s: float = Field(4.0, gt=0.0, le=10.0, description="people are predicted this far")
    prediction_growth_mps: float = Field(
        0.15, ge=0.0, le=1.0, description="the comfortable distance to a walking person grows "
        "by this much per second of prediction (for the first 2 s): a constant-velocity "
        "prediction drifts off by about the tracker's velocity error (0.20 m/s RMSE in the "
        "crowd benchmark); docs/people.md, 'Room for the prediction'")
    interaction_radius_m: float = Field(6.0, gt=0.0, le=20.0, description="people farther "
                                        "than this are ignored by the stage")
    near_distance_m: float = Field(1.0, ge=0.0, le=5.0)
    near_speed_mps: float = Field(0.2, gt=0.0, le=1.0, description="speed limit within "
                                  "near_distance_m of a person")
    excuse_me_after_s: float = Field(5.0, gt=0.0, description="yielding this long: say "
                                     "'Excuse me' and try again, assertively")
    excuse_me_interval_s: float = Field(10.0, gt=0.0)
    excuse_me_text: str = "Excuse me, may I pass?"
    assertive_s: float = Field(6.0, ge=0.0, description="after 'Excuse me' the comfortable "
                               "distances shrink to min_distance_m for this long")
    yield_max_s: float = Field(60.0, gt=0.0, description="after yielding this long the "
                               "navigator's progress checks run again (recovery, help)")
    # -- the guide ----------------------------------------------------------------------------
    face_group: bool = Field(True, description="at a tour stop, turn to face the group")
    group_radius_m: float = Field(3.0, gt=0.0, le=10.0, description="people this near a stop "
                                  "are the group")
    leave_clearance_m: float = Field(0.5, ge=0.0, le=5.0, description="before leaving a stop, "
                                     "wait until nobody is this near the way out")
    leave_wait_max_s: float = Field(8.0, ge=0.0, description="then say 'Excuse me' and go")
    stop_short_m: float = Field(1.2, ge=0.0, le=5.0, description="a tour stop with people "
                                "standing on it counts as reached this far from it")


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
    help_clear_s: float = Field(
        1.0, ge=0.0, description="the way must be seen clear (fresh scans along the route) "
        "this long before Thanks!")
    help_rearm_s: float = Field(
        15.0, ge=0.0,
        description="after a help episode that ended without the way clearing (help_done, "
        "timeout, pre-emption), ignore BLOCKED this long unless it first reports clear",
    )
    low_battery_v: float = Field(6.6, ge=0.0, description="below this the rover leaves what "
                                 "it does and goes to its dock (or home) to charge")
    battery_ok_v: float = Field(7.0, ge=0.0, description="low (or critical) ends at or above "
                                "this (hysteresis): route commands are accepted again")
    critical_battery_v: float = Field(
        6.3, ge=0.0, description="below this the rover stops where it is and asks for help "
        "(it cannot be trusted to reach the dock); ends at battery_ok_v")
    lost_confirm_s: float = Field(
        1.0, ge=0.0, description="localisation 'lost' this long: the rover stops and "
        "relocalises (lost and found)")
    lost_uncertain_s: float = Field(
        20.0, gt=0.0, description="localisation 'uncertain' with a spread above "
        "lost_std_xy_m this long also counts as lost (a slowly degrading fit)")
    lost_std_xy_m: float = Field(0.3, gt=0.0, description="see lost_uncertain_s")
    found_confirm_s: float = Field(
        1.0, ge=0.0, description="localisation 'ok' this long: found, the route resumes")
    relocalise_rotation_rad: float = Field(
        6.3, ge=0.0, le=31.5, description="bounded rotation in place while relocalising "
        "(0 = none): turn up to this much to let the lidar see more")
    relocalise_speed_radps: float = Field(0.4, gt=0.0, le=1.45)
    relocalise_timeout_s: float = Field(
        30.0, gt=0.0, description="not found within this long: ask a person for help")
    speak: bool = True
    two_step_goals: list[tuple[float, float, float]] = Field(
        default_factory=lambda: [(1.0, 1.0, 0.0), (2.0, 2.0, 0.0)]
    )
    paths: list[PathConfig] = Field(default_factory=_default_paths)
    paths_file: str = "paths.json"
    tour_stops: list[TourStopConfig] = Field(default_factory=list)
    tour_loop: bool = False


class PowerConfig(Section):
    """The servo battery: a NiMH pack read as a voltage (curio/power, docs/unattended.md)."""

    cells: int = Field(6, ge=1, le=40, description="cells in series (Curio: 6 x 1.2 V NiMH)")
    capacity_ah: float = Field(5.0, gt=0.0, le=100.0, description="rated capacity, Ah")
    ocv_table: list[tuple[float, float]] = Field(
        default_factory=lambda: [
            (0.0, 1.00), (0.05, 1.10), (0.10, 1.15), (0.20, 1.18), (0.40, 1.21),
            (0.60, 1.24), (0.80, 1.28), (0.90, 1.31), (0.95, 1.34), (1.00, 1.40)],
        description="state of charge (0..1) -> resting cell voltage, V; increasing in both")
    filter_s: float = Field(
        10.0, ge=0.0, le=600.0, description="time constant of the voltage low-pass (load sag "
        "and servo read noise); 0 = raw")
    trend_window_s: float = Field(
        600.0, ge=30.0, le=7200.0, description="time left: fitted on the state of charge over "
        "this long")
    average_current_a: float = Field(
        1.5, gt=0.0, le=50.0, description="time left before a trend exists: capacity left / "
        "this current")
    charge_current_a: float = Field(0.5, gt=0.0, le=50.0, description="the charger's current "
                                    "(time to full while charging)")
    charger_detect_v: float = Field(
        5.0, ge=0.0, description="a voltage at the dock contacts above this means the rover "
        "is on its charger")

    @field_validator("ocv_table")
    @classmethod
    def _increasing(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        if len(value) < 2:
            raise ValueError("ocv_table needs at least 2 [soc, volts_per_cell] rows")
        socs = [r[0] for r in value]
        volts = [r[1] for r in value]
        if socs[0] != 0.0 or socs[-1] != 1.0:
            raise ValueError("ocv_table must run from soc 0.0 to soc 1.0")
        if any(b <= a for a, b in itertools.pairwise(socs)) or any(
                b <= a for a, b in itertools.pairwise(volts)):
            raise ValueError("ocv_table: soc and volts must both increase from row to row")
        return value


class DockConfig(Section):
    """The charging dock: one named pose that is home and dock (curio/docking)."""

    enabled: bool = Field(
        False, description="a dock stands at home: Go Home and low battery dock the rover, "
        "and the simulator places one there")
    in_map: bool = Field(
        False, description="the navigation map already shows the dock (mapped with it in "
        "place); else its shape is drawn into the map at home")
    staging_distance_m: float = Field(
        0.7, ge=0.4, le=3.0, description="the staging pose is this far straight out of the dock")
    approach_speed_mps: float = Field(0.06, gt=0.0, le=0.15, description="final approach")
    min_approach_speed_mps: float = Field(0.02, gt=0.0, le=0.1)
    xy_tolerance_m: float = Field(0.012, gt=0.0, le=0.1, description="docked when within this")
    yaw_tolerance_rad: float = Field(0.026, gt=0.0, le=0.2)
    max_attempts: int = Field(3, ge=1, le=10, description="approaches before docking fails")
    contact_wait_s: float = Field(2.0, ge=0.0, le=30.0, description="wait this long at the "
                                  "dock for the charger's voltage before retrying")
    undock_distance_m: float = Field(0.7, gt=0.0, le=3.0)
    undock_speed_mps: float = Field(0.12, gt=0.0, le=0.3)
    detect_range_m: float = Field(
        0.35, gt=0.0, le=1.0, description="the lidar looks for the dock's shape this far "
        "around where the map says it is")
    charge_rate_v_per_h: float = Field(
        0.5, gt=0.0, le=10000.0, description="simulator: how fast the pack's resting voltage "
        "rises on the charger (scenarios speed it up)")
    contact_xy_m: float = Field(0.02, gt=0.0, le=0.1, description="simulator: the charging "
                                "contact touches within this of the docked pose")
    contact_yaw_rad: float = Field(0.05, gt=0.0, le=0.3)
    charger_v: float = Field(9.0, gt=0.0, le=30.0, description="simulator: voltage at the "
                             "contacts while they touch")


class HelpConfig(Section):
    """Help that reaches a person: the spoken request, notifications (curio/help)."""

    blocked_message: str = Field("Excuse me, could you help me? My way is blocked.",
                                 min_length=1, max_length=300)
    lost_message: str = Field("Excuse me, could you help me? I am lost: please show me where "
                              "I am on the map.", min_length=1, max_length=300)
    battery_message: str = Field("Excuse me, could you help me? My battery is almost empty: "
                                 "please take me to my charger.", min_length=1, max_length=300)
    dock_message: str = Field("Excuse me, could you help me? I cannot reach my charger.",
                              min_length=1, max_length=300)
    repeat_s: float = Field(60.0, ge=10.0, le=3600.0, description="say it again this often")
    max_repeats: int = Field(10, ge=0, le=1000, description="then only the notifications "
                             "and the dashboard keep asking")
    speak: bool = True
    webhook_urls: list[str] = Field(default_factory=list, description="HTTP POST of a JSON "
                                    "body to each, on every help request and resolution")
    ntfy_urls: list[str] = Field(default_factory=list, description="ntfy-style topic URLs "
                                 "(POST of the text, Title/Priority/Tags headers)")
    notify_kinds: list[str] = Field(
        default_factory=lambda: ["help.requested", "help.resolved", "battery.critical",
                                 "dock.failed", "tour.skipped"],
        description="event kinds that are sent to the notification channels")
    timeout_s: float = Field(5.0, gt=0.0, le=60.0, description="per delivery attempt")
    retries: int = Field(5, ge=0, le=50)
    backoff_s: float = Field(2.0, gt=0.0, le=600.0, description="first retry delay; doubles")
    backoff_max_s: float = Field(300.0, gt=0.0, le=3600.0)
    queue_size: int = Field(100, ge=1, le=10000, description="undelivered messages kept; "
                            "the oldest is dropped beyond this")

    @field_validator("webhook_urls", "ntfy_urls")
    @classmethod
    def _http(cls, value: list[str]) -> list[str]:
        for url in value:
            if not url.startswith(("http://", "https://")):
                raise ValueError(f"{url!r} is not an http:// or https:// URL")
        return value


class ZonesConfig(Section):
    """Keep-out and speed zones drawn on the map (curio/zones)."""

    enabled: bool = True
    directory: str = Field("zones", description="in data_dir: one <map name>.json per map")
    keepout_margin_m: float = Field(
        0.05, ge=0.0, le=1.0, description="keep-out zones are grown by this before they "
        "become lethal in the costmap (localisation error)")
    lookahead_s: float = Field(1.5, gt=0.0, le=10.0, description="the safety stage sweeps "
                               "the footprint this far ahead against keep-out zones")
    speed_margin_m: float = Field(0.25, ge=0.0, le=3.0, description="slow down this far "
                                  "before the footprint reaches a speed zone")


class MapsConfig(Section):
    """The map library: maps made, switched and edited from the dashboard (curio/maps)."""

    enabled: bool = Field(True, description="curio run keeps its maps in the library and "
                          "serves the /maps page (false: the configured map only)")
    directory: str = Field("maps", description="in data_dir: one directory per map")
    default_floor: str = Field("Ground floor", max_length=30,
                               description="the floor label of the first (seeded) map")
    max_upload_bytes: int = Field(16_000_000, ge=65536, le=256_000_000,
                                  description="largest map upload (YAML + image), bytes")
    stop_timeout_s: float = Field(3.0, gt=0.0, le=30.0, description="switching maps: how "
                                  "long to wait for the rover to stand still before the swap")


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
    token_file: str = Field(
        "web_token", description="the single token of older installs (migrated to tokens_file)")
    tokens_file: str = Field(
        "web_tokens.json", description="named tokens and roles in data_dir (curio token ...)")
    require_token: bool = True
    max_message_bytes: int = Field(65536, ge=256)
    max_messages_per_s: float = Field(50.0, gt=0.0)
    client_rate_hz: float = Field(10.0, gt=0.0, le=60.0)
    allowed_origins: list[str] = Field(default_factory=list)
    allowed_hosts: list[str] = Field(
        default_factory=list, description="host names the page may be opened by, besides IP "
        "addresses, localhost and this machine's name (DNS-rebinding guard); '*' allows any")
    max_viewer_sockets_per_ip: int = Field(
        16, ge=1, le=1000, description="live connections without a token from one address")
    max_viewer_sockets: int = Field(
        64, ge=1, le=10000, description="live connections without a token in total")
    teleop_lease_s: float = Field(
        3.0, gt=0.0, le=60.0, description="the driver keeps the joystick this long after "
        "letting go before another operator may drive without taking over")
    wrong_token_limit: int = Field(
        5, ge=1, le=1000, description="wrong tokens from one address before it is throttled")
    wrong_token_window_s: float = Field(
        60.0, gt=0.0, le=3600.0, description="the window for wrong_token_limit, and how long "
        "an address stays throttled")


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


class FleetTrafficConfig(Section):
    """Traffic between rovers: others as moving obstacles, one rover at a time through narrow
    passages (curio/fleet/traffic.py)."""

    enabled: bool = True
    narrow_width_m: float = Field(
        1.6, gt=0.0, le=5.0, description="a passage narrower than this (wall to wall, across "
        "the plan) takes one rover at a time")
    lookahead_m: float = Field(
        8.0, gt=0.0, le=50.0, description="passages this far ahead along the plan are "
        "negotiated with the other rovers")
    stop_before_m: float = Field(
        1.3, ge=0.3, le=10.0, description="a rover that gives way holds at least this far "
        "(along its plan) before the passage")
    wait_back_m: float = Field(
        3.0, ge=0.3, le=20.0, description="and at most this far, choosing the spot that stands "
        "clearest of the other rover's way")
    clearance_m: float = Field(
        0.9, gt=0.0, le=5.0, description="another rover whose plan or pose comes this close "
        "to the passage uses it")
    clear_after_m: float = Field(
        0.9, ge=0.0, le=10.0, description="a rover has left a passage once it is this far "
        "from it")
    peer_timeout_s: float = Field(
        2.0, gt=0.0, le=60.0, description="a rover not heard from for this long is left to "
        "the lidar and the safety stage")
    tie_margin_s: float = Field(
        2.0, ge=0.0, le=60.0, description="the rover that will reach the passage sooner by more "
        "than this goes first (distance and turns, estimated); closer than that, the one whose "
        "name sorts first")
    slow_approach_lead_s: float = Field(
        4.0, ge=0.0, le=60.0, description="a rover that gives way slows on its way to the "
        "staging point so that it arrives this long before the other is expected through the "
        "passage (0: it drives there at full speed and waits)")
    rate_hz: float = Field(5.0, gt=0.0, le=50.0, description="right-of-way decisions per second")
    predict_peers: bool = Field(
        False, description="give the other rovers, predicted along their planned paths, to the "
        "people-aware controller as moving obstacles (needs people.aware; "
        "curio/fleet/intent.py). Off by default: in the doorway bench both settings pass 50 of "
        "50 seeds, the longest stop 3.3 s without it, 1.9 s with it (docs/fleet.md)")


class FleetRos2Config(Section):
    """ROS 2 can listen: /scan, /odom, /tf, /map as CDR under rmw_zenoh's keys
    (curio/fleet/ros2)."""

    enabled: bool = False
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID")
    namespace: str = Field("", description="ROS namespace of the topics; '' = /<rover name>")
    frame_prefix: str = Field("", description="put before every frame id (e.g. 'r1/')")
    scan_rate_hz: float = Field(5.0, gt=0.0, le=50.0)
    odom_rate_hz: float = Field(10.0, gt=0.0, le=100.0)
    tf_rate_hz: float = Field(10.0, gt=0.0, le=100.0)


class FleetManagerConfig(Section):
    """The fleet manager of ``curio fleet run`` (curio/fleet/manager)."""

    host: str = "127.0.0.1"
    port: int = Field(8090, ge=0, le=65535, description="the fleet page and JSON API")
    mode: Literal["peer", "client", "router"] = "router"
    listen: list[str] = Field(default_factory=lambda: ["tcp/0.0.0.0:7447"])
    connect: list[str] = Field(default_factory=list)
    key_name: str = Field("fleet", description="the key (in fleet.keys_file) it signs with")
    min_battery_v: float = Field(7.0, ge=0.0, description="a rover below this gets no tour")
    low_battery_v: float = Field(
        6.8, ge=0.0, description="a rover on a tour below this is sent home and its tour goes "
        "to another rover")
    min_soc: float = Field(
        0.3, ge=0.0, le=1.0, description="a rover whose power model reports a state of charge "
        "(0..1) below this gets no tour")
    low_soc: float = Field(
        0.15, ge=0.0, le=1.0, description="a rover on a tour whose state of charge falls below "
        "this docks and its tour goes to another rover")
    offline_after_s: float = Field(5.0, gt=0.0, description="no status for this long: offline")
    redispatch_after_s: float = Field(
        60.0, ge=0.0, description="a rover that stays offline this long during a tour loses it "
        "to another rover")
    failed_tour_s: float = Field(
        120.0, gt=0.0, description="a tour stuck 'failed' this long goes to another rover")
    ack_timeout_s: float = Field(20.0, gt=0.0, description="a dispatched tour must start "
                                 "within this")
    start_window_s: float = Field(900.0, ge=0.0, description="a tour no rover can take is "
                                  "dropped after waiting this long")
    max_attempts: int = Field(3, ge=1, le=20, description="dispatches of one tour at most")
    check_period_s: float = Field(1.0, gt=0.0, le=60.0)
    distribute_maps: bool = Field(
        True, description="push the shared map (the manager's map file, read again when it "
        "changes) to every rover on that map whose cells differ; a rover takes it when parked "
        "(curio/fleet/maps_sync.py)")
    map_resend_s: float = Field(
        30.0, gt=0.0, le=3600.0, description="a rover that refused the map (busy) is asked "
        "again after this long")
    distribute_zones: bool = Field(
        True, description="push the zones of the shared map (the manager's zone file, once it "
        "exists) to every rover on that map (curio/fleet/zones_sync.py)")


class FleetConfig(Section):
    """A fleet over Eclipse Zenoh (curio[fleet]; off unless enabled; docs/fleet.md)."""

    enabled: bool = False
    rover: str = Field("", description="this rover's name in the fleet ('' = robot.name)")
    mode: Literal["peer", "client", "router"] = "peer"
    connect: list[str] = Field(default_factory=list, description="Zenoh endpoints, e.g. "
                               "tcp/10.0.0.2:7447 (the site's zenohd)")
    listen: list[str] = Field(default_factory=list)
    multicast_scouting: bool = False
    zenoh_config: str = Field("", description="a Zenoh JSON5 config file (wins over the keys "
                              "above)")
    keys_file: str = Field("fleet_keys.json", description="named keys, in data_dir (0600)")
    command_max_age_s: float = Field(30.0, gt=0.0, le=3600.0)
    pose_rate_hz: float = Field(5.0, gt=0.0, le=50.0)
    scan_rate_hz: float = Field(1.0, ge=0.0, le=20.0, description="thinned scans; 0 = none")
    scan_beams: int = Field(90, ge=8, le=2000)
    status_period_s: float = Field(1.0, gt=0.0, le=60.0)
    health_period_s: float = Field(5.0, gt=0.0, le=600.0)
    plan_step_m: float = Field(0.2, gt=0.0, le=5.0, description="plans are thinned to this")
    pump_period_s: float = Field(0.05, gt=0.0, le=1.0, description="received samples are "
                                 "handed to the rover this often")
    share_sim_truth: bool = Field(False, description="simulator: publish the true pose so "
                                  "rovers in other processes appear in this one's world")
    dashboard_url: str = Field(
        "", max_length=200, pattern=r"^(https?://\S+)?$",
        description="where operators reach this rover's own dashboard (e.g. "
        "http://10.0.0.11:8080/), published in its status for the fleet page's link; '' = "
        "found out: web.host when it is an address, with web.host 0.0.0.0 this machine's "
        "address towards fleet.connect (else <hostname>.local), none on the loopback")
    traffic: FleetTrafficConfig = Field(default_factory=FleetTrafficConfig)
    ros2: FleetRos2Config = Field(default_factory=FleetRos2Config)
    manager: FleetManagerConfig = Field(default_factory=FleetManagerConfig)

    @field_validator("rover")
    @classmethod
    def _rover_name(cls, value: str) -> str:
        if value and not re.match(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,31}$", value):
            raise ValueError("use 1-32 letters, digits, '-' or '_', starting with a letter or "
                             "digit")
        return value


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
    power: PowerConfig = Field(default_factory=PowerConfig)
    dock: DockConfig = Field(default_factory=DockConfig)
    help: HelpConfig = Field(default_factory=HelpConfig)
    zones: ZonesConfig = Field(default_factory=ZonesConfig)
    maps: MapsConfig = Field(default_factory=MapsConfig)
    people: PeopleConfig = Field(default_factory=PeopleConfig)
    fleet: FleetConfig = Field(default_factory=FleetConfig)

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
        bt = self.bt
        if not bt.critical_battery_v < bt.low_battery_v < bt.battery_ok_v:
            raise ValueError(
                f"bt.critical_battery_v = {bt.critical_battery_v:g}, bt.low_battery_v = "
                f"{bt.low_battery_v:g} and bt.battery_ok_v = {bt.battery_ok_v:g} must increase "
                "in that order (critical < low < ok)")
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
