"""``curio map`` as a user meets it: honest summaries, hints, bad lines, quiet output."""

from __future__ import annotations

import logging
import re
import subprocess
import sys
from pathlib import Path

from curio.commands.map import main as map_main
from curio.core.config import REPO_ROOT


def run_map(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "curio", "map", *args], capture_output=True,
                          text=True, timeout=300, cwd=REPO_ROOT)


def percentages(text: str) -> dict[str, float]:
    return {k: float(v) for k, v in re.findall(r"(free|occupied|unknown)\s+([\d.]+) %", text)}


def head_of(log: Path, tmp_path: Path, lines: int) -> Path:
    head = tmp_path / "head.clf"
    with open(log) as fh:
        head.write_text("".join(next(fh) for _ in range(lines)))
    return head


def test_the_build_summary_adds_up_and_matches_map_info(tmp_path: Path,
                                                        mit_csail_log: Path) -> None:
    log = head_of(mit_csail_log, tmp_path, 400)
    built = run_map("build", "--log", str(log), "--out", str(tmp_path / "m.yaml"))
    assert built.returncode == 0, built.stderr
    info = run_map("info", str(tmp_path / "m.yaml"))
    summary, shown = percentages(built.stdout), percentages(info.stdout)
    assert summary == shown
    assert abs(sum(summary.values()) - 100.0) <= 0.15
    # The progress bar only goes to a terminal; stderr here is a pipe.
    assert "[#" not in built.stderr and "%" not in built.stderr


def test_a_rover_that_did_not_move_gets_a_hint(tmp_path: Path) -> None:
    run = tmp_path / "still.jsonl"
    lines = ['{"type": "header", "format": "curio-run", "version": 1, '
             '"laser_pose": [0.15, 0.0, 0.0]}']
    for k in range(30):
        t = 0.1 * k
        lines.append(f'{{"type": "odom", "t": {t}, "x": 0.0, "y": 0.0, "yaw": 0.0}}')
        ranges = ", ".join("3.0" for _ in range(360))
        lines.append(f'{{"type": "scan", "t": {t}, "angle_min": -3.14159, '
                     f'"angle_increment": 0.017453, "range_min": 0.15, "range_max": 12.0, '
                     f'"ranges": [{ranges}]}}')
    run.write_text("\n".join(lines) + "\n")
    built = run_map("build", "--log", str(run), "--out", str(tmp_path / "s.yaml"))
    assert built.returncode == 0, built.stderr
    assert "the rover moved at most 0.00 m" in built.stdout
    assert "drive the rover around" in built.stdout


def test_a_bad_line_names_itself_and_can_be_skipped(tmp_path: Path,
                                                    mit_csail_log: Path) -> None:
    log = head_of(mit_csail_log, tmp_path, 130)
    with open(log, "a") as fh:
        fh.write("FLASER 180 1.0 2.0\n")  # a truncated last line
    stopped = run_map("build", "--log", str(log), "--out", str(tmp_path / "a.yaml"))
    assert stopped.returncode == 2
    assert f"{log}:131: FLASER" in stopped.stderr and "--skip-bad-lines" in stopped.stderr
    assert "Traceback" not in stopped.stderr
    skipped = run_map("build", "--log", str(log), "--out", str(tmp_path / "b.yaml"),
                      "--skip-bad-lines")
    assert skipped.returncode == 0, skipped.stderr
    assert "skipped 1 bad line" in skipped.stdout and ":131:" in skipped.stdout
    assert (tmp_path / "b.yaml").is_file()


def test_no_action_says_which_there_are() -> None:
    result = run_map()
    assert result.returncode == 2
    assert "build, info, score, convert or record" in result.stderr


def test_quiet_silences_the_log_messages(tmp_path: Path, mit_csail_log: Path) -> None:
    log = head_of(mit_csail_log, tmp_path, 60)
    logger = logging.getLogger("curio")
    before = logger.level
    try:
        logger.setLevel(logging.INFO)
        code = map_main(["build", "--log", str(log), "--out", str(tmp_path / "q.yaml"),
                         "--quiet"])
        assert code == 0
        assert logger.getEffectiveLevel() == logging.WARNING
    finally:
        logger.setLevel(before)
