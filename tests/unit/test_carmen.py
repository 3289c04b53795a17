"""CARMEN and Curio run-log readers: the real MIT CSAIL log, hand-made lines, bad lines."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from curio.core.geometry import Pose2D
from curio.estimation.carmen import LogError, RunRecorder, read_carmen, read_log, read_run


def test_reads_the_mit_csail_log(mit_csail_log: Path) -> None:
    first = None
    n = 0
    for s in read_carmen(mit_csail_log):
        if first is None:
            first = s
        n += 1
    assert n == 1988
    assert first is not None
    assert len(first.ranges_m) == 361
    assert first.angle_min_rad == pytest.approx(-math.pi / 2)
    assert first.angle_increment_rad == pytest.approx(math.radians(0.5))
    assert first.odom == Pose2D(576.536523, 0.106594, -2.255213)
    assert first.ranges_m[0] == pytest.approx(1.40)
    assert math.isinf(first.ranges_m[24])  # 81.91 = no return
    pts = first.points()
    assert len(pts) == int(np.isfinite(first.ranges_m).sum())


def _flaser(n: int = 5, r: str = "1.0") -> str:
    readings = " ".join([r] * n)
    return f"FLASER {n} {readings} 1 2 0.5 1 2 0.5 100.5 host 0.1\n"


def test_flaser_robotlaser_and_comments(tmp_path: Path) -> None:
    rl = ("ROBOTLASER1 0 -1.5708 3.14159 0.0174533 81.9 0.01 0 3 1.0 2.0 81.9 0 "
          "0.1 0 0 1 2 0 0 0 0 0 0 200.0 host 0.2\n")
    log = tmp_path / "a.clf"
    log.write_text("# comment\nPARAM robot_x 1\n" + _flaser() + "ODOM 1 2 0 0 0 0 5 h 1\n" + rl)
    scans = list(read_carmen(log))
    assert len(scans) == 2
    assert scans[0].odom == Pose2D(1, 2, 0.5)
    assert scans[0].stamp == 100.5
    r = scans[1]
    assert r.odom == Pose2D(1, 2, 0)
    assert r.laser_pose.x == pytest.approx(-0.9)  # laser at (0.1, 0) in the odom frame
    assert r.ranges_m[1] == 2.0 and math.isinf(r.ranges_m[2])
    assert r.angle_min_rad == pytest.approx(-1.5708)


@pytest.mark.parametrize(("line", "pattern"), [
    ("FLASER x 1 2\n", r"a\.clf:2: FLASER: number of readings 'x'"),
    ("FLASER 5 1 1 1\n", r"a\.clf:2: FLASER: 5 readings need at least 14 fields"),
    (_flaser(r="abc"), r"a\.clf:2: FLASER reading: field 1 is 'abc'"),
    (_flaser(r="nan"), r"a\.clf:2: FLASER reading: field 1 is 'nan', not finite"),
    ("ODOM 1 2\n", r"a\.clf:2: ODOM needs"),
    ("hello world\n", r"a\.clf:2: not a CARMEN message"),
])
def test_bad_lines_are_rejected_with_the_line_number(tmp_path: Path, line: str,
                                                     pattern: str) -> None:
    log = tmp_path / "a.clf"
    log.write_text(_flaser() + line)
    with pytest.raises(LogError, match=pattern):
        list(read_carmen(log))


def test_log_without_lasers_is_rejected(tmp_path: Path) -> None:
    log = tmp_path / "a.clf"
    log.write_text("ODOM 1 2 0 0 0 0 5 h 1\n")
    with pytest.raises(LogError, match="no FLASER or ROBOTLASER"):
        list(read_carmen(log))
    with pytest.raises(LogError, match="cannot open"):
        list(read_carmen(tmp_path / "missing.clf"))


def test_run_log_round_trip_interpolates_odometry(tmp_path: Path) -> None:
    buf = io.StringIO()
    rec = RunRecorder(buf, Pose2D(0.1, 0.0, 0.0))
    rec.odom(0.0, Pose2D(0, 0, 0))
    rec.odom(1.0, Pose2D(1.0, 0, 0))
    rec.truth(0.5, Pose2D(0.5, 0, 0))
    rec.scan(0.5, -math.pi, math.pi / 2, 0.1, 10.0, np.array([1.0, np.inf, np.nan, 3.0]))
    path = tmp_path / "run.jsonl"
    path.write_text(buf.getvalue())
    scans = list(read_log(path))
    assert len(scans) == 1
    s = scans[0]
    assert s.odom.x == pytest.approx(0.5)
    assert s.laser_pose == Pose2D(0.1, 0.0, 0.0)
    assert s.ranges_m[0] == 1.0 and math.isinf(s.ranges_m[1]) and math.isinf(s.ranges_m[2])
    assert len(s.points()) == 2


@pytest.mark.parametrize(("text", "pattern"), [
    ('{"type": "odom", "t": 0, "x": 0}\n', r"run\.jsonl:1: odom record is missing field 'y'"),
    ('not json\n', r"run\.jsonl:1: not valid JSON"),
    ('{"type": "teleport"}\n', r"run\.jsonl:1: unknown record type 'teleport'"),
    ('{"type": "odom", "t": "soon", "x": 0, "y": 0, "yaw": 0}\n', r"run\.jsonl:1: odom record "
     r"has a bad value"),
    ('{"type": "odom", "t": 0, "x": 0, "y": 0, "yaw": 0}\n', "no scan records"),
    ('{"type": "header", "format": "rosbag"}\n', "header format must be 'curio-run'"),
])
def test_bad_run_logs(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "run.jsonl"
    path.write_text(text)
    with pytest.raises(LogError, match=pattern):
        list(read_run(path))
