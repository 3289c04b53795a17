"""The simulated world: rover motion, collisions, scripted objects, sensors, determinism."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from curio.core.config import REPO_ROOT, Config
from curio.core.geometry import Pose2D, quat_to_yaw
from curio.core.messages import ServoCommand
from curio.drivers.kinematics import twist_to_servo_command
from curio.estimation.maps import load_map
from curio.robot import RobotModel
from curio.sim import worldgen
from curio.sim.objects import Door, circle_hits_polygon
from curio.sim.world import (
    WALKER_GAP_M,
    WALKER_PATIENCE_S,
    World,
    WorldError,
    WorldSpec,
    load_world_spec,
)
from tests.unit.test_sim_raycast import quiet_config, room

DT = 0.02


def drive(w: World, v: float, omega: float, seconds: float) -> None:
    w.apply_servo_command(twist_to_servo_command(v, omega, RobotModel.from_config(w.cfg.robot),
                                                 0.0))
    for _ in range(round(seconds / DT)):
        w.step(DT)


def no_noise() -> Config:
    cfg = quiet_config()
    cfg.sim.noise.odom_scale_error = 0.0
    cfg.sim.noise.odom_heading_drift_rad_per_m = 0.0
    return cfg


def test_straight_drive_speed_uses_true_wheel_radius() -> None:
    w = World(room(), no_noise(), Pose2D(1.0, 2.0, 0.0))
    drive(w, 0.2, 0.0, 5.0)
    # The duty is computed with R = 0.06; the true rolling radius is 0.06 · 1.04.
    duty = twist_to_servo_command(0.2, 0.0, RobotModel.from_config(w.cfg.robot), 0.0).wheel_duty[1]
    v_true = duty * 2 * math.pi / 1000 * 0.06 * 1.04
    assert w.truth_twist[0] == pytest.approx(v_true, rel=1e-6)
    # Acceleration from rest costs a little distance: ramp 0 → ω at 40 rad/s².
    assert w.truth_pose.x - 1.0 == pytest.approx(v_true * 5.0, abs=0.01)
    assert w.truth_pose.y == pytest.approx(2.0, abs=1e-9)


def test_in_place_turn_needs_the_steering_to_swing_first() -> None:
    w = World(room(), no_noise(), Pose2D(3.0, 2.0, 0.0))
    w.apply_servo_command(twist_to_servo_command(0.0, 1.0, RobotModel.from_config(w.cfg.robot),
                                                 0.0))
    w.step(DT)
    # 60° per 0.16 s: after one 20 ms step the corners have moved 7.5° of their ~50°.
    assert abs(w.steer_angles_rad[0]) == pytest.approx(math.radians(7.5), abs=1e-6)
    for _ in range(round(0.3 / DT)):
        w.step(DT)
    assert abs(w.steer_angles_rad[0]) == pytest.approx(math.radians(49.99), abs=0.01)
    drive(w, 0.0, 1.0, 2.0)
    assert w.truth_pose.x == pytest.approx(3.0, abs=0.01)
    assert w.truth_twist[1] > 0.9


def test_collision_stops_the_rover_is_counted_once_and_never_passes_the_wall() -> None:
    w = World(room(), no_noise(), Pose2D(4.0, 2.0, 0.0))  # wall face at x = 6
    drive(w, 0.37, 0.0, 12.0)
    assert w.collisions == 1
    assert w.in_contact
    assert w.truth_twist == (0.0, 0.0)
    front = w.truth_pose.x + 0.33
    assert 5.95 < front <= 6.0  # touching, not through
    events = w.pop_events()
    assert [e[0] for e in events] == ["collision"]
    assert events[0][1]["with"] == ["wall"]
    # Backing off more than 5 cm ends the contact; driving in again is a second collision.
    drive(w, -0.2, 0.0, 1.0)
    assert not w.in_contact
    drive(w, 0.2, 0.0, 3.0)
    assert w.collisions == 2


def test_wheel_stall_at_contact_keeps_encoders_still() -> None:
    w = World(room(), no_noise(), Pose2D(5.5, 2.0, 0.0))
    drive(w, 0.2, 0.0, 2.0)
    assert w.in_contact
    before = w.wheel_positions()
    drive(w, 0.2, 0.0, 1.0)
    assert w.wheel_positions()[1] == before[1]


def test_boxes_doors_and_people_block_the_rover() -> None:
    door = Door("d", (3.0, 0.0), (3.0, 4.0), is_open=False, thickness_m=0.05)
    w = World(room(), no_noise(), Pose2D(1.0, 2.0, 0.0), WorldSpec(doors=[door]))
    drive(w, 0.3, 0.0, 10.0)
    assert w.collisions == 1
    assert w.truth_pose.x + 0.33 <= 2.975 + 1e-9
    assert w.pop_events()[0][1]["with"] == ["door:d"]
    w.set_door("d", True)
    drive(w, -0.2, 0.0, 1.0)
    box = w.add_box(4.5, 2.0, 0.4, 0.4)
    drive(w, 0.3, 0.0, 12.0)
    assert w.collisions == 2
    assert w.truth_pose.x + 0.33 <= 4.3 + 1e-9
    assert next(e for e in w.pop_events() if e[0] == "collision")[1]["with"] == [f"box:{box}"]
    w.remove_object(box)
    with pytest.raises(KeyError, match="objects"):
        w.remove_object(box)


def test_person_walks_route_and_waits_for_the_rover() -> None:
    w = World(room(), no_noise(), Pose2D(3.0, 2.0, 0.0))
    pid = w.add_person([(0.5, 3.5), (5.5, 3.5)], speed_mps=1.0, radius_m=0.2, loop=False)
    for _ in range(round(2.0 / DT)):
        w.step(DT)
    p = w.people[pid]
    assert p.x_m == pytest.approx(2.5, abs=1e-6) and p.y_m == pytest.approx(3.5)
    # Now stand the rover in the person's way: they stop short of it.
    w.teleport(Pose2D(4.0, 3.4, math.pi / 2))
    for _ in range(round(3.0 / DT)):
        w.step(DT)
    assert p.x_m < 4.0 - 0.31 - 0.2 + 0.05
    assert w.collisions == 0
    w.teleport(Pose2D(1.0, 1.0, 0.0))
    for _ in range(round(3.0 / DT)):
        w.step(DT)
    assert p.x_m == pytest.approx(5.5)


def test_door_script_and_world_file(tmp_path: Path) -> None:
    spec_file = tmp_path / "w.world.toml"
    spec_file.write_text(
        '[[doors]]\nname = "lab"\na = [3.0, 0.0]\nb = [3.0, 4.0]\nopen = true\n'
        'script = [{ t_s = 1.0, open = false }, { t_s = 2.0, open = true }]\n'
        "[[boxes]]\nx = 5.0\ny = 1.0\nw = 0.5\nh = 0.5\n"
        "[[people]]\nroute = [[1.0, 3.5], [2.0, 3.5]]\n", encoding="utf-8")
    spec = load_world_spec(spec_file)
    w = World(room(), no_noise(), Pose2D(1.0, 2.0, 0.0), spec)
    assert w.doors == ["lab"] and len(w.boxes) == 1 and len(w.people) == 1
    for _ in range(round(1.5 / DT)):
        w.step(DT)
    assert not w.door("lab").is_open
    for _ in range(round(1.0 / DT)):
        w.step(DT)
    assert w.door("lab").is_open
    assert [e[1]["open"] for e in w.pop_events() if e[0] == "door"] == [False, True]


@pytest.mark.parametrize(("text", "message"), [
    ("[[doors]]\nname = 3\n", "'name' must be a non-empty string"),
    ('[[doors]]\nname = "a"\na = [0, 0]\nb = [1]\n', "expected a point"),
    ("[[boxes]]\nx = 1\n", "required field 'y'"),
    ("[rooms]\n", "unknown section"),
    ("[[people]]\nroute = []\n", "route"),
    ("x = [\n", "cannot read"),
])
def test_world_file_errors_name_the_problem(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.world.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(WorldError, match=message):
        load_world_spec(path)


def test_wheel_positions_count_up_with_positive_duty_and_hit_the_dead_zone() -> None:
    w = World(room(), no_noise(), Pose2D(1.0, 2.0, 0.0))
    w.apply_servo_command(ServoCommand(0.0, (300, 300, 300, 300, 300, 300), (500,) * 4))
    seen: list[tuple[int, ...]] = []
    for _ in range(round(6.0 / DT)):
        w.step(DT)
        seen.append(w.wheel_positions())
    left = [s[1] for s in seen]
    assert all(0 <= c < 1500 for c in left)
    # 300 duty = 0.3 rev/s = 450 counts/s: readings wrap and pass the dead zone, where they
    # stick at 1180..1194 instead of reading 1190..1309.
    assert any(1180 <= c <= 1194 for c in left)
    assert not any(1195 <= c < 1310 for c in left)
    assert any(c < 100 for c in left) and any(c > 1310 for c in left)


def test_imu_and_battery() -> None:
    w = World(room(), Config(), Pose2D(3.0, 2.0, 0.5))
    imu = w.imu_sample(1.0)
    assert imu.orientation_valid and imu.frame_id == "imu_link"
    assert quat_to_yaw(imu.orientation_xyzw) == pytest.approx(0.5, abs=0.02)
    drive(w, 0.0, 0.8, 2.0)
    rates = [w.imu_sample(2.0).angular_velocity_radps[2] for _ in range(200)]
    assert np.mean(rates) == pytest.approx(w.truth_twist[1] + 0.005, abs=0.001)  # bias 0.005
    assert 0.001 < np.std(rates) < 0.004
    v0 = w.battery_voltage()
    assert 7.0 < v0 < 8.2
    w.set_battery_voltage(6.5)
    assert w.battery_voltage() < 6.5
    with pytest.raises(ValueError, match=r"0\.\.20 V"):
        w.set_battery_voltage(-1.0)


def test_same_seed_same_trajectory_and_sensors() -> None:
    def run(seed: int) -> tuple[Pose2D, tuple[int, ...], bytes]:
        cfg = Config()
        cfg.sim.seed = seed
        w = World(room(), cfg, Pose2D(2.0, 2.0, 0.0))
        drive(w, 0.3, 0.4, 4.0)
        return w.truth_pose, w.wheel_positions(), w.cast_scan(4.0).ranges_m.tobytes()

    assert run(7) == run(7)
    assert run(7) != run(8)


# --- the default world ----------------------------------------------------------------------

def default_world() -> World:
    cfg = Config()
    cfg.sim.world = str(REPO_ROOT / "maps" / "curio_building.yaml")
    return World.from_config(cfg)


def test_default_world_files_are_what_the_generator_makes(tmp_path: Path) -> None:
    worldgen.generate(tmp_path)
    for name in ("curio_building.yaml", "curio_building.pgm", "curio_building.world.toml"):
        assert (tmp_path / name).read_bytes() == (REPO_ROOT / "maps" / name).read_bytes(), name


def test_default_world_size_doors_and_home() -> None:
    w = default_world()
    assert w.grid.resolution_m == 0.05
    assert w.grid.size_m == pytest.approx((30.0, 20.0))
    assert set(w.doors) == {"gallery", "lab", "library", "meeting"}
    assert w.truth_pose == Pose2D(0.0, 0.0, 0.0)
    for name in w.doors:
        d = w.door(name)
        width = math.hypot(d.b[0] - d.a[0], d.b[1] - d.a[1])
        assert 0.9 - 1e-9 <= width <= 1.2 + 1e-9, name


@pytest.mark.parametrize("path", [
    [(0.2, 0.0), (-0.2, 0.0), (0.5, 0.0)],
    [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0), (3.0, 4.0)],
])
def test_original_paths_are_drivable(path: list[tuple[float, float]]) -> None:
    w = default_world()
    for (x1, y1), (x2, y2) in itertools.pairwise(path):
        for k in range(21):
            x, y = x1 + (x2 - x1) * k / 20, y1 + (y2 - y1) * k / 20
            for yaw in np.linspace(-math.pi, math.pi, 16, endpoint=False):
                assert not w.collides(Pose2D(x, y, float(yaw))), (x, y, yaw)


def test_tour_stops_are_reachable_through_the_doorways() -> None:
    grid = load_map(REPO_ROOT / "maps" / "curio_building.yaml")
    # Free space the rover's centre may use: at least the inscribed radius (0.31 m) from walls.
    free = ndimage.distance_transform_edt(~grid.occupied_mask()) * grid.resolution_m > 0.34
    labels, _ = ndimage.label(free)
    home = labels[grid.world_to_cell(0.0, 0.0)]
    assert home != 0
    for name, x, y, _msg in worldgen.TOUR_STOPS:
        assert labels[grid.world_to_cell(x, y)] == home, name
    # The meeting room and the library each have a single way in: their named door.
    w = default_world()
    for room_name, door, (x, y) in (("Meeting room", "meeting", (19.5, 12.0)),
                                    ("Library", "library", (1.0, 11.8))):
        d = w.door(door)
        mask = free.copy()
        for px, py in np.linspace(d.a, d.b, 40):
            r, c = grid.world_to_cell(float(px), float(py))
            mask[r - 8:r + 9, c - 8:c + 9] = False
        lab2, _ = ndimage.label(mask)
        assert lab2[grid.world_to_cell(x, y)] != lab2[grid.world_to_cell(0.0, 0.0)], room_name


def test_a_door_closed_onto_the_rover_does_not_trap_it() -> None:
    door = Door("d", (2.0, 0.0), (2.0, 4.0), is_open=True, thickness_m=0.05)
    w = World(room(), no_noise(), Pose2D(2.0, 2.0, 0.0), WorldSpec(doors=[door]))
    w.set_door("d", False)
    assert w.collides(w.truth_pose)
    drive(w, 0.3, 0.0, 3.0)
    assert w.truth_pose.x > 2.5
    assert w.collisions == 0


def test_a_walker_stops_short_of_a_still_rover_and_a_rover_driving_off_never_touches_it(
        ) -> None:
    """Scripted people stop WALKER_GAP_M from the footprint rather than walk up to it: before,
    a walker stood 1 mm from the rover's side, and the rover driving off along it brushed it
    with a millimetre of drift (two contacts charged to the rover in the soaks of
    2026-12-01; reproduced here at 0.1 m/s with the default noise)."""
    cfg = Config()  # the default noise: the drift that closes a millimetre
    w = World(room(), cfg, Pose2D(3.0, 2.0, 0.0))
    a = math.radians(60.0)
    pid = w.add_person([(3.0 + 1.5 * math.cos(a), 2.0 + 1.5 * math.sin(a)),
                        (3.0 - 1.5 * math.cos(a), 2.0 - 1.5 * math.sin(a))],
                       speed_mps=0.6, radius_m=0.25, loop=True)
    drive(w, 0.0, 0.0, 8.0)  # the walker's loop runs through the rover: it waits beside it
    p = w.people[pid]
    poly = [w.truth_pose.transform_point(x, y) for x, y in w.footprint]
    assert not circle_hits_polygon(p.x_m, p.y_m, p.radius_m + WALKER_GAP_M - 0.01, poly)
    drive(w, 0.1, 0.0, 1.6)  # off along it
    assert w.collisions == 0, w.pop_events()


def test_a_walker_keeps_out_of_the_circle_a_turning_rover_sweeps() -> None:
    """Scripted people wait rather than walk into the rover, and into the circle its corners
    sweep while it turns in place: before, the workshop's walker walked up to a lost rover
    turning to search and its corner hit them (a contact charged to the rover)."""
    w = World(room(), no_noise(), Pose2D(3.0, 2.0, 0.0))
    # The walker heads for a spot beside the rover: 0.43 m from its centre to their edge,
    # clear of its sides (0.31 m) by more than WALKER_GAP_M but inside the circle of its
    # corners (0.45 m).
    pid = w.add_person([(0.5, 2.63), (3.0, 2.63)], speed_mps=1.0, radius_m=0.2, loop=False)
    p = w.people[pid]
    drive(w, 0.0, 0.6, 6.0)  # turning in place meanwhile
    assert w.collisions == 0, w.pop_events()
    assert math.hypot(p.x_m - 3.0, p.y_m - 2.0) >= 0.45 + 0.2  # waiting outside the circle
    drive(w, 0.0, 0.0, 1.0)  # the rover stops, turned back as it started: the walker goes on
    w.teleport(Pose2D(3.0, 2.0, 0.0))
    drive(w, 0.0, 0.0, 6.0)
    assert p.x_m == pytest.approx(3.0) and w.collisions == 0


def test_a_walker_waiting_for_a_rover_that_does_not_move_turns_back() -> None:
    """A scripted walker whose loop runs through a rover standing still waits for it, then,
    after WALKER_PATIENCE_S, walks back the way they came instead of waiting for ever (a
    walker and a rover that waited for each other stood still for 15 simulated minutes in a
    24-hour soak: the rover would not turn with the walker in its corners' circle, the walker
    would not walk into the rover)."""
    w = World(room(), no_noise(), Pose2D(3.0, 2.0, 0.0))
    pid = w.add_person([(1.0, 2.0), (5.0, 2.0)], speed_mps=0.8, radius_m=0.25, loop=True)
    p = w.people[pid]
    drive(w, 0.0, 0.0, 5.0)  # walked up to the rover and waits
    waiting_at = p.x_m
    assert waiting_at < 3.0 - 0.33 and p.waited_s > 0.0
    drive(w, 0.0, 0.0, WALKER_PATIENCE_S - 5.0 - 1.0)
    assert p.x_m == pytest.approx(waiting_at)  # still waiting, within their patience
    drive(w, 0.0, 0.0, 4.0)
    assert p.x_m < waiting_at - 1.0  # turned back: walking towards (1, 2) again
    assert w.collisions == 0
