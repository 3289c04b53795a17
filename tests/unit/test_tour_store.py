"""The tour store: validated edits, placement on the map, persistence, migration, corrupt files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from curio.core.config import TourStopConfig
from curio.core.errors import SetupError
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid
from curio.tours.files import DataFileError
from curio.tours.model import TourError, make_message, make_stop
from curio.tours.placement import MapPlacement
from curio.tours.store import TourStore

SEED = [TourStopConfig(name="Lobby", x_m=1.0, y_m=1.0, dwell_s=5.0, message="Welcome!"),
        TourStopConfig(name="Gallery", x_m=3.0, y_m=1.0, yaw_deg=90.0, message="Art.")]


def room() -> OccupancyGrid:
    """A 5 m x 3 m room at 0.05 m: walls all round, a pillar at (2.5, 2.0)."""
    data = np.zeros((60, 100), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[38:42, 48:52] = 100
    data[50:58, 80:98] = -1  # an unmapped corner
    return OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0), name="room")


def store(tmp_path: Path, **kw: object) -> TourStore:
    return TourStore(tmp_path / "tours.json", SEED,
                     check_place=MapPlacement(room(), 0.31), **kw)  # type: ignore[arg-type]


def test_config_stops_seed_the_first_tour_and_are_saved(tmp_path: Path) -> None:
    s = store(tmp_path)
    (tour,) = s.list_tours()
    assert (tour.id, tour.name, [st.name for st in tour.stops]) == (1, "Tour", ["Lobby",
                                                                                 "Gallery"])
    assert tour.stops[1].yaw_rad == pytest.approx(math.pi / 2, abs=1e-6)
    assert tour.stops[0].message.text == "Welcome!" and tour.stops[0].dwell_s == 5.0
    saved = json.loads((tmp_path / "tours.json").read_text())
    assert saved["version"] == 2 and saved["tours"][0]["name"] == "Tour"
    again = TourStore(tmp_path / "tours.json", [])
    assert again.list_tours() == s.list_tours()


def test_crud_and_ids_are_never_reused(tmp_path: Path) -> None:
    s = store(tmp_path)
    a = s.create("Highlights", [make_stop("Desk", 1.0, 2.0, dwell_s=3.0)])
    assert a.id == 2
    s.rename(a.id, "  Best   of ")
    assert s.get(a.id).name == "Best of"
    dup = s.duplicate(a.id)
    assert dup.name == "Best of (copy)" and dup.stops == s.get(a.id).stops
    assert s.duplicate(a.id).name == "Best of (copy 2)"
    s.delete(a.id)
    assert s.create("New").id == 5
    with pytest.raises(TourError, match=r"There is no tour 2\. The tours are: 1 \(Tour\)"):
        s.get(2)
    with pytest.raises(TourError, match="already a tour called 'New'"):
        s.create("new")
    reloaded = TourStore(tmp_path / "tours.json")
    assert [t.id for t in reloaded.list_tours()] == [1, 3, 4, 5]
    assert reloaded.create("Later").id == 6


def test_stop_edits_reorder_and_revisions(tmp_path: Path) -> None:
    s = store(tmp_path)
    t = s.add_stop(1, make_stop("Desk", 4.0, 1.0, dwell_s=2.0), index=1)
    assert [st.name for st in t.stops] == ["Lobby", "Desk", "Gallery"] and t.revision == 2
    t = s.move_stop(1, 0, 2)
    assert [st.name for st in t.stops] == ["Desk", "Gallery", "Lobby"]
    t = s.reorder(1, [2, 0, 1])
    assert [st.name for st in t.stops] == ["Lobby", "Desk", "Gallery"]
    t = s.update_stop(1, 1, x_m=4.2, yaw_rad=7.0, dwell_s=20, message="Hello", language="fr",
                      voice="fr+f2")
    stop = t.stops[1]
    assert (stop.x_m, stop.dwell_s, stop.message) == (4.2, 20.0,
                                                      make_message("Hello", "fr", "fr+f2"))
    assert stop.yaw_rad == pytest.approx(7.0 - 2 * math.pi, abs=1e-6)
    t = s.remove_stop(1, 0)
    assert [st.name for st in t.stops] == ["Desk", "Gallery"]
    with pytest.raises(TourError, match=r"was changed meanwhile .*revision 6.*based on 2"):
        s.rename(1, "Other", expect_revision=2)
    assert s.rename(1, "Other", expect_revision=t.revision).name == "Other"
    with pytest.raises(TourError, match="each of its stop numbers 0 to 1 once"):
        s.reorder(1, [0, 0])
    with pytest.raises(TourError, match="has stops 0 to 1; there is no stop 5"):
        s.update_stop(1, 5, dwell_s=1)
    with pytest.raises(TourError, match="no field 'colour'"):
        s.update_stop(1, 0, colour="red")


@pytest.mark.parametrize(("x", "y", "why"), [
    (7.0, 1.0, r"outside the map \(the map spans x 0 to 5 m and y 0 to 3 m\)"),
    (0.02, 1.0, "inside an obstacle"),
    (2.5, 2.0, "inside an obstacle"),
    (2.5, 1.6, r"too close to an obstacle \(0\.\d+ m from it; the rover needs 0\.31 m\)"),
    (4.5, 2.7, "unmapped part of the map"),
])
def test_a_stop_off_the_map_or_in_a_wall_is_refused_with_the_reason(
        tmp_path: Path, x: float, y: float, why: str) -> None:
    s = store(tmp_path)
    before = s.get(1)
    with pytest.raises(TourError, match=f"The stop 'Bad' at \\(.*\\) m is .*{why}"):
        s.add_stop(1, make_stop("Bad", x, y))
    with pytest.raises(TourError, match=why):
        s.update_stop(1, 0, x_m=x, y_m=y)
    assert s.get(1) == before  # nothing changed
    assert TourStore(tmp_path / "tours.json").get(1) == before


def test_problems_list_what_keeps_a_tour_from_running(tmp_path: Path) -> None:
    s = store(tmp_path, path_exists=lambda pid: pid == 1)
    empty = s.create("Empty")
    assert s.problems(empty) == ["Tour 2 (Empty) has no stops; add at least one."]
    assert s.problems(s.get(1)) == []
    # The map changes under a saved stop (checked at start, not at load).
    s.check_place = lambda x, y: "is inside an obstacle on the map" if x > 2 else None
    assert s.problems(s.get(1)) == ["Stop 2 (Gallery) is inside an obstacle on the map."]
    with pytest.raises(TourError, match="no path 7 to follow"):
        s.add_stop(1, make_stop("Via", 1.0, 1.5, route_path_id=7))


@pytest.mark.parametrize(("kwargs", "why"), [
    ({"name": ""}, "a stop name cannot be empty"),
    ({"x_m": float("nan")}, "x must be a number of metres"),
    ({"dwell_s": -1}, "the dwell time must be a number of seconds from 0 to 3600"),
    ({"dwell_s": True}, "the dwell time must be a number"),
    ({"route_path_id": -2}, "a path number"),
])
def test_bad_stop_values_name_the_value(kwargs: dict[str, object], why: str) -> None:
    args: dict[str, object] = {"name": "S", "x_m": 1.0, "y_m": 1.0, **kwargs}
    with pytest.raises(TourError, match=why):
        make_stop(**args)  # type: ignore[arg-type]


def test_message_language_and_voice_are_checked() -> None:
    assert make_message("  Hi   there ", "pt-BR", "en-gb+f3").text == "Hi there"
    with pytest.raises(TourError, match="language tag"):
        make_message("x", "English")
    with pytest.raises(TourError, match="voice name"):
        make_message("x", "", "rm -rf /")
    with pytest.raises(TourError, match="at most 1000 characters"):
        make_message("x" * 1001)


def test_a_damaged_file_is_replaced_by_its_backup_and_kept(tmp_path: Path) -> None:
    # Found by curio soak (corrupt_file): a damaged tours file kept the rover from starting,
    # and the backup was the version before the last save (one edit behind).
    s = store(tmp_path)
    s.rename(1, "Good")
    path = tmp_path / "tours.json"
    good = path.read_text()
    assert (tmp_path / "tours.json.bak").read_text() == good  # a second copy of the last save
    path.write_text(good[:-20])  # truncated by a crash of some editor
    again = TourStore(path, SEED)
    assert [t.name for t in again.list_tours()] == ["Good"]
    assert again.restored is not None and "not valid JSON" in again.restored
    assert "tours.json.corrupt-1" in again.restored
    assert path.read_text() == good
    assert (tmp_path / "tours.json.corrupt-1").read_text() == good[:-20]


def test_a_damaged_file_without_a_usable_backup_is_refused_and_kept(tmp_path: Path) -> None:
    s = store(tmp_path)
    s.rename(1, "Good")
    path = tmp_path / "tours.json"
    good = path.read_text()
    path.write_text(good[:-20])
    (tmp_path / "tours.json.bak").write_text("{")
    with pytest.raises(DataFileError) as info:
        TourStore(path, SEED)
    msg = str(info.value)
    assert str(path) in msg and "not valid JSON (line" in msg
    assert "tours.json.bak" in msg and "cannot be used either" in msg
    assert isinstance(info.value, SetupError)
    assert path.read_text() == good[:-20]  # left exactly as it was


@pytest.mark.parametrize(("content", "problem"), [
    ('{"version": 9, "tours": []}', r"written by a newer Curio \(version 9"),
    ('{"tours": []}', "has no version number"),
    ('[1, 2]', "holds list, not a JSON object"),
    ('{"version": 2, "tours": [{"id": 1, "name": "A", "stops": [{"name": "S", "x_m": "far",'
     ' "y_m": 0}]}]}', "tour 1, stop 1: x must be a number of metres"),
    ('{"version": 2, "tours": [{"id": 1, "name": "A"}, {"id": 1, "name": "B"}]}',
     "tour ids repeat"),
])
def test_invalid_files_are_refused(tmp_path: Path, content: str, problem: str) -> None:
    path = tmp_path / "tours.json"
    path.write_text(content)
    with pytest.raises(DataFileError, match=problem):
        TourStore(path)
    assert path.read_text() == content


def test_a_version_1_file_is_migrated(tmp_path: Path) -> None:
    path = tmp_path / "tours.json"
    path.write_text(json.dumps({"version": 1, "name": "Old tour", "stops": [
        {"name": "A", "x_m": 1, "y_m": 2, "yaw_deg": 180, "dwell_s": 4, "message": "Hi"},
        {"name": "B", "x_m": 3, "y_m": 2}]}))
    s = TourStore(path)
    (tour,) = s.list_tours()
    assert tour.name == "Old tour" and tour.stops[0].message.text == "Hi"
    assert tour.stops[0].yaw_rad == pytest.approx(math.pi, abs=1e-6) or \
        tour.stops[0].yaw_rad == pytest.approx(-math.pi, abs=1e-6)
    assert tour.stops[1].yaw_rad is None and tour.stops[1].dwell_s == 10.0
    s.rename(1, "Renamed")
    assert json.loads(path.read_text())["version"] == 2
    assert json.loads((tmp_path / "tours.json.v1.bak").read_text())["version"] == 1


def test_an_edit_the_disk_refused_is_undone_not_saved_later(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Same defect as the paths' (found by curio soak's disk_full): an edit whose save failed
    # stayed in memory and reached the file with the next successful save.
    import errno

    s = store(tmp_path)

    def full(path: Path, text: str, private: bool = False) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("curio.tours.files.atomic_write_text", full)
    with pytest.raises(TourError, match=r"No space left on device.*nothing was changed"):
        s.create("Lost")
    with pytest.raises(TourError, match="nothing was changed"):
        s.rename(1, "Renamed")
    assert [(t.id, t.name) for t in s.list_tours()] == [(1, "Tour")]
    monkeypatch.undo()  # the disk has room again
    assert s.create("Kept").id == 2  # the refused create did not use up an id
    again = TourStore(tmp_path / "tours.json", [])
    assert [(t.id, t.name) for t in again.list_tours()] == [(1, "Tour"), (2, "Kept")]
