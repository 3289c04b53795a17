"""The simulated world: a map_server map, dynamic objects and the Curio rover with its sensors.

Public API (other parts — the sim wiring, the device emulators, scenarios — code against it):

* ``World.from_config(cfg) -> World`` — load ``cfg.sim.world`` (map YAML) and, if present, the
  ``<stem>.world.toml`` next to it (doors, boxes, people); start at ``cfg.sim.start`` or
  ``cfg.robot.home``. ``World(grid, cfg, start=Pose2D, spec=WorldSpec|None)`` builds one
  directly (tests use small hand-made grids).
* ``world.step(dt_s)`` — advance physics (rover, people, door scripts) by ``dt_s`` seconds.
  ``world.time_s`` is the world's own simulated time.
* ``world.apply_servo_command(cmd: ServoCommand)`` — the duties and steering positions the
  servos now execute (what the Arduino forwards to the LX-16As).
* ``world.wheel_positions() -> tuple[int, ...]`` — six LX-16A ``POS_READ`` values (FL, ML, BL,
  FR, MR, BR), counts 0..1499 over a turn, positive duty counts up; inside the 1190..1310 dead
  zone the servo reports garbage stuck near 1180–1194 (hardware.md §4.5).
* ``world.cast_scan(stamp) -> LaserScan`` — one RPLidar A1 revolution in ``laser`` (beam 0 at
  −π, counter-clockwise), with range noise, dropouts (``inf``) and invalid returns (``nan``).
* ``world.imu_sample(stamp) -> Imu`` — BNO055 in ``imu_link``: yaw, yaw rate with bias and
  noise, linear acceleration (gravity removed).
* ``world.battery_voltage() -> float`` and ``world.set_battery_voltage(v)`` — servo pack volts;
  ``world.battery_drain_v_per_h`` (settable) — how fast the resting voltage falls.
* ``world.dock`` (a :class:`~curio.docking.station.DockStation` or None; ``set_dock``) — the
  charging dock at home when ``dock.enabled``: its outline blocks rays and the rover, and while
  its contact touches (``world.docked``) the pack charges at ``dock.charge_rate_v_per_h`` and
  ``world.charger_voltage()`` reads ``dock.charger_v`` (else 0; None without a dock).
* ``world.truth_pose -> Pose2D`` (``base_link`` in ``map``), ``world.truth_twist -> (v, ω)``,
  ``world.teleport(pose)``.
* ``world.add_box(x, y, w, h, yaw=0) -> int``, ``world.move_box(id, x, y, yaw)``,
  ``world.add_person(route, speed_mps=0.8,
  radius_m=0.25, loop=True, wait_s=0, start_delay_s=0) -> int``, ``world.remove_object(id)``,
  ``world.set_door(name, open)``, ``world.doors`` (names), ``world.door(name) -> Door``.
* ``world.collisions`` (count of contacts so far), ``world.in_contact``, and
  ``world.pop_events() -> list[(kind, detail)]``: one ``collision`` per contact (the wiring
  publishes them on ``/events``).

Physics: each wheel servo turns at ``duty · 2π/1000`` rad/s (small deadband, acceleration
limit); steering servos slew at ``cfg.sim.steer_slew_radps``. The body twist is the least-
squares rigid motion that best satisfies the six wheels' rolling and no-side-slip constraints
at their current steering angles, so mis-steered corners scrub as on the real rover. The true
rolling radius is ``R · wheel_radius_multiplier · (1 + e)`` with a per-run scale error
``e ∈ ±noise.odom_scale_error``, the wheel contact points are pulled in by the track
multiplier (rocker-bogie flex), a heading drift of ``noise.odom_heading_drift_rad_per_m`` is
added, and ``noise.wheel_slip`` randomly shortens each step's motion. A step whose footprint
would overlap a wall or an object is refused: the rover stops, its wheels stall, and one
``collision`` event is raised per contact. All randomness comes from ``cfg.sim.seed``.
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.config import Config
from curio.core.errors import SetupError
from curio.core.geometry import Pose2D, wrap_angle, yaw_to_quat
from curio.core.messages import Imu, LaserScan, ServoCommand, SimPeople, SimPerson
from curio.docking.station import DockShape, DockStation
from curio.drivers.kinematics import (
    STEER_CORNERS,
    WHEEL_SIDES,
    duty_to_servo_radps,
    steer_position_to_angle,
)
from curio.estimation.last_pose import LAST_POSE_FILE, load_last_pose
from curio.estimation.maps import OccupancyGrid, load_map
from curio.robot import RobotModel, wheel_geometry
from curio.sim.crowd import Crowd, RoverState
from curio.sim.crowd_kernel import count_hits
from curio.sim.objects import (
    Box,
    Door,
    Person,
    circle_hits_polygon,
    point_in_polygon,
    polygons_overlap,
)
from curio.sim.raycast import GridRaycaster, cast_circles, cast_segments

__all__ = ["World", "WorldError", "WorldSpec", "load_world_spec", "world_spec_path"]

F64 = npt.NDArray[np.float64]
log = logging.getLogger("curio.sim")

ENCODER_COUNTS = 1500  # LX-16A counts per revolution (0.24° each)
DEAD_ZONE = (1190, 1310)  # garbage readings while the pot wiper is here (mod 1500)
DUTY_DEADBAND = 20  # |duty| below this does not turn the motor
WHEEL_ACCEL_RADPS2 = 40.0  # servo shaft acceleration limit
CONTACT_RELEASE_M = 0.05  # a contact ends after moving this far from where it began
CONTACT_RELEASE_RAD = 0.1
TURNING_RADPS = 0.05  # a rover turning faster than this: scripted people keep out of its sweep
# Scripted people stop this far from the rover's footprint rather than walk up to it: people
# keep a little room from a machine (before, the walkers stood 1 mm from the rover's side, and
# a rover driving off along them brushed them with a millimetre of drift — two contacts
# charged to the rover in the 24-hour soaks of 2026-12-01).
WALKER_GAP_M = 0.10
# How long scripted people wait for the rover before they turn back along their route, s:
# people do not wait for ever (a walker and a rover waiting for each other stood still for
# 15 simulated minutes in a 24-hour soak of 2026-12-02).
WALKER_PATIENCE_S = 15.0
LIDAR_NOISE_BLOCK = 50  # lidar noise is drawn for this many scans at a time
IMU_NOISE_BLOCK = 1000  # IMU noise is drawn in blocks (fast, and still deterministic)
IMU_YAW_SIGMA_RAD = 0.002  # BNO055 fusion heading jitter
BATTERY_FULL_V = 8.1
BATTERY_DRAIN_V_PER_H = 0.3
BATTERY_LOAD_SAG_V = 0.25  # sag at full duty on every wheel


class WorldError(SetupError, ValueError):
    """A world description that cannot be used (file, field, problem)."""


@dataclass
class WorldSpec:
    """Dynamic objects from a ``.world.toml`` file."""

    doors: list[Door] = field(default_factory=list)
    boxes: list[Box] = field(default_factory=list)
    people: list[Person] = field(default_factory=list)


def _pt(value: Any, where: str) -> tuple[float, float]:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise WorldError(f"{where}: expected a point [x, y] in metres, got {value!r}")
    return (float(value[0]), float(value[1]))


def _num(table: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in table:
        if default is None:
            raise WorldError(f"{where}: required field '{key}' is missing")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise WorldError(f"{where}: field '{key}' must be a number, got {value!r}")
    return float(value)


def load_world_spec(path: Path) -> WorldSpec:
    """Read a ``.world.toml``: ``[[doors]]`` (name, a, b, open, thickness_m, script =
    [{t_s, open}]), ``[[boxes]]`` (x, y, w, h, yaw) and ``[[people]]`` (route, speed_mps,
    radius_m, loop, wait_s, start_delay_s).

    Raises:
        WorldError: naming the file, the entry and the problem.
    """
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise WorldError(f"{path}: world file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise WorldError(f"{path}: cannot read the world file ({exc})") from None
    allowed = {"doors", "boxes", "people", "description"}
    unknown = set(data) - allowed
    if unknown:
        raise WorldError(f"{path}: unknown section(s) {sorted(unknown)}; allowed: "
                         f"{sorted(allowed)}")
    spec = WorldSpec()
    names: set[str] = set()
    for i, d in enumerate(data.get("doors", [])):
        where = f"{path}: doors[{i}]"
        name = d.get("name")
        if not isinstance(name, str) or not name:
            raise WorldError(f"{where}: field 'name' must be a non-empty string")
        if name in names:
            raise WorldError(f"{where}: door name '{name}' is used twice")
        names.add(name)
        script = []
        for j, ev in enumerate(d.get("script", [])):
            t = _num(ev, "t_s", f"{where}.script[{j}]")
            if not isinstance(ev.get("open"), bool):
                raise WorldError(f"{where}.script[{j}]: field 'open' must be true or false")
            script.append((t, bool(ev["open"])))
        is_open = d.get("open", True)
        if not isinstance(is_open, bool):
            raise WorldError(f"{where}: field 'open' must be true or false")
        spec.doors.append(Door(name, _pt(d.get("a"), f"{where}.a"), _pt(d.get("b"), f"{where}.b"),
                               is_open, _num(d, "thickness_m", where, 0.05), sorted(script)))
    for i, b in enumerate(data.get("boxes", [])):
        where = f"{path}: boxes[{i}]"
        spec.boxes.append(Box(_num(b, "x", where), _num(b, "y", where), _num(b, "w", where),
                              _num(b, "h", where), _num(b, "yaw", where, 0.0)))
    for i, p in enumerate(data.get("people", [])):
        where = f"{path}: people[{i}]"
        route = p.get("route")
        if not isinstance(route, list) or not route:
            raise WorldError(f"{where}: field 'route' must be a list of [x, y] points")
        try:
            spec.people.append(Person(
                [_pt(q, f"{where}.route") for q in route],
                _num(p, "speed_mps", where, 0.8), _num(p, "radius_m", where, 0.25),
                bool(p.get("loop", True)), _num(p, "wait_s", where, 0.0),
                _num(p, "start_delay_s", where, 0.0)))
        except ValueError as exc:
            raise WorldError(f"{where}: {exc}") from None
    return spec


def world_spec_path(map_yaml: Path) -> Path:
    """The ``<stem>.world.toml`` that goes with a map YAML."""
    return map_yaml.with_name(map_yaml.stem + ".world.toml")


class World:
    """The simulated world and rover (see the module docstring for the API)."""

    def __init__(self, grid: OccupancyGrid, cfg: Config, start: Pose2D | None = None,
                 spec: WorldSpec | None = None, robot: RobotModel | None = None) -> None:
        self.cfg = cfg
        self.grid = grid
        self.raycaster = GridRaycaster(grid)
        self.time_s = 0.0
        seq = np.random.SeedSequence(cfg.sim.seed)
        rng_world, self._rng_lidar, self._rng_imu, self._rng_enc, self._rng_slip = (
            np.random.default_rng(s) for s in seq.spawn(5))
        self.robot = robot if robot is not None else RobotModel.from_config(cfg.robot)
        rcfg, noise = cfg.robot, cfg.sim.noise
        # Per-run systematic errors (drawn once).
        self.scale_error = float(rng_world.uniform(-1.0, 1.0)) * noise.odom_scale_error
        self.drift_sign = 1.0 if rng_world.uniform() < 0.5 else -1.0
        self._gyro_bias = noise.gyro_bias_radps
        # Truth geometry: contact points pulled in by rocker-bogie flex.
        self._geo = wheel_geometry(rcfg, lateral_scale=rcfg.mid_wheel_track_multiplier)
        self._roll_radius_m = (rcfg.wheel_radius_m * rcfg.wheel_radius_multiplier
                               * (1.0 + self.scale_error))
        # Footprint, collision samples (base_link).
        self.footprint: list[tuple[float, float]] = self.robot.footprint_points
        self._fp_radius = max(math.hypot(x, y) for x, y in self.footprint)
        self._fp_samples = _footprint_samples(self.footprint, 0.5 * grid.resolution_m)
        # State.
        self._pose = start or Pose2D()
        self._vx = self._vy = self._w = 0.0
        self._ax = self._ay = 0.0
        self._duty = [0, 0, 0, 0, 0, 0]
        self._servo_radps = [0.0] * 6
        self._servo_angle_rad = [0.0] * 6
        self._steer_target = [0.0] * 4
        self._steer = [0.0] * 4
        self._fit_key: tuple[float, ...] = ()
        self._fit_rows: list[tuple[float, float, float]] = []
        self._fit_inv: list[list[float]] = []
        self._contacts: frozenset[str] = frozenset()
        self.in_contact = False
        self._contact_pose = Pose2D()
        self.collisions = 0
        self._events: list[tuple[str, dict[str, Any]]] = []
        self._contacts_stale = False
        self._enc_stuck = [0] * 6
        self._imu_noise: list[list[float]] = []
        self._beam_angles: dict[int, F64] = {}
        self._lidar_gauss = np.zeros((0, 0))
        self._lidar_uniform = np.zeros((0, 0))
        self._lidar_k = 0
        self._imu_k = 0
        self._battery_base_v = BATTERY_FULL_V
        self._battery_t0 = 0.0
        self.battery_drain_v_per_h = BATTERY_DRAIN_V_PER_H
        self.dock: DockStation | None = None
        # Objects.
        self._next_id = 1
        self._boxes: dict[int, Box] = {}
        self._people: dict[int, Person] = {}
        self._doors: dict[str, Door] = {}
        if spec is not None:
            for door in spec.doors:
                self._doors[door.name] = door
            for box in spec.boxes:
                self._boxes[self._new_id()] = box
            for person in spec.people:
                self._people[self._new_id()] = person
        self._shapes_dirty = True
        self._segs = np.zeros((0, 4))
        self._circles = np.zeros((0, 3))
        # Simulated visitors (sim.crowd), attached by from_config or a test.
        self.crowd: Crowd | None = None
        self._last_endpoints = np.zeros((0, 2))

    # -- construction ------------------------------------------------------------------
    @classmethod
    def from_config(cls, cfg: Config, robot: RobotModel | None = None) -> World:
        """Build the world of ``cfg.sim.world`` (and its ``.world.toml``, if there is one) for
        the robot model ``robot`` (default: built from ``cfg.robot``)."""
        yaml_path = cfg.resolve(cfg.sim.world)
        grid = load_map(yaml_path)
        spec_path = world_spec_path(yaml_path)
        spec = load_world_spec(spec_path) if spec_path.is_file() else None
        robot = robot if robot is not None else RobotModel.from_config(cfg.robot)
        start = (Pose2D(*cfg.sim.start) if cfg.sim.start is not None
                 else _resumed_start(cfg, robot.home))
        world = cls(grid, cfg, start, spec, robot)
        if cfg.dock.enabled:
            d = cfg.dock
            world.set_dock(DockStation(robot.home, DockShape.for_footprint(robot.footprint),
                                       d.contact_xy_m, d.contact_yaw_rad, d.charger_v))
        world.crowd = Crowd.for_world(grid, cfg, world.truth_pose)
        if world.collides(world.truth_pose):
            log.warning("the start pose (%.2f, %.2f, %.2f) overlaps %s in %s: the rover can only "
                        "move out of it (set sim.start or robot.home to a free pose)",
                        *start.as_tuple(), ", ".join(world._hits(world.truth_pose)),
                        yaml_path.name)
        return world

    def _new_id(self) -> int:
        oid = self._next_id
        self._next_id += 1
        return oid

    # -- objects -----------------------------------------------------------------------
    def add_box(self, x: float, y: float, w: float, h: float, yaw: float = 0.0) -> int:
        """Place a ``w × h`` m box centred at map (x, y) with heading ``yaw``; return its id."""
        if not (w > 0.0 and h > 0.0):
            raise ValueError(f"a box needs w > 0 and h > 0 metres, got w={w}, h={h}")
        oid = self._new_id()
        self._boxes[oid] = Box(x, y, w, h, yaw)
        self._shapes_dirty = True
        self._contacts_stale = True
        return oid

    def move_box(self, object_id: int, x: float, y: float, yaw: float) -> None:
        """Put box ``object_id`` at map (x, y) with heading ``yaw`` (another rover of a fleet,
        curio/fleet/simworld.py); its size is kept.

        Raises:
            KeyError: no such box.
        """
        box = self._boxes[object_id]
        self._boxes[object_id] = Box(x, y, box.w_m, box.h_m, yaw)
        self._shapes_dirty = True

    def add_person(self, route: list[tuple[float, float]], speed_mps: float = 0.8,
                   radius_m: float = 0.25, loop: bool = True, wait_s: float = 0.0,
                   start_delay_s: float = 0.0) -> int:
        """Add a person walking ``route`` (map points, m) at ``speed_mps``; return its id."""
        oid = self._new_id()
        self._people[oid] = Person([(float(x), float(y)) for x, y in route], speed_mps,
                                   radius_m, loop, wait_s, start_delay_s)
        self._shapes_dirty = True
        return oid

    def remove_object(self, object_id: int) -> None:
        """Remove a box or person by id.

        Raises:
            KeyError: no such object (the message lists the ids there are).
        """
        if self._boxes.pop(object_id, None) is None and \
                self._people.pop(object_id, None) is None:
            ids = sorted([*self._boxes, *self._people])
            raise KeyError(f"no object with id {object_id}; objects: {ids}")
        self._shapes_dirty = True

    def set_door(self, name: str, open: bool) -> None:
        """Open or close the door called ``name``.

        Raises:
            KeyError: no such door (the message lists the doors).
        """
        door = self.door(name)
        if door.is_open != open:
            door.is_open = open
            self._shapes_dirty = True
            self._contacts_stale = True
            self._events.append(("door", {"name": name, "open": open}))

    def door(self, name: str) -> Door:
        """The door called ``name`` (KeyError naming the known doors)."""
        try:
            return self._doors[name]
        except KeyError:
            raise KeyError(f"no door called '{name}'; doors: {sorted(self._doors)}") from None

    @property
    def doors(self) -> list[str]:
        """Names of the doors."""
        return list(self._doors)

    @property
    def boxes(self) -> dict[int, Box]:
        """Boxes by id (read-only by convention)."""
        return self._boxes

    @property
    def people(self) -> dict[int, Person]:
        """People by id (read-only by convention)."""
        return self._people

    def set_dock(self, dock: DockStation | None) -> None:
        """Place (or remove) the charging dock."""
        self.dock = dock
        self._shapes_dirty = True
        self._contacts_stale = True

    @property
    def docked(self) -> bool:
        """Whether the dock's charging contact touches the rover."""
        return self.dock is not None and self.dock.touching(self._pose)

    def charger_voltage(self) -> float | None:
        """Volts at the dock's contacts (the charger's while they touch, else 0); None
        without a dock."""
        if self.dock is None:
            return None
        return self.dock.charger_v if self.docked else 0.0

    def _update_shapes(self) -> None:
        segs: list[tuple[float, float, float, float]] = []
        if self.dock is not None:
            segs.extend(self.dock.segments())
        for box in self._boxes.values():
            segs.extend(box.segments())
        for door in self._doors.values():
            segs.extend(door.segments())
        self._segs = np.array(segs, dtype=np.float64).reshape(-1, 4)
        self._circles = np.array([(p.x_m, p.y_m, p.radius_m) for p in self._people.values()],
                                 dtype=np.float64).reshape(-1, 3)
        self._shapes_dirty = False

    # -- rover -------------------------------------------------------------------------
    @property
    def truth_pose(self) -> Pose2D:
        """The rover's true ``base_link`` pose in ``map``."""
        return self._pose

    @property
    def truth_twist(self) -> tuple[float, float]:
        """True forward speed (m/s) and yaw rate (rad/s) in ``base_link``."""
        return (self._vx, self._w)

    @property
    def steer_angles_rad(self) -> tuple[float, ...]:
        """Current corner steering angles (FL, BL, FR, BR), radians."""
        return tuple(self._steer)

    def teleport(self, pose: Pose2D) -> None:
        """Put the rover at ``pose`` (map) at rest; contact state is reset."""
        self._pose = Pose2D(pose.x, pose.y, wrap_angle(pose.yaw))
        self._vx = self._vy = self._w = 0.0
        self._servo_radps = [0.0] * 6
        self._contacts = frozenset(self._hits(self._pose))
        self.in_contact = False

    def apply_servo_command(self, cmd: ServoCommand) -> None:
        """Make the servos execute ``cmd`` (duties −1000..1000, steering positions 0..1000)."""
        self._duty = [max(-1000, min(1000, int(d))) for d in cmd.wheel_duty]
        self._steer_target = [steer_position_to_angle(max(0, min(1000, p)))
                              for p in cmd.steer_position]

    def collides(self, pose: Pose2D) -> bool:
        """Whether the footprint at ``pose`` overlaps a wall or an object."""
        return bool(self._hits(pose))

    def _hits(self, pose: Pose2D) -> list[str]:
        """What the footprint at ``pose`` overlaps: ``wall``, ``box:ID``, ``person:ID``,
        ``door:NAME``."""
        hits: list[str] = []
        if self.raycaster.clearance_at(pose.x, pose.y) <= self._fp_radius:
            pts = pose.transform_points(self._fp_samples)
            if self.raycaster.occupied_at(pts).any():
                hits.append("wall")
        poly: list[tuple[float, float]] | None = None
        for oid, box in self._boxes.items():
            if math.hypot(box.x_m - pose.x, box.y_m - pose.y) <= \
                    self._fp_radius + box.bounding_radius_m():
                poly = poly or [pose.transform_point(x, y) for x, y in self.footprint]
                if polygons_overlap(poly, box.polygon()):
                    hits.append(f"box:{oid}")
        for name, door in self._doors.items():
            if door.is_open:
                continue
            half = 0.5 * math.hypot(door.b[0] - door.a[0], door.b[1] - door.a[1])
            cx, cy = door.centre
            if math.hypot(cx - pose.x, cy - pose.y) <= self._fp_radius + half + door.thickness_m:
                poly = poly or [pose.transform_point(x, y) for x, y in self.footprint]
                if polygons_overlap(poly, door.polygon()):
                    hits.append(f"door:{name}")
        for oid, person in self._people.items():
            if self._person_touches(person.x_m, person.y_m, person.radius_m, pose):
                hits.append(f"person:{oid}")
        dock = self.dock
        if dock is not None and math.hypot(dock.centre[0] - pose.x, dock.centre[1] - pose.y) \
                <= self._fp_radius + dock.radius_m:
            poly = poly or [pose.transform_point(x, y) for x, y in self.footprint]
            if any(polygons_overlap(poly, block) for block in dock.polygons()):
                hits.append("dock")
        if self.crowd is not None:
            hits += self.crowd.touching(lambda x, y, r: self._person_touches(x, y, r, pose),
                                        (pose.x, pose.y), self._fp_radius)
        return hits

    def _person_touches(self, x: float, y: float, r: float, pose: Pose2D) -> bool:
        if math.hypot(x - pose.x, y - pose.y) > self._fp_radius + r:
            return False
        poly = [pose.transform_point(px, py) for px, py in self.footprint]
        return circle_hits_polygon(x, y, r, poly)

    def step(self, dt_s: float) -> None:
        """Advance the world by ``dt_s`` seconds: scripts, people, servos, rover motion."""
        if dt_s <= 0.0:
            return
        self.time_s += dt_s
        self._run_door_scripts()
        self._move_people(dt_s)
        self._move_crowd(dt_s)
        self._step_rover(dt_s)
        if self.dock is not None and self.docked:
            self._charge(dt_s)

    def _run_door_scripts(self) -> None:
        for door in self._doors.values():
            while door.script and door.script[0][0] <= self.time_s:
                _, is_open = door.script.pop(0)
                self.set_door(door.name, is_open)

    def _move_people(self, dt_s: float) -> None:
        if not self._people:
            return
        turning = abs(self._w) > TURNING_RADPS
        here = self._pose
        for person in self._people.values():
            state = person.next_position(dt_s)
            if (state[0], state[1]) != (person.x_m, person.y_m) and (
                    self._closing_in(person.x_m, person.y_m, state[0], state[1],
                                     person.radius_m + WALKER_GAP_M)
                    or (turning and math.hypot(state[0] - here.x, state[1] - here.y)
                        <= self._fp_radius + person.radius_m)):
                # People wait rather than walk into the rover, or into the circle its corners
                # sweep while it turns in place (before, the workshop's walker walked up to a
                # lost rover turning to search, stopped 1 cm from its side, and the corner hit
                # it: no stop zone can see a person step into the sweep that late).
                person.waited_s += dt_s
                if person.waited_s >= WALKER_PATIENCE_S:
                    person.turn_back()
                continue
            person.waited_s = 0.0
            person.commit(state)
        self._shapes_dirty = True

    def _closing_in(self, x0: float, y0: float, x1: float, y1: float, r: float) -> bool:
        """A step from ``(x0, y0)`` to ``(x1, y1)`` ends within ``r`` of the rover's footprint
        and nearer to the rover than it began (a step away is always allowed)."""
        pose = self._pose
        if not self._person_touches(x1, y1, r, pose):
            return False
        return math.hypot(x1 - pose.x, y1 - pose.y) < math.hypot(x0 - pose.x, y0 - pose.y)

    def _move_crowd(self, dt_s: float) -> None:
        """Step the visitors; a visitor walking into the rover raises a ``collision`` event
        with ``fault`` (see :mod:`curio.sim.crowd`)."""
        if self.crowd is None:
            return
        poly = [self._pose.transform_point(x, y) for x, y in self.footprint]
        rover = RoverState(self._pose, self._vx, self._w, self.robot.footprint)
        for detail in self.crowd.step(dt_s, rover,
                                      lambda x, y, r: circle_hits_polygon(x, y, r, poly)):
            self._events.append(("collision", detail))

    def _step_rover(self, dt_s: float) -> None:
        sim = self.cfg.sim
        # Steering servos slew toward their targets.
        max_turn = sim.steer_slew_radps * dt_s
        for k in range(4):
            err = self._steer_target[k] - self._steer[k]
            self._steer[k] += max(-max_turn, min(max_turn, err))
        # Wheel servos accelerate toward the commanded speed.
        max_dw = WHEEL_ACCEL_RADPS2 * dt_s
        for i in range(6):
            duty = self._duty[i]
            target = 0.0 if abs(duty) < DUTY_DEADBAND else duty_to_servo_radps(duty)
            err = target - self._servo_radps[i]
            self._servo_radps[i] += max(-max_dw, min(max_dw, err))
        vx, vy, w = self._fit_body_twist()
        if vx == 0.0 and vy == 0.0 and w == 0.0:
            self._set_velocity(0.0, 0.0, 0.0, dt_s)
            return
        noise = sim.noise
        if noise.wheel_slip > 0.0:
            keep = 1.0 - noise.wheel_slip * float(self._rng_slip.uniform())
            vx, vy, w = vx * keep, vy * keep, w * keep
        w += self.drift_sign * noise.odom_heading_drift_rad_per_m * math.hypot(vx, vy)
        candidate = _integrate(self._pose, vx, vy, w, dt_s)
        if self._contacts_stale:
            # Something appeared on the rover (a box placed, a door closed onto it): what it
            # already overlaps does not block it, so it can drive out.
            self._contacts = frozenset(self._hits(self._pose))
            self._contacts_stale = False
        hits = frozenset(self._hits(candidate))
        new = hits - self._contacts
        if new:
            # Refused: the rover stops against the obstacle and the wheels stall.
            if not self.in_contact:
                self.collisions += 1
                self._events.append(("collision", {
                    "with": sorted(new), "fault": "rover", "by": "rover",
                    "x": round(self._pose.x, 3),
                    "y": round(self._pose.y, 3), "yaw": round(self._pose.yaw, 3),
                    "speed_mps": round(math.hypot(vx, vy), 3)}))
            self.in_contact = True
            self._contact_pose = self._pose
            self._servo_radps = [0.0] * 6
            self._set_velocity(0.0, 0.0, 0.0, dt_s)
            return
        for i in range(6):
            self._servo_angle_rad[i] += self._servo_radps[i] * dt_s
        self._pose = candidate
        self._contacts = hits
        if self.in_contact and not hits:
            # The contact ends once the rover has clearly moved away from where it touched.
            cp = self._contact_pose
            self.in_contact = (cp.distance_to(candidate) < CONTACT_RELEASE_M
                               and abs(wrap_angle(cp.yaw - candidate.yaw)) < CONTACT_RELEASE_RAD)
        else:
            self.in_contact = bool(hits)
        self._set_velocity(vx, vy, w, dt_s)

    def _set_velocity(self, vx: float, vy: float, w: float, dt_s: float) -> None:
        self._ax = (vx - self._vx) / dt_s - w * vy
        self._ay = (vy - self._vy) / dt_s + w * vx
        self._vx, self._vy, self._w = vx, vy, w

    def _fit_body_twist(self) -> tuple[float, float, float]:
        """Least-squares (vx, vy, ω) from the six wheels' rolling and no-side-slip rows.

        The normal matrix depends only on the steering angles, so its inverse and the rolling
        rows are cached until a steering servo moves.
        """
        radius = self._roll_radius_m
        u = [self._servo_radps[i] * WHEEL_SIDES[i] * radius for i in range(6)]
        if not any(u):
            return 0.0, 0.0, 0.0
        key = tuple(self._steer)
        if key != self._fit_key:
            self._fit_key = key
            self._fit_rows, self._fit_inv = _fit_matrices(self._geo.x_m, self._geo.y_m, key)
        rows, inv = self._fit_rows, self._fit_inv
        b0 = b1 = b2 = 0.0
        for i in range(6):
            r = rows[i]
            b0 += r[0] * u[i]
            b1 += r[1] * u[i]
            b2 += r[2] * u[i]
        return (inv[0][0] * b0 + inv[0][1] * b1 + inv[0][2] * b2,
                inv[1][0] * b0 + inv[1][1] * b1 + inv[1][2] * b2,
                inv[2][0] * b0 + inv[2][1] * b1 + inv[2][2] * b2)

    # -- sensors -----------------------------------------------------------------------
    def wheel_positions(self) -> tuple[int, ...]:
        """Six LX-16A position readings (FL, ML, BL, FR, MR, BR), counts 0..1499."""
        out = []
        for i in range(6):
            count = math.floor(self._servo_angle_rad[i] * ENCODER_COUNTS / (2 * math.pi))
            count %= ENCODER_COUNTS
            if DEAD_ZONE[0] <= count < DEAD_ZONE[1]:
                # Garbage: the reading sticks near 1180..1194 and may creep backwards.
                if self._enc_stuck[i] == 0:
                    self._enc_stuck[i] = int(self._rng_enc.integers(1185, 1195))
                else:
                    self._enc_stuck[i] = max(1180, self._enc_stuck[i] - int(
                        self._rng_enc.integers(0, 3)))
                out.append(self._enc_stuck[i])
            else:
                self._enc_stuck[i] = 0
                out.append(count)
        return tuple(out)

    def laser_pose(self) -> Pose2D:
        """The ``laser`` frame's pose in ``map``."""
        return self._pose @ self.robot.laser_in_base

    def cast_scan(self, stamp: float) -> LaserScan:
        """One lidar revolution from the current pose (``laser`` frame, noisy).

        The revolution is taken at one instant (the real A1 sweeps for 0.1–0.18 s while the
        rover moves). Range noise is Gaussian; each beam independently drops out (``inf``) or
        returns garbage (``nan``) with the configured fractions; returns closer than
        ``lidar_range_min_m`` read ``inf`` (distance 0, as ``rplidar_ros`` maps it).
        """
        sim = self.cfg.sim
        n = sim.lidar_beams
        inc = 2.0 * math.pi / n
        angles = self._beam_angles.get(n)
        if angles is None:
            angles = -math.pi + np.arange(n, dtype=np.float64) * inc
            self._beam_angles[n] = angles
        ranges = self.cast_ranges(angles, sim.lidar_range_max_m)
        noise = sim.noise
        gauss, u = self._lidar_noise_row(n)
        if noise.lidar_range_sigma_m > 0.0:
            ranges += noise.lidar_range_sigma_m * gauss
        p_drop = noise.lidar_dropout_fraction
        gone = (ranges < sim.lidar_range_min_m) | (ranges > sim.lidar_range_max_m) | (u < p_drop)
        ranges[gone] = np.inf
        ranges[(u >= p_drop) & (u < p_drop + noise.lidar_invalid_fraction)] = np.nan
        if self.crowd is not None:
            laser = self.laser_pose()
            hit = np.isfinite(ranges)
            ang = angles[hit] + laser.yaw
            self._last_endpoints = np.column_stack([laser.x + ranges[hit] * np.cos(ang),
                                                    laser.y + ranges[hit] * np.sin(ang)])
            self.crowd.note_scan(self._last_endpoints)
        out = ranges.astype(np.float32)
        out.flags.writeable = False
        return LaserScan(stamp=stamp, angle_min_rad=-math.pi, angle_increment_rad=inc,
                         range_min_m=sim.lidar_range_min_m, range_max_m=sim.lidar_range_max_m,
                         ranges_m=out, scan_time_s=1.0 / sim.lidar_rate_hz)

    def _lidar_noise_row(self, n: int) -> tuple[F64, F64]:
        """The next scan's Gaussian and uniform draws (drawn in blocks: fast, deterministic)."""
        if self._lidar_k >= LIDAR_NOISE_BLOCK or self._lidar_gauss.shape[1] != n:
            self._lidar_gauss = self._rng_lidar.standard_normal((LIDAR_NOISE_BLOCK, n))
            self._lidar_uniform = self._rng_lidar.random((LIDAR_NOISE_BLOCK, n))
            self._lidar_k = 0
        k = self._lidar_k
        self._lidar_k += 1
        return self._lidar_gauss[k], self._lidar_uniform[k]

    def cast_ranges(self, angles_rad: F64, max_range_m: float) -> F64:
        """Noise-free ranges (m) along laser-frame ``angles_rad`` from the current laser pose."""
        laser = self.laser_pose()
        world_angles = angles_rad + laser.yaw
        ranges = self.raycaster.cast(laser.x, laser.y, world_angles, max_range_m)
        if self._shapes_dirty:
            self._update_shapes()
        segs, circles = self._segs, self._circles
        if circles.size:
            reach = np.hypot(circles[:, 0] - laser.x, circles[:, 1] - laser.y) - circles[:, 2]
            circles = circles[reach < max_range_m]
        if segs.size or circles.size:
            dx, dy = np.cos(world_angles), np.sin(world_angles)
            if segs.size:
                np.minimum(ranges, cast_segments(laser.x, laser.y, dx, dy, segs), out=ranges)
            if circles.size:
                np.minimum(ranges, cast_circles(laser.x, laser.y, dx, dy, circles), out=ranges)
        if self.crowd is not None:
            self.crowd.cast(laser.x, laser.y, np.cos(world_angles), np.sin(world_angles), ranges)
        ranges[ranges > max_range_m] = np.inf
        return ranges

    def imu_sample(self, stamp: float) -> Imu:
        """A BNO055 reading in ``imu_link`` (fusion mode: orientation, gyro, linear accel)."""
        noise = self.cfg.sim.noise
        if self._imu_k >= len(self._imu_noise):
            self._imu_noise = self._rng_imu.standard_normal((IMU_NOISE_BLOCK, 5)).tolist()
            self._imu_k = 0
        n = self._imu_noise[self._imu_k]
        self._imu_k += 1
        imu = self.robot.imu_in_base
        ix, iy, iyaw = imu.x, imu.y, imu.yaw
        yaw = wrap_angle(self._pose.yaw + iyaw + IMU_YAW_SIGMA_RAD * n[0])
        gyro_z = self._w + self._gyro_bias + noise.gyro_sigma_radps * n[1]
        # Acceleration of the IMU point (rigid body; yaw acceleration neglected).
        ax = self._ax - self._w * self._w * ix
        ay = self._ay - self._w * self._w * iy
        c, s = math.cos(iyaw), math.sin(iyaw)
        sig = noise.accel_sigma_mps2
        a_imu = (c * ax + s * ay + sig * n[2], -s * ax + c * ay + sig * n[3], sig * n[4])
        return Imu(stamp=stamp, orientation_xyzw=yaw_to_quat(yaw),
                   angular_velocity_radps=(0.0, 0.0, gyro_z), linear_acceleration_mps2=a_imu,
                   orientation_valid=True, calibration=(3, 3, 3, 3))

    def battery_voltage(self) -> float:
        """Servo pack voltage (V): slow discharge plus sag under wheel load."""
        load = sum(abs(d) for d in self._duty) / 6000.0
        return max(0.0, self._resting_voltage() - BATTERY_LOAD_SAG_V * load)

    def _resting_voltage(self) -> float:
        hours = (self.time_s - self._battery_t0) / 3600.0
        return self._battery_base_v - self.battery_drain_v_per_h * hours

    def _charge(self, dt_s: float) -> None:
        """On the charger: the resting voltage rises (no drain) up to a full pack."""
        rate = self.cfg.dock.charge_rate_v_per_h / 3600.0
        self._battery_base_v = min(BATTERY_FULL_V, max(self._resting_voltage(),
                                                       self._battery_base_v) + rate * dt_s)
        self._battery_t0 = self.time_s

    def lapse(self, dt_s: float) -> None:
        """The building's clock jumped ``dt_s`` seconds while nothing moved (the world was not
        stepped): a rover on the dock's charging contact charges as it would have."""
        if dt_s > 0.0 and self.dock is not None and self.docked:
            self._charge(dt_s)

    def set_battery_voltage(self, volts: float) -> None:
        """Set the resting pack voltage now (it keeps discharging from there)."""
        if not (0.0 <= volts <= 20.0):
            raise ValueError(f"battery voltage must be 0..20 V, got {volts}")
        self._battery_base_v = volts
        self._battery_t0 = self.time_s

    def people_now(self) -> tuple[list[int], F64, F64]:
        """Ids, positions ``(N, 2)`` (map, m) and body radii (m) of every person now: the
        crowd's visitors, then the scripted people (ids 1000 + object id)."""
        ids: list[int] = []
        xy, radii = [np.zeros((0, 2))], [np.zeros(0)]
        if self.crowd is not None:
            ids += [v.vid for v in self.crowd.visitors]
            xy.append(self.crowd.pos)
            radii.append(np.full(len(self.crowd.visitors), self.crowd.radius_m))
        if self._people:
            ids += [1000 + oid for oid in self._people]
            xy.append(np.array([(p.x_m, p.y_m) for p in self._people.values()]))
            radii.append(np.array([p.radius_m for p in self._people.values()]))
        return ids, np.concatenate(xy), np.concatenate(radii)

    def people_truth(self, stamp: float) -> SimPeople:
        """Ground truth of every person: the crowd's visitors and the scripted people (ids
        1000 + their object id, behaviour ``scripted``), with the returns of the latest scan
        that hit each."""
        out = list(self.crowd.truth(stamp).people) if self.crowd is not None else []
        if self._people:
            pts = np.array([(p.x_m, p.y_m) for p in self._people.values()])
            hits = np.zeros(len(pts), dtype=np.int64)
            count_hits(self._last_endpoints, pts, 0.35, hits)
            out += [SimPerson(1000 + oid, p.x_m, p.y_m, 0.0, 0.0, p.radius_m, "scripted",
                              visible_beams=int(h))
                    for (oid, p), h in zip(self._people.items(), hits.tolist(), strict=True)]
        return SimPeople(stamp, tuple(out))

    def pop_events(self) -> list[tuple[str, dict[str, Any]]]:
        """Events since the last call: ``("collision", detail)``, ``("door", detail)``."""
        events, self._events = self._events, []
        return events


