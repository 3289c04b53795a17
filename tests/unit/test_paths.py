"""Path manager: defaults, edits, validation, atomic persistence across restarts, corrupt files;
and the path follower's counter rules (original-system.md §3.4)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from curio.bt.paths import (
    HOME_PATH_ID,
    NamedPath,
    PathError,
    PathManager,
    Waypoint,
    format_xy,
)
from curio.core.config import BtConfig, ConfigError, PathConfig, load_config

from .bt_fakes import make_harness


def defaults() -> list[PathConfig]:
    return BtConfig().paths


# --- defaults and formats -------------------------------------------------------------------


def test_defaults_are_the_originals() -> None:
    pm = PathManager(defaults(), None)
    paths = pm.list_paths()
    assert [p.id for p in paths] == [0, 1, 2]
    assert paths[0].name == "Home"
    assert [(w.x_m, w.y_m) for w in paths[0].waypoints] == [(0.0, 0.0)]
    assert [(w.x_m, w.y_m) for w in paths[1].waypoints] == [(0.2, 0.0), (-0.2, 0.0), (0.5, 0.0)]
    assert [round(math.degrees(w.yaw_rad or 0.0)) for w in paths[1].waypoints] == [90, 0, 180]
    assert [(w.x_m, w.y_m) for w in paths[2].waypoints] == [(1.0, 1.0), (2.0, 2.0), (3.0, 4.0)]


@pytest.mark.parametrize(("x", "y", "text"), [
    (0.2, 0.0, "(0.2,0)"), (-0.2, 0.0, "(-0.2,0)"), (1.0, 1.0, "(1,1)"), (0.5, -0.0, "(0.5,0)"),
    (3.14159, 2.0, "(3.142,2)"),
])
def test_status_token_format(x: float, y: float, text: str) -> None:
    assert format_xy(x, y) == text


def test_config_rejects_mismatched_headings() -> None:
    with pytest.raises(ValueError, match="one heading per point"):
        PathConfig(points=[(0.0, 0.0), (1.0, 1.0)], yaw_deg=[0.0])


def test_config_file_paths(tmp_path: Path) -> None:
    toml = tmp_path / "c.toml"
    toml.write_text('[[bt.paths]]\nname = "Dock"\npoints = [[1.0, 2.0]]\n'
                    '[[bt.paths]]\nname = "Loop"\npoints = [[0, 0], [1, 0], [1, 1], [0, 1]]\n')
    cfg = load_config(toml)
    pm = PathManager(cfg.bt.paths, None)
    assert [p.name for p in pm.list_paths()] == ["Dock", "Loop"]
    assert pm.get(1).waypoints[2] == Waypoint(1.0, 1.0, None)
    toml.write_text('[[bt.paths]]\npoints = [[0, 0]]\nyaw_deg = [1, 2]\n')
    with pytest.raises(ConfigError, match="yaw_deg"):
        load_config(toml)


# --- edits ----------------------------------------------------------------------------------


def test_create_click_rename_delete() -> None:
    pm = PathManager(defaults(), None)
    p = pm.create("Lobby loop")
    assert p.id == 3 and p.waypoints == []
    for i in range(7):  # any length (the original capped clicks at 3 points, §9.17)
        pm.add_waypoint(3, i * 0.5, 1.0, yaw_rad=None if i % 2 else 0.5)
    got = pm.get(3)
    assert len(got.waypoints) == 7
    assert got.waypoints[0].yaw_rad == 0.5 and got.waypoints[1].yaw_rad is None
    assert pm.remove_waypoint(3, 1).waypoints[1].x_m == 1.0
    assert pm.remove_waypoint(3, -1).waypoints[-1].x_m == 2.5
    assert pm.rename(3, "  Front   desk ").name == "Front desk"
    pm.delete(3)
    with pytest.raises(PathError, match="There is no path 3"):
        pm.get(3)
    assert pm.create("Next").id == 4  # ids are never reused


def test_returned_paths_are_copies() -> None:
    pm = PathManager(defaults(), None)
    p = pm.get(1)
    p.waypoints.clear()
    assert len(pm.get(1).waypoints) == 3


@pytest.mark.parametrize(("call", "message"), [
    (lambda pm: pm.delete(HOME_PATH_ID), "Home .path 0. cannot be deleted"),
    (lambda pm: pm.get(9), "There is no path 9. The paths are: 0 .Home., 1"),
    (lambda pm: pm.create("   "), "cannot be empty"),
    (lambda pm: pm.create("x" * 61), "at most 60 characters"),
    (lambda pm: pm.add_waypoint(1, float("nan"), 0.0), "finite number"),
    (lambda pm: pm.add_waypoint(1, "1", 0.0), "must be a number"),
    (lambda pm: pm.add_waypoint(1, 0.0, 0.0, float("inf")), "finite number of radians"),
    (lambda pm: pm.remove_waypoint(1, 3), "waypoints 0 to 2; there is no waypoint 3"),
    (lambda pm: pm.remove_waypoint(HOME_PATH_ID, 0), "Home must keep its waypoint"),
    (lambda pm: pm.rename(7, "x"), "There is no path 7"),
    (lambda pm: pm.get(True), "whole number"),
])
def test_errors_are_sentences(call, message: str) -> None:  # type: ignore[no-untyped-def]
    pm = PathManager(defaults(), None)
    with pytest.raises(PathError, match=message):
        call(pm)
    assert isinstance(PathError("x"), ValueError)
    assert len(pm.list_paths()) == 3  # nothing changed


def test_listeners_hear_every_change() -> None:
    pm = PathManager(defaults(), None)
    heard: list[tuple[str, int]] = []
    pm.add_listener(lambda what, pid: heard.append((what, pid)))
    pm.create("A")
    pm.add_waypoint(3, 1.0, 1.0)
    pm.rename(3, "B")
    pm.delete(3)
    assert heard == [("created", 3), ("changed", 3), ("renamed", 3), ("deleted", 3)]


# --- persistence ----------------------------------------------------------------------------


def test_persistence_across_restart(tmp_path: Path) -> None:
    file = tmp_path / "paths.json"
    pm = PathManager(defaults(), file)
    assert file.exists()  # the defaults are written at once
    pm.create("Gallery", [Waypoint(1.0, 2.0, 0.5)])
    pm.add_waypoint(3, 4.0, 5.0)
    pm.rename(1, "Wiggle")
    pm.delete(2)
    again = PathManager(defaults(), file)  # a restart: a new manager on the same file
    assert [(p.id, p.name) for p in again.list_paths()] == [(0, "Home"), (1, "Wiggle"),
                                                            (3, "Gallery")]
    assert again.get(3).waypoints == [Waypoint(1.0, 2.0, 0.5), Waypoint(4.0, 5.0, None)]
    assert again.create("After restart").id == 4  # next_id survived: 2 and 3 not reused
    assert again.load_warning is None
    # No temporary files are left behind by the atomic writes; the backup is a second copy.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paths.json", "paths.json.bak"]
    assert (tmp_path / "paths.json.bak").read_text() == file.read_text()


def test_a_damaged_file_is_replaced_by_its_backup_without_loss(tmp_path: Path) -> None:
    # Found by curio soak (corrupt_file): a damaged paths file lost every path the operators
    # had made (the defaults were used).
    file = tmp_path / "paths.json"
    pm = PathManager(defaults(), file)
    pm.create("Gallery", [Waypoint(1.0, 2.0, 0.5)])
    good = file.read_text()
    file.write_text(good[: len(good) // 2])
    again = PathManager(defaults(), file)
    assert again.load_warning is None and again.restored is not None
    assert "paths.json.corrupt-1" in again.restored
    assert [p.name for p in again.list_paths()] == ["Home", "Path 1", "Path 2", "Gallery"]
    assert file.read_text() == good
    assert (tmp_path / "paths.json.corrupt-1").read_text() == good[: len(good) // 2]


@pytest.mark.parametrize("content", ["{not json", json.dumps({"version": 99, "paths": []}),
                                     json.dumps({"version": 1, "paths": [
                                         {"id": 1, "name": "x", "waypoints": []}]}),
                                     json.dumps({"version": 1, "paths": [
                                         {"id": 0, "name": "H", "waypoints": [
                                             {"x_m": "nan?", "y_m": 0}]}]})])
def test_corrupt_file_is_kept_aside(tmp_path: Path, content: str) -> None:
    file = tmp_path / "paths.json"
    file.write_text(content)
    pm = PathManager(defaults(), file)
    assert pm.load_warning is not None and "could not be read" in pm.load_warning
    assert [p.id for p in pm.list_paths()] == [0, 1, 2]  # the defaults
    aside = tmp_path / "paths.json.corrupt-1"
    assert aside.read_text() == content  # nothing lost
    assert json.loads(file.read_text())["version"] == 1  # a good file is written again


def test_named_path_json_round_trip() -> None:
    p = NamedPath(5, "A", [Waypoint(1.0, 2.0, None)])
    assert p.to_json() == {"id": 5, "name": "A",
                           "waypoints": [{"x_m": 1.0, "y_m": 2.0, "yaw_rad": None}]}


# --- follower counter rules (switch_path, §3.4) ---------------------------------------------


def test_equivalent_waypoint_switch_keeps_the_index() -> None:
    h = make_harness()
    h.press("select_path", path_id=1)
    h.tick()
    h.nav.succeed()
    h.tick()  # heading to waypoint 1 of path 1
    assert h.nav.target() == (-0.2, 0.0)
    h.press("select_path", path_id=2)
    h.tick()
    assert h.nav.target() == (2.0, 2.0)  # waypoint 1 of path 2
    assert h.bb("waypoint") == 1
    assert h.progress[-1].states == ("skipped", "active", "pending")
    assert "from waypoint 2" in h.last_message("bt.command_accepted")


def test_end_of_path_resets_the_index() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)
    h.tick()
    for _ in range(3):
        h.nav.succeed()
        h.tick()
    assert h.of("path.finished") and h.bb("waypoint") == 0
    h.press("select_path", path_id=1)
    h.tick()
    assert h.nav.target() == (0.2, 0.0)  # starts at waypoint 0


def test_switch_to_home_resets_and_leaving_home_resets() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)
    h.tick()
    h.nav.succeed()
    h.tick()
    assert h.bb("waypoint") == 1
    h.press("go_home")
    h.tick()
    assert h.nav.target() == (0.0, 0.0) and h.bb("waypoint") == 0
    h.tick()
    h.press("select_path", path_id=2)
    h.tick()
    assert h.nav.target() == (1.0, 1.0)  # leaving home: from the start


def test_path_too_short_starts_from_its_first_waypoint_and_says_so() -> None:
    h = make_harness()
    h.paths.create("Short", [Waypoint(5.0, 5.0, None)])
    h.press("select_path", path_id=2)
    h.tick()
    for _ in range(2):
        h.nav.succeed()
        h.tick()
    assert h.bb("waypoint") == 2
    h.press("select_path", path_id=3)
    h.tick()
    assert h.nav.target() == (5.0, 5.0)  # the original kept the old goal silently (§9.13)
    msg = h.last_message("bt.command_accepted")
    assert "has 1 waypoint" in msg and "starts from its first waypoint" in msg


def test_pause_resume_keeps_the_waypoint() -> None:
    h = make_harness()
    h.press("select_path", path_id=1)
    h.tick()
    h.nav.succeed()
    h.tick()
    goal_before = h.nav.last
    h.press("pause")
    h.tick()
    assert goal_before.state.value == "preempted" and h.nav.active is None
    assert h.status.text == "Paused" and h.status.state == "paused"
    h.press("resume")
    h.tick()
    assert h.nav.target() == (-0.2, 0.0)  # the same waypoint again
    assert h.bb("waypoint") == 1 and h.status.text == "Moving to (-0.2,0)"


def test_failed_waypoint_is_not_skipped_and_resume_retries_it() -> None:
    from curio.nav.api import LocalizationLostError

    h = make_harness()
    h.press("select_path", path_id=2)
    h.tick()
    h.nav.abort(LocalizationLostError("Localisation is lost."))
    h.tick()
    assert h.bb("waypoint") == 0  # the original advanced the index (§9.12)
    assert h.progress[-1].states == ("failed", "pending", "pending")
    assert h.status.text == "Could not reach (1,1): Localisation is lost."
    goals = len(h.nav.goals)
    h.tick(3)
    assert len(h.nav.goals) == goals  # no goal storm after a failure
    h.press("resume")
    h.tick()
    assert h.nav.target() == (1.0, 1.0) and len(h.nav.goals) == goals + 1
    assert "Trying (1,1) again" in h.last_message("bt.command_accepted")


def test_rejected_goal_does_not_stop_anything() -> None:
    from curio.nav.api import GoalOutsideMapError

    h = make_harness()
    h.nav.reject_next = GoalOutsideMapError("The goal is outside the map.")
    h.press("select_path", path_id=2)
    h.tick(2)
    assert h.of("waypoint.failed")[0].detail["error"] == "goal_outside_map"
    assert "outside the map" in h.status.text
    h.press("select_path", path_id=1)  # the tree still answers (the original died, §9.15)
    h.tick()
    assert h.nav.target() == (0.2, 0.0)


def test_edits_do_not_move_a_running_route() -> None:
    h = make_harness()
    h.press("select_path", path_id=2)
    h.tick()
    h.paths.remove_waypoint(2, 0)
    h.nav.succeed()
    h.tick()
    assert h.nav.target() == (2.0, 2.0)  # the route copied at selection time


def test_replace_waypoints_is_one_validated_persisted_change(tmp_path: Path) -> None:
    """The dashboard's moves, inserts and reorders: all or nothing, saved, one notice."""
    file = tmp_path / "paths.json"
    pm = PathManager(defaults(), file)
    heard: list[tuple[str, int]] = []
    pm.add_listener(lambda what, pid: heard.append((what, pid)))
    pm.replace_waypoints(1, [Waypoint(3.0, 1.0), Waypoint(0.5, 0.5, 7.0)])
    assert heard == [("changed", 1)]
    again = PathManager(defaults(), file)
    wrapped = round(math.remainder(7.0, 2 * math.pi), 6)
    assert again.get(1).waypoints == [Waypoint(3.0, 1.0), Waypoint(0.5, 0.5, wrapped)]
    with pytest.raises(PathError, match="finite"):
        pm.replace_waypoints(1, [Waypoint(1.0, 1.0), Waypoint(float("nan"), 0.0)])
    assert len(pm.get(1).waypoints) == 2  # nothing of the refused change was kept
    with pytest.raises(PathError, match="Home must keep"):
        pm.replace_waypoints(HOME_PATH_ID, [])


