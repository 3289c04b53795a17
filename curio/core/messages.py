"""Immutable messages carried by the bus.

Every message has ``stamp`` (the injected clock's ``now()``, seconds) and, when it has a frame,
``frame_id`` (REP-105: ``map``, ``odom``, ``base_link``, ``laser``, ``imu_link``). Units are SI
and in the field names. Arrays inside messages are read-only by convention: producers create a
fresh array for each message and consumers never write into it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D

FloatArray = npt.NDArray[np.float32]

# Wheel order used everywhere a tuple of six wheels appears (hardware.md §2.1).
WHEEL_NAMES: tuple[str, ...] = ("FL", "ML", "BL", "FR", "MR", "BR")
# Steering servo order where a tuple of four corners appears.
STEER_NAMES: tuple[str, ...] = ("FL", "BL", "FR", "BR")


@dataclass(frozen=True, slots=True)
class Twist:
    """A velocity command or estimate in ``base_link``: forward m/s and yaw rate rad/s."""

    stamp: float
    linear_mps: float = 0.0
    angular_radps: float = 0.0
    source: str = ""
    frame_id: str = "base_link"


@functools.lru_cache(maxsize=16)
def _beam_trig(angle_min_rad: float, angle_increment_rad: float,
               n: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Cosine and sine of the ``n`` beam angles of a scan geometry (read-only, shared: every
    scan of one lidar has the same angles)."""
    ang = angle_min_rad + np.arange(n, dtype=np.int64) * angle_increment_rad
    cos, sin = np.cos(ang), np.sin(ang)
    cos.flags.writeable = False
    sin.flags.writeable = False
    return cos, sin


@functools.lru_cache(maxsize=64)
def _even_pick(n: int, count: int) -> npt.NDArray[np.int64]:
    """``count`` evenly spread indices of ``range(n)`` (read-only, shared)."""
    pick = np.linspace(0, n - 1, count).round().astype(np.int64)
    pick.flags.writeable = False
    return pick


@dataclass(frozen=True, slots=True, eq=False)
class LaserScan:
    """One full lidar revolution in ``laser`` frame.

    Beam ``i`` points at ``angle_min_rad + i * angle_increment_rad`` (counter-clockwise, 0 = the
    laser's +x). ``ranges_m`` holds ``inf`` for no return and ``nan`` for an invalid return;
    values outside ``[range_min_m, range_max_m]`` are also invalid.
    """

    stamp: float
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    ranges_m: FloatArray
    intensities: FloatArray | None = None
    scan_time_s: float = 0.1
    frame_id: str = "laser"

    @property
    def angles_rad(self) -> npt.NDArray[np.float64]:
        """Beam angles in the laser frame, radians."""
        n = len(self.ranges_m)
        return self.angle_min_rad + np.arange(n, dtype=np.float64) * self.angle_increment_rad

    def valid_mask(self) -> npt.NDArray[np.bool_]:
        """Beams with a finite range inside the sensor's limits."""
        r = self.ranges_m
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r >= self.range_min_m) & (r <= self.range_max_m)

    def points(self, laser_in_base: Pose2D | None = None, *, max_beams: int | None = None,
               range_max_m: float | None = None) -> npt.NDArray[np.float64]:
        """The valid beams' end points ``(N, 2)``, metres.

        Args:
            laser_in_base: the ``laser`` frame in ``base_link``: points come in ``base_link``;
                None keeps them in ``laser``.
            max_beams: evenly subsample the valid beams to at most this many.
            range_max_m: also drop returns beyond this range.
        """
        ranges = np.asarray(self.ranges_m, dtype=np.float64)
        valid = self.valid_mask()
        if range_max_m is not None:
            valid &= ranges <= range_max_m
        idx = np.flatnonzero(valid)
        if max_beams is not None and len(idx) > max_beams:
            idx = idx[_even_pick(len(idx), max_beams)]
        cos, sin = _beam_trig(self.angle_min_rad, self.angle_increment_rad, len(ranges))
        r = ranges[idx]
        pts = np.stack([r * cos[idx], r * sin[idx]], axis=1)
        return pts if laser_in_base is None else laser_in_base.transform_points(pts)


@dataclass(frozen=True, slots=True)
class Imu:
    """BNO055 reading in ``imu_link`` (REP-103 axes, converted at the driver).

    Attributes:
        orientation_xyzw: absolute orientation quaternion; meaningful when ``orientation_valid``.
        angular_velocity_radps: gyro (x, y, z), rad/s.
        linear_acceleration_mps2: gravity-free acceleration (x, y, z), m/s².
        calibration: BNO055 calibration levels (sys, gyro, accel, mag), each 0–3.
    """

    stamp: float
    orientation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    angular_velocity_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    linear_acceleration_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation_valid: bool = False
    calibration: tuple[int, int, int, int] = (0, 0, 0, 0)
    frame_id: str = "imu_link"