def _resumed_start(cfg: Config, home: Pose2D) -> Pose2D:
    """Without ``sim.start``: where the last run left the rover (``last_pose.json``, so the
    simulated rover and its own estimate agree after a restart), else ``home`` (the dock)."""
    if cfg.localization.resume_last_pose:
        last = load_last_pose(cfg.data_path(LAST_POSE_FILE))
        if last is not None:
            return last
    return home


def _integrate(pose: Pose2D, vx: float, vy: float, w: float, dt_s: float) -> Pose2D:
    """Exact constant-twist motion over ``dt_s`` from ``pose``."""
    dth = w * dt_s
    if abs(dth) < 1e-9:
        dx, dy = vx * dt_s, vy * dt_s
    else:
        s, c = math.sin(dth), math.cos(dth)
        dx = (vx * s - vy * (1.0 - c)) / w
        dy = (vx * (1.0 - c) + vy * s) / w
    return pose @ Pose2D(dx, dy, dth)


def _fit_matrices(
    xs: tuple[float, ...], ys: tuple[float, ...], steer: tuple[float, ...]
) -> tuple[list[tuple[float, float, float]], list[list[float]]]:
    """Rolling rows and the inverse normal matrix of the rigid-motion fit.

    Wheel i at (x, y) steered by δ: rolling ``c·(vx − ω·y) + s·(vy + ω·x) = u_i`` and no side
    slip ``−s·(vx − ω·y) + c·(vy + ω·x) = 0``; ``c, s = cos δ, sin δ``.
    """
    angles = [0.0] * 6
    for k, i in enumerate(STEER_CORNERS):
        angles[i] = steer[k]
    rows: list[tuple[float, float, float]] = []
    # Normal matrix on Python floats: entry by entry the same operations in the same order as
    # ``ata += np.outer(roll, roll) + np.outer(side, side)``, so the same bits, without numpy's
    # per-call overhead on 3-vectors. The inverse stays with LAPACK.
    ata = [[0.0] * 3 for _ in range(3)]
    for i in range(6):
        c, s = math.cos(angles[i]), math.sin(angles[i])
        x, y = xs[i], ys[i]
        roll = (c, s, -c * y + s * x)
        side = (-s, c, s * y + c * x)
        rows.append(roll)
        for j in range(3):
            row, rj, sj = ata[j], roll[j], side[j]
            for k in range(3):
                row[k] = row[k] + (rj * roll[k] + sj * side[k])
    inv = np.linalg.inv(np.array(ata, dtype=np.float64))
    return rows, [[float(v) for v in row] for row in inv]


def _footprint_samples(poly: list[tuple[float, float]], spacing_m: float) -> F64:
    """Points on the outline and inside the footprint (base_link) every ``spacing_m``."""
    pts: list[tuple[float, float]] = []
    n = len(poly)
    for i in range(n):
        (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % n]
        k = max(1, math.ceil(math.hypot(x2 - x1, y2 - y1) / spacing_m))
        pts.extend((x1 + (x2 - x1) * j / k, y1 + (y2 - y1) * j / k) for j in range(k))
    xs = [p[0] for p in poly]
    ys = [p[1] for p in poly]
    for x in np.arange(min(xs), max(xs), 2 * spacing_m):
        for y in np.arange(min(ys), max(ys), 2 * spacing_m):
            if point_in_polygon(float(x), float(y), poly):
                pts.append((float(x), float(y)))
    return np.array(pts, dtype=np.float64)
