"""Mapping: pose-graph optimisation, scan-matched mapping of a room, loop closure, CLI."""

from __future__ import annotations

import csv
import io
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from curio.commands.map import main as map_main
from curio.core.geometry import Pose2D
from curio.estimation.carmen import LogScan, RunRecorder
from curio.estimation.mapping import (
    MapperParams,
    ScanMapper,
    build_map_from_log,
    optimize_pose_graph,
)
from curio.estimation.maps import OccupancyGrid, load_map
from tests.unit.test_localization_helpers import cast_scan, room_grid

LASER = Pose2D(0.152, 0.078, 0.0)


def test_pose_graph_closes_a_drifting_square() -> None:
    truth = [Pose2D()]
    for k in range(1, 40):
        truth.append(truth[-1] @ Pose2D(1.0, 0.0, math.pi / 2 if k % 10 == 0 else 0.0))
    info = np.diag([100.0, 100.0, 1000.0])
    edges = []
    est = [Pose2D()]
    for k in range(1, 40):
        z = truth[k - 1].inverse() @ truth[k]
        zn = Pose2D(z.x, z.y + 0.01, z.yaw + 0.02)  # a curving drift
        edges.append((k - 1, k, zn, info))
        est.append(est[-1] @ zn)
    edges.append((0, 39, truth[0].inverse() @ truth[39], info))
    x0 = np.array([p.as_tuple() for p in est])
    x = optimize_pose_graph(x0, edges)
    before = max(Pose2D(*r).distance_to(t) for r, t in zip(x0, truth, strict=True))
    after = max(Pose2D(*r).distance_to(t) for r, t in zip(x, truth, strict=True))
    assert before > 3.0
    assert after < 0.25 * before
    assert np.allclose(x[0], 0.0)


def _loop_scans(rng: np.random.Generator, laps: float = 1.0) -> tuple[list[LogScan], list[Pose2D]]:
    """A loop through both rooms of the test map with drifting odometry (5 %, 2°/m)."""
    grid = room_grid()
    wps = [(1.0, 3.0), (4.0, 3.0), (7.5, 2.7), (9.5, 4.0), (8.0, 5.0), (5.5, 3.7), (3.0, 4.0),
           (1.5, 4.5), (1.0, 3.0), (4.0, 3.0)]
    truth: list[Pose2D] = []
    pose = Pose2D(1.0, 3.0, 0.0)
    odom = Pose2D()
    scans = []
    t = 0.0
    for (x0, y0), (x1, y1) in itertools.pairwise(wps):
        heading = math.atan2(y1 - y0, x1 - x0)
        turn = math.remainder(heading - pose.yaw, 2 * math.pi)
        steps = [Pose2D(0, 0, turn / 4)] * 4
        dist = math.hypot(x1 - x0, y1 - y0)
        n = max(1, round(dist / 0.05))
        steps += [Pose2D(dist / n, 0, 0)] * n
        for d in steps:
            pose = pose @ d
            noisy = Pose2D(d.x * 1.05, d.y, d.yaw + math.radians(2.0) * abs(d.x))
            odom = odom @ noisy
            t += 0.1
            scan = cast_scan(grid, pose, LASER, stamp=t, sigma_m=0.02, dropout=0.02, rng=rng)
            r = np.asarray(scan.ranges_m, dtype=np.float64)
            scans.append(LogScan(t, odom, LASER, scan.angle_min_rad, scan.angle_increment_rad,
                                 r, scan.range_max_m))
            truth.append(pose)
    return scans, truth


def _agreement(built: OccupancyGrid, truth: OccupancyGrid) -> float:
    near = ndimage.binary_dilation(truth.occupied_mask(), structure=np.ones((3, 3), bool))
    rows, cols = np.nonzero(built.occupied_mask())
    xy = np.array([built.cell_to_world(int(r), int(c)) for r, c in zip(rows, cols, strict=True)])
    cells = truth.world_to_cells(xy)
    ok = ((cells[:, 0] >= 0) & (cells[:, 0] < truth.height) & (cells[:, 1] >= 0)
          & (cells[:, 1] < truth.width))
    hit = np.zeros(len(cells), dtype=bool)
    hit[ok] = near[cells[ok, 0], cells[ok, 1]]
    return float(hit.mean())


@pytest.fixture(scope="module")
def room_run() -> tuple[list[LogScan], list[Pose2D], ScanMapper]:
    """One loop through the test room, mapped once for the tests below."""
    scans, truth = _loop_scans(np.random.default_rng(7))
    mapper = build_map_from_log(scans, MapperParams(max_range_m=12.0, loop_min_travel_m=8.0),
                                initial=truth[0])
    return scans, truth, mapper