@dataclass(frozen=True, slots=True)
class ServoCommand:
    """What the base sends to the servos: wheel duties and steering positions.

    Attributes:
        wheel_duty: LX-16A motor-mode duties −1000..1000, order ``WHEEL_NAMES``.
        steer_position: LX-16A positions 0..1000 (500 = straight), order ``STEER_NAMES``.
        steer_move_time_ms: time the steering servos are given to reach the positions.
    """

    stamp: float
    wheel_duty: tuple[int, int, int, int, int, int]
    steer_position: tuple[int, int, int, int]
    steer_move_time_ms: int = 50


@dataclass(frozen=True, slots=True)
class WheelEncoders:
    """Raw LX-16A wheel servo positions (counts 0..1499 over a turn, with the dead zone).

    ``positions`` follow ``WHEEL_NAMES``; ``None`` marks a reading the servo did not give.
    """

    stamp: float
    positions: tuple[int | None, int | None, int | None, int | None, int | None, int | None]


@dataclass(frozen=True, slots=True)
class Odometry:
    """A pose of ``child_frame_id`` in ``frame_id`` with its velocity in ``child_frame_id``.

    ``covariance`` is the row-major 3×3 covariance of (x, y, yaw) in m² and rad².
    """

    stamp: float
    pose: Pose2D
    linear_mps: float = 0.0
    angular_radps: float = 0.0
    covariance: tuple[float, ...] = (0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01)
    frame_id: str = "odom"
    child_frame_id: str = "base_link"


@dataclass(frozen=True, slots=True)
class PoseWithCovariance:
    """An estimated pose of ``base_link`` in ``frame_id`` (normally ``map``).

    ``covariance`` is the row-major 3×3 covariance of (x, y, yaw) in m² and rad².
    """

    stamp: float
    pose: Pose2D
    covariance: tuple[float, ...] = (0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.07)
    frame_id: str = "map"

    @classmethod
    def from_std(cls, stamp: float, pose: Pose2D, std_xy_m: float,
                 std_yaw_rad: float) -> PoseWithCovariance:
        """A pose with independent spreads: ``std_xy_m`` in x and y (m), ``std_yaw_rad``."""
        return cls(stamp, pose, covariance=(std_xy_m ** 2, 0.0, 0.0, 0.0, std_xy_m ** 2, 0.0,
                                            0.0, 0.0, std_yaw_rad ** 2))


@dataclass(frozen=True, slots=True)
class Transform:
    """The pose of ``child_frame_id`` in ``frame_id`` (e.g. the ``map`` → ``odom`` correction)."""

    stamp: float
    transform: Pose2D
    frame_id: str = "map"
    child_frame_id: str = "odom"


@dataclass(frozen=True, slots=True)
class Path:
    """A sequence of poses in ``frame_id`` (a global or local plan), metres/radians."""

    stamp: float
    poses: tuple[Pose2D, ...]
    frame_id: str = "map"


@dataclass(frozen=True, slots=True, eq=False)
class GridMessage:
    """An occupancy or cost grid in ``frame_id``.

    Attributes:
        data: row-major ``(height, width)`` int8 values, row 0 at the *bottom* (map_server
            convention after loading): occupancy −1 unknown, 0..100; costs 0..100 likewise.
        resolution_m: cell size, metres.
        origin: pose of cell (0, 0)'s lower-left corner in ``frame_id``.
        version: increases whenever the content changes (the dashboard refetches then).
        kind: ``"map"`` or ``"costmap"``.
    """

    stamp: float
    data: npt.NDArray[np.int8]
    resolution_m: float
    origin: Pose2D
    version: int = 0
    kind: str = "map"
    frame_id: str = "map"


@dataclass(frozen=True, slots=True)
class Obstacles:
    """Obstacles extracted from a scan, in ``frame_id``.

    Attributes:
        segments: ``((x1, y1), (x2, y2))`` line segments, metres.
        circles: ``(x, y, radius)``, metres.
    """

    stamp: float
    segments: tuple[tuple[tuple[float, float], tuple[float, float]], ...] = ()
    circles: tuple[tuple[float, float, float], ...] = ()
    frame_id: str = "map"


@dataclass(frozen=True, slots=True)
class BlockedState:
    """The blocked-path signal: an obstacle ahead and no progress for a while."""

    stamp: float
    blocked: bool
    obstacle_distance_m: float | None = None
    reason: str = ""


