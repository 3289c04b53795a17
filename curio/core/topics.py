"""The topic table: every topic of the application, declared once.

Each entry names its publisher (the module that owns the topic) in ``doc``. Subscribers import
the constant, never spell the name.
"""

from __future__ import annotations

from typing import Any

from curio.core.bus import Bus, Topic
from curio.core.messages import (
    BatteryState,
    BlockedState,
    DockState,
    DriverHealth,
    EStop,
    Event,
    GridMessage,
    HelpState,
    Imu,
    LaserScan,
    LocalizationStatus,
    NavGoal,
    Obstacles,
    Odometry,
    OperatorCommand,
    Path,
    PeopleTracks,
    PoseWithCovariance,
    PowerState,
    Progress,
    ServoCommand,
    SimPeople,
    StatusText,
    TourState,
    Transform,
    TreeSnapshot,
    Twist,
    WheelEncoders,
)

# --- sensors (drivers or simulator) ---------------------------------------------------------
SCAN = Topic("/scan", LaserScan, doc="lidar driver / simulator: one revolution, laser frame")
WHEELS = Topic("/wheels", WheelEncoders, doc="base driver / simulator: wheel servo positions")
IMU = Topic("/imu", Imu, doc="BNO055 driver / simulator: imu_link, REP-103")
BATTERY = Topic("/battery", BatteryState, doc="base driver / simulator: servo supply voltage")
SERVO_CMD = Topic("/servo_cmd", ServoCommand, doc="base driver: the duties and positions sent")
GROUND_TRUTH = Topic("/ground_truth", Odometry, doc="simulator only: true pose in map")
PEOPLE_TRUTH = Topic("/people/ground_truth", SimPeople,
                     doc="simulator only: every simulated visitor, at the lidar rate")

# --- estimation (curio/nav) -------------------------------------------------------------------
WHEEL_ODOM = Topic("/wheel_odom", Odometry, doc="odometry (drivers/odometry.py): odom frame")
ODOM = Topic("/odom", Odometry, doc="EKF: fused odom -> base_link")
POSE = Topic("/pose", PoseWithCovariance, latched=True, doc="localisation: base_link in map")
MAP_TO_ODOM = Topic("/tf/map_odom", Transform, latched=True, doc="localisation: map -> odom")
LOCALIZATION = Topic(
    "/localization", LocalizationStatus, latched=True, doc="localisation: quality / lost"
)
INITIAL_POSE = Topic(
    "/initialpose", PoseWithCovariance, kind="reliable", doc="operator: set the pose in map"
)
MAP = Topic("/map", GridMessage, latched=True, doc="map server / mapping: occupancy grid")

# --- navigation (curio/nav) -------------------------------------------------------------------
COSTMAP = Topic("/costmap", GridMessage, latched=True, doc="costmap: global costmap")
LOCAL_COSTMAP = Topic("/local_costmap", GridMessage, latched=True, doc="costmap: rolling window")
PLAN = Topic("/plan", Path, latched=True, doc="global planner: current global plan")
LOCAL_PLAN = Topic("/local_plan", Path, latched=True, doc="controller: predicted trajectory")
OBSTACLES = Topic("/obstacles", Obstacles, doc="obstacle extractor: segments and circles")
BLOCKED = Topic("/blocked", BlockedState, latched=True, doc="blocked-path detector")
GOAL = Topic("/goal", NavGoal, kind="reliable",
             doc="scenario scripts / tools: goals given to the navigator (not the tree's own)")
PEOPLE = Topic("/people", PeopleTracks, latched=True,
               doc="people tracker (curio/people): confirmed tracks in map, one per scan")
CMD_VEL_NAV = Topic("/cmd_vel_nav", Twist, doc="local controller / recovery: wanted velocity")
CMD_VEL_TELEOP = Topic("/cmd_vel_teleop", Twist, doc="teleop (web, CLI): wanted velocity")
CMD_VEL = Topic("/cmd_vel", Twist, doc="safety stage only: the velocity the base executes")
ESTOP = Topic("/estop", EStop, kind="reliable", latched=True, doc="safety stage: e-stop state")

# --- operator, behaviour tree, events ---------------------------------------------------------
OPERATOR = Topic(
    "/operator", OperatorCommand, kind="reliable", doc="dashboard / CLI / scenarios: commands"
)
STATUS = Topic(
    "/status", StatusText, kind="reliable", latched=True, doc="behaviour tree: status line"
)
PROGRESS = Topic(
    "/progress", Progress, kind="reliable", latched=True, doc="path manager: waypoint states"
)
EVENTS = Topic("/events", Event, kind="reliable", doc="everyone: reliable events for reports")
ANSWERS = Topic("/operator/answers", Event, kind="reliable",
                doc="command journal: an answer to an operator command, once it is in the log")
TREE = Topic("/tree", TreeSnapshot, latched=True, doc="tree runner: snapshot after a change")
HEALTH = Topic("/health", DriverHealth, doc="every driver/component: health, counters")
TOUR = Topic("/tour", TourState, kind="reliable", latched=True,
             doc="tour feed (curio/bt/tour_feed.py): the running tour, its stop and the next")

# --- unattended operation (curio/power, curio/docking, curio/help, curio/zones) -------------
POWER = Topic("/power", PowerState, latched=True,
              doc="power monitor: state of charge, time left, charging, level")
DOCK = Topic("/dock", DockState, kind="reliable", latched=True,
             doc="docking (curio/docking/docker.py): docking state and last error")
HELP = Topic("/help", HelpState, kind="reliable", latched=True,
             doc="help desk (curio/help): the open help request, its sound and repeats")
HELP_BLOCKAGE = Topic("/help_blockage", Obstacles, latched=True,
                      doc="clearance probe: scan points that block the held route (map)")
ZONES = Topic("/zones", Event, kind="reliable", latched=True,
              doc="zone service (curio/zones): the zones of the current map (detail: zones)")

ALL_TOPICS: list[Topic[Any]] = [
    SCAN,
    WHEELS,
    IMU,
    BATTERY,
    SERVO_CMD,
    GROUND_TRUTH,
    PEOPLE_TRUTH,
    WHEEL_ODOM,
    ODOM,
    POSE,
    MAP_TO_ODOM,
    LOCALIZATION,
    INITIAL_POSE,
    MAP,
    COSTMAP,
    LOCAL_COSTMAP,
    PLAN,
    LOCAL_PLAN,
    OBSTACLES,
    BLOCKED,
    GOAL,
    PEOPLE,
    CMD_VEL_NAV,
    CMD_VEL_TELEOP,
    CMD_VEL,
    ESTOP,
    OPERATOR,
    STATUS,
    PROGRESS,
    EVENTS,
    ANSWERS,
    TREE,
    HEALTH,
    TOUR,
    POWER,
    DOCK,
    HELP,
    HELP_BLOCKAGE,
    ZONES,
]


def make_bus() -> Bus:
    """Return a bus with every topic of the application declared."""
    return Bus(ALL_TOPICS)
