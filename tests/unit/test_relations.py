"""The Freiburg relative-relation metric and ``curio map score``."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from curio.commands.map import main as map_main
from curio.core.geometry import Pose2D
from curio.estimation.relations import (
    Relation,
    RelationError,
    read_relations,
    read_trajectory,
    score_trajectory,
)

# A small square drive: one pose every 0.2 s.
TRUTH = [Pose2D(0.0, 0.0, 0.3)]
for _k in range(1, 12):
    TRUTH.append(TRUTH[-1] @ Pose2D(0.5, 0.0, math.pi / 2 if _k % 3 == 0 else 0.05))
STAMPS = [1000.0 + 0.2 * k for k in range(len(TRUTH))]


def _relations(pairs: list[tuple[int, int]]) -> list[Relation]:
    out = []
    for i, j in pairs:
        d = TRUTH[i].inverse() @ TRUTH[j]
        out.append(Relation(STAMPS[i], STAMPS[j], d.x, d.y, d.yaw))
    return out


def _traj(poses: list[Pose2D], stamps: list[float] | None = None) -> np.ndarray:
    ts = STAMPS if stamps is None else stamps
    return np.array([(t, p.x, p.y, p.yaw) for t, p in zip(ts, poses, strict=True)])


PAIRS = [(0, 1), (1, 2), (2, 5), (0, 11), (4, 9), (10, 11)]


def test_a_perfect_trajectory_scores_zero() -> None:
    sc = score_trajectory(_traj(TRUTH), _relations(PAIRS))
    assert sc.matched == len(PAIRS)
    assert sc.trans_mean_m == pytest.approx(0.0, abs=1e-9)
    assert sc.trans_max_m == pytest.approx(0.0, abs=1e-9)
    assert sc.rot_mean_deg == pytest.approx(0.0, abs=1e-9)


def test_a_rigidly_moved_trajectory_scores_zero() -> None:
    """The metric is relative: a global offset of the map frame is no error."""
    move = Pose2D(12.0, -3.0, 2.5)
    sc = score_trajectory(_traj([move @ p for p in TRUTH]), _relations(PAIRS))
    assert sc.trans_max_m == pytest.approx(0.0, abs=1e-9)
    assert sc.rot_max_deg == pytest.approx(0.0, abs=1e-9)


def test_a_known_offset_gives_the_known_error() -> None:
    # Pose 5 is 0.1 m off sideways (in its own frame) and 2° off in heading.
    est = list(TRUTH)
    est[5] = TRUTH[5] @ Pose2D(0.0, 0.1, math.radians(2.0))
    sc = score_trajectory(_traj(est), _relations([(2, 5), (0, 1)]))
    assert sc.trans_errors_m == pytest.approx([0.1, 0.0], abs=1e-9)
    assert sc.rot_errors_deg == pytest.approx([2.0, 0.0], abs=1e-9)
    assert sc.trans_mean_m == pytest.approx(0.05)
    assert sc.trans_std_m == pytest.approx(0.05)
    assert sc.rot_mean_deg == pytest.approx(1.0)
    assert sc.worst_trans == _relations([(2, 5)])[0]


def test_a_heading_error_at_the_first_pose_swings_the_second() -> None:
    """A 90° error at t1 turns a 1 m relation by 90°: √2 m and 90° of error."""
    truth = [Pose2D(), Pose2D(1.0, 0.0, 0.0)]
    est = [Pose2D(0.0, 0.0, math.pi / 2), Pose2D(1.0, 0.0, 0.0)]
    traj = np.array([(0.0, *p.as_tuple()) if k == 0 else (1.0, *p.as_tuple())
                     for k, p in enumerate(est)])
    rel = [Relation(0.0, 1.0, *(truth[0].inverse() @ truth[1]).as_tuple())]
    sc = score_trajectory(traj, rel)
    assert sc.trans_mean_m == pytest.approx(math.sqrt(2.0))
    assert sc.rot_mean_deg == pytest.approx(90.0)


def test_timestamps_match_the_nearest_pose_within_max_dt() -> None:
    stamps = [t + 0.0004 for t in STAMPS]  # 0.4 ms late
    rels = _relations(PAIRS)
    assert score_trajectory(_traj(TRUTH, stamps), rels).matched == len(PAIRS)
    sc = score_trajectory(_traj(TRUTH, stamps), rels, max_dt_s=1e-4)
    assert sc.matched == 0
    assert math.isnan(sc.trans_mean_m)
    # A relation outside the trajectory's time span is not matched.
    far = [*rels, Relation(5000.0, 5000.2, 0.5, 0.0, 0.0)]
    assert score_trajectory(_traj(TRUTH), far).matched == len(PAIRS)


def _write(tmp: Path, rels: list[Relation], poses: list[Pose2D]) -> tuple[Path, Path]:
    rp = tmp / "r.relations"
    rp.write_text("# t1 t2 x y z roll pitch yaw\n" + "".join(
        f"{r.t1_s:.5f} {r.t2_s:.5f} {r.x_m:.6f} {r.y_m:.6f} 0 0 0 {r.yaw_rad:.6f}\n"
        for r in rels))
    tp = tmp / "t.csv"
    tp.write_text("t,x,y,yaw\n" + "".join(f"{t:.6f},{p.x:.6f},{p.y:.6f},{p.yaw:.7f}\n"
                                          for t, p in zip(STAMPS, poses, strict=True)))
    return tp, rp


def test_files_round_trip(tmp_path: Path) -> None:
    tp, rp = _write(tmp_path, _relations(PAIRS), TRUTH)
    assert len(read_relations(rp)) == len(PAIRS)
    assert read_trajectory(tp).shape == (len(TRUTH), 4)
    sc = score_trajectory(read_trajectory(tp), read_relations(rp))
    assert sc.trans_max_m < 1e-5


def test_cli_prints_the_figures_and_writes_json(tmp_path: Path) -> None:
    est = list(TRUTH)
    est[5] = TRUTH[5] @ Pose2D(0.0, 0.1, math.radians(2.0))
    tp, rp = _write(tmp_path, _relations([(2, 5), (0, 1)]), est)
    out, err = io.StringIO(), io.StringIO()
    code = map_main(["score", str(tp), str(rp), "--json", str(tmp_path / "s.json")], out, err)
    assert code == 0, err.getvalue()
    text = out.getvalue()
    assert "2 relations, 2 matched" in text
    assert "0.050 ± 0.050 m, max 0.100 m" in text
    assert "1.00 ± 1.00 deg, max 2.00 deg" in text
    data = json.loads((tmp_path / "s.json").read_text())
    assert data["matched"] == 2
    assert data["trans_max_m"] == pytest.approx(0.1, abs=1e-5)


@pytest.mark.parametrize(("traj_text", "rel_text", "needle"), [
    (None, "1 2 0 0 0 0 0 0\n", "no such trajectory file"),
    ("t,x,y,yaw\n1,0,0\n", "1 2 0 0 0 0 0 0\n", "4 comma-separated fields"),
    ("t,x,y,yaw\n1,0,zero,0\n", "1 2 0 0 0 0 0 0\n", "'zero', not a number"),
    ("time,x,y\n1,0,0,0\n", "1 2 0 0 0 0 0 0\n", "header must be 't,x,y,yaw'"),
    ("t,x,y,yaw\n", "1 2 0 0 0 0 0 0\n", "no poses"),
    ("t,x,y,yaw\n1,0,0,0\n", "1 2 0 0 0 0 0\n", "8 fields (t1 t2 x y z roll pitch yaw)"),
    ("t,x,y,yaw\n1,0,0,0\n", "1 2 0 0 0 0 0 nan\n", "not finite"),
    ("t,x,y,yaw\n1,0,0,0\n", "# nothing\n", "no relations"),
    ("t,x,y,yaw\n1,0,0,0\n", None, "no such relations file"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path: Path, traj_text: str | None,
                                              rel_text: str | None, needle: str) -> None:
    tp, rp = tmp_path / "t.csv", tmp_path / "r.txt"
    if traj_text is not None:
        tp.write_text(traj_text)
    if rel_text is not None:
        rp.write_text(rel_text)
    out, err = io.StringIO(), io.StringIO()
    assert map_main(["score", str(tp), str(rp)], out, err) == 2
    lines = err.getvalue().strip().splitlines()
    assert len(lines) == 1
    assert needle in lines[0]
    assert lines[0].startswith("curio map score: ")


def test_cli_bad_max_dt_and_no_match(tmp_path: Path) -> None:
    tp, rp = _write(tmp_path, _relations(PAIRS), TRUTH)
    out, err = io.StringIO(), io.StringIO()
    assert map_main(["score", str(tp), str(rp), "--max-dt", "-1"], out, err) == 2
    assert "--max-dt must be a positive" in err.getvalue()
    rp.write_text("5000 5001 0 0 0 0 0 0\n")
    out, err = io.StringIO(), io.StringIO()
    assert map_main(["score", str(tp), str(rp)], out, err) == 1
    assert "no relation matched" in err.getvalue()


def test_read_errors_name_the_line(tmp_path: Path) -> None:
    rp = tmp_path / "r.txt"
    rp.write_text("1 2 0 0 0 0 0 0\n1 2 0 0 0 0 0 x\n")
    with pytest.raises(RelationError, match=r"r.txt:2: relation: field 8 is 'x'"):
        read_relations(rp)