@dataclass(frozen=True, slots=True)
class BatteryState:
    """Servo supply voltage, volts, and whether it counts as low.

    ``charger_v``: the voltage at the dock's charging contacts, volts (None: not measured, e.g.
    no divider fitted on the Arduino's A0); above ``power.charger_detect_v`` the rover is on
    its charger.
    """

    stamp: float
    voltage_v: float
    low: bool = False
    charger_v: float | None = None


@dataclass(frozen=True, slots=True)
class PowerState:
    """The battery as the operator sees it (curio/power): filtered voltage, state of charge,
    time left, charging, level.

    Attributes:
        voltage_v: the low-passed pack voltage, volts; ``raw_v`` the last reading.
        soc: state of charge 0..1 from the pack's voltage curve (``power.ocv_table``).
        time_left_s: time until empty at the present drain (None while charging or unknown).
        time_to_low_s: time until ``bt.low_battery_v`` (None while charging or unknown).
        time_to_full_s: while charging, time until full (None otherwise).
        charging: on the charger (the dock's contacts carry the charger's voltage).
        level: ``ok``, ``low`` or ``critical`` (the tree's hysteresis on the raw voltage).
    """

    stamp: float
    voltage_v: float
    raw_v: float
    soc: float
    time_left_s: float | None = None
    time_to_low_s: float | None = None
    time_to_full_s: float | None = None
    charging: bool = False
    level: str = "ok"


@dataclass(frozen=True, slots=True)
class DockState:
    """The docking behaviour (curio/docking): where it is and how the last docking went.

    Attributes:
        state: ``idle``, ``staging``, ``approaching``, ``backing_off``, ``docked``,
            ``undocking`` or ``failed``.
        attempt: the approach being made (1-based; 0 before the first).
        error_m, error_deg: the last docked pose's error against the dock's pose, from the
            lidar's view of the dock (None before one).
        charging: the charger's voltage is on the contacts.
        detail: a sentence for the operator.
    """

    stamp: float
    state: str = "idle"
    attempt: int = 0
    error_m: float | None = None
    error_deg: float | None = None
    charging: bool = False
    detail: str = ""


@dataclass(frozen=True, slots=True)
class HelpState:
    """The open help request, if any (curio/help): why, what the rover says, since when.

    ``reason``: ``blocked``, ``lost``, ``battery_critical`` or ``dock_failed``;
    ``sound``: the dashboard should play its help sound (set at the request and at every
    repeat, cleared when answered); ``repeats``: how often it was said again.
    """

    stamp: float
    active: bool = False
    reason: str = ""
    message: str = ""
    since_s: float | None = None
    repeats: int = 0
    sound: bool = False
    blocked_at: tuple[float, float] | None = None


@dataclass(frozen=True, slots=True)
class EStop:
    """The latched emergency stop: ``engaged`` until an operator releases it."""

    stamp: float
    engaged: bool
    source: str = ""
    reason: str = ""


OperatorAction = Literal[
    "go_home",
    "pause",
    "resume",
    "toggle_pause",
    "select_path",
    "goto",
    "cancel",
    "help_done",
    "estop",
    "release_estop",
    "start_tour",
    "stop_tour",
]


@dataclass(frozen=True, slots=True)
class OperatorCommand:
    """A one-shot operator command (reliable: never dropped, never collapsed).

    Attributes:
        action: what to do.
        path_id: with ``select_path``: the path number (0 = home).
        goal: with ``goto``: a single goal pose in ``map``.
        source: who sent it (``web``, ``cli``, ``scenario``, ``tree``, ``scheduler``,
            ``kiosk``).
        request_id: an id the sender can match against the reply event.
        tour_id: with ``start_tour``: which tour of the tour store (None = the first).
    """

    stamp: float
    action: OperatorAction
    path_id: int | None = None
    goal: Pose2D | None = None
    source: str = ""
    request_id: str = ""
    tour_id: int | None = None


@dataclass(frozen=True, slots=True)
class NavGoal:
    """A goal given to the navigator's interface from outside the behaviour tree (a scenario
    script, a tool): what ``curio replay`` gives the navigator again. The tree's own goals are
    not on it (a replay re-runs the tree).

    Attributes:
        action: ``send`` (``poses`` in ``frame_id``; a NaN yaw has no heading requirement) or
            ``cancel`` (with ``reason``).
        tag: the goal's label (``GoalHandle.tag``).
    """

    stamp: float
    action: Literal["send", "cancel"]
    poses: tuple[Pose2D, ...] = ()
    tag: str = ""
    reason: str = ""
    frame_id: str = "map"


@dataclass(frozen=True, slots=True)
class StatusText:
    """Operator-facing status line (e.g. ``Moving to (0.2,0)``)."""

    stamp: float
    text: str
    state: str = "idle"


