"""map_server maps: the real maps, hand-made tiny maps in every mode, round trips and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from curio.core.geometry import Pose2D
from curio.estimation.maps import MapError, OccupancyGrid, load_map, map_stats, save_map


def _write(tmp: Path, pixels: list[list[int]], yaml_text: str, name: str = "m.pgm",
           mode: str = "L") -> Path:
    img = Image.fromarray(np.array(pixels, dtype=np.uint8), mode=mode)
    img.save(tmp / name)
    y = tmp / "m.yaml"
    y.write_text(f"image: {name}\n" + yaml_text)
    return y


BASE = "resolution: 0.1\norigin: [1.0, 2.0, 0.0]\n"


@pytest.mark.parametrize("folder", ["willow_garage", "tb3_sandbox", "warehouse", "depot",
                                    "lse_arena", "curio_shapes"])
def test_real_maps_load(shared_maps: Path, folder: str) -> None:
    yaml_path = next((shared_maps / folder).glob("*.yaml"))
    grid = load_map(yaml_path)
    with Image.open(yaml_path.with_suffix(".pgm") if yaml_path.with_suffix(".pgm").exists()
                    else next((shared_maps / folder).glob("*.pgm"))) as img:
        assert (grid.width, grid.height) == img.size
    stats = map_stats(grid)
    assert stats["free_pct"] > 5.0 and stats["occupied_pct"] > 0.1
    assert math.isclose(stats["free_pct"] + stats["occupied_pct"] + stats["unknown_pct"], 100.0,
                        abs_tol=1e-6) or grid.occupied_thresh < 1.0


def test_willow_garage_has_its_documented_size(shared_maps: Path) -> None:
    grid = load_map(shared_maps / "willow_garage" / "willow-full-0.05.yaml")
    assert (grid.width, grid.height) == (1165, 945)
    assert grid.resolution_m == pytest.approx(0.05)


def test_trinary_rows_flip_and_thresholds(tmp_path: Path) -> None:
    # Image top row is the map's highest y.
    y = _write(tmp_path, [[0, 254, 205], [255, 60, 180]], BASE)
    g = load_map(y)
    assert g.data.dtype == np.int8
    # 60 → p = 0.76 > 0.65: occupied; 180 → p = 0.29: between the thresholds, unknown.
    assert g.data.tolist() == [[0, 100, -1], [100, 0, -1]]
    assert g.origin == Pose2D(1.0, 2.0, 0.0)
    # Cell (row 1, col 0) = top-left pixel, occupied.
    assert g.world_to_cell(1.05, 2.15) == (1, 0)


def test_negate_inverts(tmp_path: Path) -> None:
    y = _write(tmp_path, [[0, 254]], BASE + "negate: 1\n")
    assert load_map(y).data.tolist() == [[0, 100]]


def test_scale_mode_keeps_intermediate_values(tmp_path: Path) -> None:
    y = _write(tmp_path, [[0, 254, 128]], BASE + "mode: scale\n")
    row = load_map(y).data.tolist()[0]
    assert row[0] == 100 and row[1] == 0
    assert 0 < row[2] < 100


def test_scale_mode_transparent_is_unknown(tmp_path: Path) -> None:
    rgba = np.zeros((1, 2, 4), dtype=np.uint8)
    rgba[0, :, :3] = 254
    rgba[0, 0, 3] = 255
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
    y = tmp_path / "m.yaml"
    y.write_text("image: a.png\nmode: scale\n" + BASE)
    assert load_map(y).data.tolist() == [[0, -1]]


def test_raw_mode_copies_values(tmp_path: Path) -> None:
    y = _write(tmp_path, [[0, 37, 100, 255]], BASE + "mode: raw\n")
    assert load_map(y).data.tolist() == [[0, 37, 100, -1]]


def test_raw_mode_rejects_values_above_100(tmp_path: Path) -> None:
    y = _write(tmp_path, [[0, 180]], BASE + "mode: raw\n")
    with pytest.raises(MapError, match=r"m\.yaml.*'mode'.*180.*column 1"):
        load_map(y)


def test_origin_yaw_rotates_cells(tmp_path: Path) -> None:
    y = _write(tmp_path, [[254, 254], [254, 254]], "resolution: 1.0\norigin: [0, 0, 1.5707963]\n")
    g = load_map(y)
    # With the grid rotated 90°, cell (0, 1) (x along the grid) lies along +y in map.
    x, yy = g.cell_to_world(0, 1)
    assert x == pytest.approx(-0.5, abs=1e-6) and yy == pytest.approx(1.5, abs=1e-6)
    assert g.world_to_cell(-0.5, 1.5) == (0, 1)


@pytest.mark.parametrize("fmt", ["pgm", "png"])
@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
def test_round_trip(tmp_path: Path, fmt: str, mode: str) -> None:
    rng = np.random.default_rng(1)
    values = [0, 100] if (mode, fmt) == ("scale", "pgm") else [-1, 0, 100]
    data = rng.choice(np.array(values, dtype=np.int8), size=(7, 11))
    grid = OccupancyGrid(data, 0.05, Pose2D(-1.25, 3.5, 0.3))
    out = save_map(grid, tmp_path / "saved.yaml", image_format=fmt, mode=mode)
    back = load_map(out)
    assert np.array_equal(back.data, data)
    assert back.origin.x == pytest.approx(-1.25) and back.origin.yaw == pytest.approx(0.3)
    assert back.resolution_m == pytest.approx(0.05)
    assert (tmp_path / f"saved.{fmt}").exists()


@pytest.mark.parametrize("mode", ["scale", "raw"])
def test_round_trip_intermediate_values(tmp_path: Path, mode: str) -> None:
    data = np.array([[0, 10, 50, 90, 99, 100, -1]], dtype=np.int8)
    grid = OccupancyGrid(data, 0.1)
    back = load_map(save_map(grid, tmp_path / "s.yaml", image_format="png", mode=mode))
    # Scale mode squeezes 1..99 into ~116 grey levels: a value may come back off by one.
    tol = 1 if mode == "scale" else 0
    assert np.abs(back.data.astype(int) - data.astype(int)).max() <= tol
    assert back.data[0, 0] == 0 and back.data[0, 5] == 100 and back.data[0, 6] == -1


def test_scale_pgm_cannot_store_unknown(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.array([[0, -1]], dtype=np.int8), 0.1)
    with pytest.raises(MapError, match=r"unknown cells.*png"):
        save_map(grid, tmp_path / "s.yaml", image_format="pgm", mode="scale")


def test_round_trip_of_a_real_map(tmp_path: Path, shared_maps: Path) -> None:
    grid = load_map(shared_maps / "tb3_sandbox" / "tb3_sandbox.yaml")
    back = load_map(save_map(grid, tmp_path / "copy.yaml", image_format="png"))
    assert np.array_equal(back.occupied_mask(), grid.occupied_mask())
    assert np.array_equal(back.free_mask(), grid.free_mask())


@pytest.mark.parametrize(("yaml_text", "pattern"), [
    ("resolution: 0.1\norigin: [0, 0, 0]\n", "'image' is missing"),
    ("image: m.pgm\norigin: [0, 0, 0]\n", "'resolution' is missing"),
    ("image: m.pgm\nresolution: -1\norigin: [0, 0, 0]\n", "'resolution' must be > 0"),
    ("image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\n", "'resolution'.*not a"),
    ("image: m.pgm\nresolution: 0.1\n", "'origin' is missing"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0]\n", "'origin' must be"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, .nan, 0]\n", "'origin' must be"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 2\n", "'negate'"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nmode: fancy\n", "'mode'"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: high\n",
     "'occupied_thresh' must be a finite number"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nfree_thresh: 0.7\n", "thresholds"),
    ("image: nothere.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", "'image' names .*nothere"),
    ("image: [1, 2]\nresolution: 0.1\norigin: [0, 0, 0]\n", "'image'"),
    ("- just\n- a list\n", "YAML mapping"),
    ("image: m.pgm\n  bad: [\n", "not valid YAML"),
])
def test_bad_files_name_file_field_and_problem(tmp_path: Path, yaml_text: str,
                                               pattern: str) -> None:
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8), mode="L").save(tmp_path / "m.pgm")
    y = tmp_path / "m.yaml"
    y.write_text(yaml_text)
    with pytest.raises(MapError, match=pattern) as info:
        load_map(y)
    assert str(y) in str(info.value)


def test_missing_yaml_and_corrupt_image(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="not found"):
        load_map(tmp_path / "absent.yaml")
    (tmp_path / "m.pgm").write_bytes(b"P5\n garbage")
    y = tmp_path / "m.yaml"
    y.write_text("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(MapError, match="'image': cannot read"):
        load_map(y)


def test_save_rejects_bad_format(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.zeros((2, 2), dtype=np.int8), 0.1)
    with pytest.raises(MapError, match="pgm or png"):
        save_map(grid, tmp_path / "x.yaml", image_format="jpg")
    with pytest.raises(MapError, match="trinary, scale or raw"):
        save_map(grid, tmp_path / "x.yaml", mode="weird")


def test_numpy_scalars_in_the_origin_are_written_as_plain_numbers(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.zeros((2, 2), dtype=np.int8), float(np.float64(0.05)),
                         Pose2D(np.float64(-6.95), np.float64(1.25), 0.0))  # type: ignore[arg-type]
    back = load_map(save_map(grid, tmp_path / "n.yaml"))
    assert back.origin.x == pytest.approx(-6.95)