def test_an_edit_the_disk_refused_is_undone_not_saved_later(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Found by curio soak (disk_full): the operator was told the edit failed (500), but it
    # stayed in memory and reached the file with the next successful save.
    import errno

    file = tmp_path / "paths.json"
    pm = PathManager(defaults(), file)
    heard: list[tuple[str, int]] = []
    pm.add_listener(lambda what, pid: heard.append((what, pid)))

    def full(path: Path, obj: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("curio.bt.paths.atomic_write_json", full)
    with pytest.raises(PathError, match=r"No space left on device.*nothing was changed"):
        pm.add_waypoint(1, 3.0, 3.0)
    with pytest.raises(PathError, match="nothing was changed"):
        pm.create("new")
    with pytest.raises(PathError, match="nothing was changed"):
        pm.delete(2)
    assert len(pm.get(1).waypoints) == 3 and pm.ids() == [0, 1, 2] and heard == []
    monkeypatch.undo()  # the disk has room again
    pm.rename(2, "Second")  # the disk has room again: the next edit saves
    again = PathManager(defaults(), file)
    assert [(w.x_m, w.y_m) for w in again.get(1).waypoints] == [(0.2, 0.0), (-0.2, 0.0),
                                                                (0.5, 0.0)]
    assert again.ids() == [0, 1, 2] and again.get(2).name == "Second"
    assert pm.create("new").id == 3  # the refused create did not use up an id