@dataclass(frozen=True, slots=True)
class Event:
    """A reliable event for people and reports: goal reached, help requested, fault, ...

    ``kind`` is a short dotted name (``goal.reached``, ``help.requested``, ``collision``);
    ``detail`` is JSON-serialisable.
    """

    stamp: float
    kind: str
    detail: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Progress:
    """Per-waypoint progress of the current path.

    ``states`` has one entry per waypoint: ``pending``, ``active``, ``reached``, ``failed`` or
    ``skipped``.
    """

    stamp: float
    path_id: int
    path_name: str
    states: tuple[str, ...]
    current_index: int


@dataclass(frozen=True, slots=True)
class TreeSnapshot:
    """The behaviour tree after a tick that changed something.

    ``nodes`` is a list of ``{id, name, type, status, parent, children}`` dicts; ``blackboard``
    maps keys to JSON-safe values.
    """

    stamp: float
    tick: int
    nodes: tuple[dict[str, Any], ...]
    blackboard: dict[str, Any]


@dataclass(frozen=True, slots=True)
class DriverHealth:
    """Health of one component: ``state`` is ``ok``, ``starting``, ``degraded``, ``error``
    or ``off``; ``counters`` holds error and traffic counts; ``message`` says what to do.
    """

    stamp: float
    name: str
    state: str
    message: str = ""
    counters: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class LocalizationStatus:
    """Localisation quality for the tree and the dashboard."""

    stamp: float
    state: Literal["ok", "uncertain", "lost", "off"]
    particles: int = 0
    std_xy_m: float = 0.0
    std_yaw_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class TourState:
    """The running tour, for the kiosk and the scheduler (published when it changes).

    Attributes:
        tour_id: the tour of the tour store, or None when no tour runs.
        name: the tour's name.
        source: who started it (``kiosk``, ``scheduler``, ``web``, ...).
        phase: ``moving`` (to ``stop_index``), ``dwelling`` (at it), ``held`` (paused,
            e-stop, help), ``failed`` (waiting for Resume) or ``idle`` (no tour).
        stop_index: the tour stop being driven to or dwelt at (0-based), or None.
        stop_name, message: that stop's name and visitor message.
        next_stop_name: the stop after it ("" at the last one).
        stops_total: the tour's number of stops.
        eta_s: seconds until the rover reaches ``stop_index`` (moving) or leaves it (dwelling),
            an estimate at ``stamp``; None when unknown.
    """

    stamp: float
    tour_id: int | None = None
    name: str = ""
    source: str = ""
    phase: str = "idle"
    stop_index: int | None = None
    stop_name: str = ""
    message: str = ""
    next_stop_name: str = ""
    stops_total: int = 0
    eta_s: float | None = None


@dataclass(frozen=True, slots=True)
class PersonTrack:
    """One person tracked from the lidar, in ``map`` (metres, m/s).

    Attributes:
        track_id: never reused within a run.
        x_m, y_m: estimated position of the person's centre.
        vx_mps, vy_mps: estimated velocity.
        pos_std_m: standard deviation of the position estimate (the larger axis).
        age_s: time since the track was born.
        moving: faster than ``people.moving_speed_mps`` now.
        walked: the person has been seen walking (not a pillar that looks like a person).
        standing_s: how long a track that walked has stood still (0 while moving).
        missed_s: time since the last detection (the track coasts on its prediction).
    """

    track_id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    pos_std_m: float = 0.0
    age_s: float = 0.0
    moving: bool = False
    walked: bool = False
    standing_s: float = 0.0
    missed_s: float = 0.0


@dataclass(frozen=True, slots=True)
class PeopleTracks:
    """The confirmed people tracks of one scan (``stamp`` is the scan's)."""

    stamp: float
    tracks: tuple[PersonTrack, ...] = ()
    frame_id: str = "map"


@dataclass(frozen=True, slots=True)
class SimPerson:
    """A simulated visitor's ground truth in ``map`` (metres, m/s).

    Attributes:
        person_id: the visitor's id in the simulated world.
        x_m, y_m, vx_mps, vy_mps: position and velocity of the body's centre.
        radius_m: the body's collision radius.
        behaviour: ``wanderer``, ``group``, ``crosser`` or ``follower``.
        group_id: the group a ``group`` visitor walks with (-1: none).
        state: ``walking``, ``standing`` or ``stepping_aside``.
        visible_beams: returns of the latest lidar scan that ended on this visitor.
    """

    person_id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    radius_m: float
    behaviour: str = "wanderer"
    group_id: int = -1
    state: str = "walking"
    visible_beams: int = 0


@dataclass(frozen=True, slots=True)
class SimPeople:
    """Every simulated visitor at one instant (simulator only)."""

    stamp: float
    people: tuple[SimPerson, ...] = ()
    frame_id: str = "map"