def test_maps_a_room_with_drifting_odometry(
        room_run: tuple[list[LogScan], list[Pose2D], ScanMapper]) -> None:
    scans, truth, mapper = room_run
    errs = [p.distance_to(t) for (_, p), t in zip(mapper.trajectory, truth, strict=True)]
    odom_end = truth[0] @ scans[-1].odom
    assert odom_end.distance_to(truth[-1]) > 0.5  # the odometry alone is far off
    assert max(errs) < 0.08
    built = mapper.occupancy()
    assert _agreement(built, room_grid()) > 0.95
    assert mapper.matched > 0.9 * mapper.scans


def test_loop_closure_is_found_on_return(
        room_run: tuple[list[LogScan], list[Pose2D], ScanMapper]) -> None:
    _, truth, mapper = room_run
    assert mapper.loop_edges, "coming back to the start should close the loop"
    for i, j, z in mapper.loop_edges:
        # Each constraint agrees with the truth at those keyframes.
        ki, kj = mapper._kf_scan_index[i], mapper._kf_scan_index[j]
        zt = truth[ki].inverse() @ truth[kj]
        assert z.distance_to(zt) < 0.1


def _write_run_log(path: Path, scans: list[LogScan]) -> None:
    buf = io.StringIO()
    rec = RunRecorder(buf, LASER)
    for s in scans:
        rec.odom(s.stamp, s.odom)
        rec.scan(s.stamp, s.angle_min_rad, s.angle_increment_rad, 0.15, s.range_max_m,
                 s.ranges_m)
    path.write_text(buf.getvalue())


def test_cli_build_info_convert(tmp_path: Path,
                                room_run: tuple[list[LogScan], list[Pose2D], ScanMapper]) -> None:
    scans = room_run[0]
    log = tmp_path / "run.jsonl"
    _write_run_log(log, scans[:120])
    out, err = io.StringIO(), io.StringIO()
    code = map_main(["build", "--log", str(log), "--out", str(tmp_path / "m.yaml"),
                     "--trajectory", str(tmp_path / "t.csv"), "--quiet"], out, err)
    assert code == 0, err.getvalue()
    assert "built" in out.getvalue()
    grid = load_map(tmp_path / "m.yaml")
    assert grid.occupied_mask().any() and grid.free_mask().any()
    with open(tmp_path / "t.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t", "x", "y", "yaw"] and len(rows) == 121
    out = io.StringIO()
    assert map_main(["info", str(tmp_path / "m.yaml")], out, err) == 0
    assert "resolution  0.05 m/cell" in out.getvalue() and "occupied" in out.getvalue()
    assert map_main(["convert", str(tmp_path / "m.yaml"), str(tmp_path / "c.yaml"),
                     "--format", "png"], io.StringIO(), err) == 0
    converted = load_map(tmp_path / "c.yaml")
    assert np.array_equal(converted.occupied_mask(), grid.occupied_mask())
    assert np.array_equal(converted.free_mask(), grid.free_mask())
    assert (tmp_path / "c.png").exists()


def test_cli_build_from_the_mit_log_head_with_progress(tmp_path: Path,
                                                       mit_csail_log: Path) -> None:
    mit = mit_csail_log
    head = tmp_path / "head.clf"
    with open(mit) as fh:
        lines = [next(fh) for _ in range(130)]
    head.write_text("".join(lines))
    class Terminal(io.StringIO):
        def isatty(self) -> bool:  # the bar is drawn on terminals only
            return True

    out, err = io.StringIO(), Terminal()
    code = map_main(["build", "--log", str(head), "--out", str(tmp_path / "mit.yaml")], out, err)
    assert code == 0, err.getvalue()
    assert "100%" in err.getvalue()  # the progress bar
    assert load_map(tmp_path / "mit.yaml").occupied_mask().sum() > 100


@pytest.mark.parametrize(("argv", "message"), [
    (["build", "--log", "/nonexistent.clf", "--out", "x.yaml"], "no such file"),
    (["info", "/nonexistent.yaml"], "map file not found"),
    (["frobnicate"], ""),
])
def test_cli_errors_exit_2(argv: list[str], message: str) -> None:
    err = io.StringIO()
    assert map_main(argv, io.StringIO(), err) == 2
    assert message in err.getvalue()


def test_cli_build_rejects_a_bad_log_with_line_number(tmp_path: Path) -> None:
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1 1 1 0 0 0 0 0 0 0 h 0\nFLASER 3 1 oops 1 0 0 0 0 0 0 0 h 0\n")
    err = io.StringIO()
    assert map_main(["build", "--log", str(bad), "--out", str(tmp_path / "b.yaml")],
                    io.StringIO(), err) == 2
    assert "bad.clf:2" in err.getvalue() and "'oops'" in err.getvalue()
    assert not (tmp_path / "b.yaml").exists()
