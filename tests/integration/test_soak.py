"""``curio soak`` end to end for one hour of the building's clock, as CI runs it: the CLI runs
the orchestrator, the rover process (emulated drivers, simulated clock), three scripted
dashboard clients and a five-fault campaign — a ``kill -9`` with a damaged data file at the
restart, the lidar unplugged and replugged, the event loop blocked for 2 s, the rover carried
away while it stands, and a kidnap, which needs the rover driving: after the last scheduled
tour (``--start 20:00``) the soak starts a tour for it (a fault that waits for a drive no
longer holds up the others or goes uninjected) — then the test reads the JSON report's
verdicts. A kidnap counts as recovered only once the tree is found again (back at work).

The rover is parked between the faults, so the building's clock time-lapses and the hour is
~570 simulated seconds (~40 s of wall time on a loaded 2-core machine). The long soaks and
their figures are in docs/reliability.md.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from curio.core.config import REPO_ROOT

KINDS = ("corrupt_file", "lidar_unplug", "loop_stall", "kidnap", "kidnap_parked")


def _soak(tmp_path: Path) -> tuple[subprocess.CompletedProcess[str], dict[str, Any]]:
    report = tmp_path / "soak.json"
    proc = subprocess.run(
        [sys.executable, "-m", "curio", "soak", "--hours", "1", "--start", "20:00",
         "--clients", "3", "--visitors", "0", "--faults", "5", "--kinds", ",".join(KINDS),
         "--seed", "2",
         "--disk", "none", "--workdir", str(tmp_path / "work"), "--report", str(report),
         "--set", f'data_dir="{tmp_path / "data"}"'],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=240, check=False)
    assert report.exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc, json.loads(report.read_text(encoding="utf-8"))


def test_an_hour_of_soak_with_a_kill_9_and_a_kidnap_passes_every_check(tmp_path: Path) -> None:
    proc, rep = _soak(tmp_path)
    failed = [c for c in rep["checks"] if c["ok"] is False]
    assert proc.returncode == 0 and rep["success"] and not failed, (failed, proc.stdout[-2000:])
    names = {c["name"].split(" (")[0]: c for c in rep["checks"]}
    # the memory slope needs an hour after warm-up: said, not passed silently
    mem = next(c for n, c in names.items() if n.startswith("memory flat"))
    assert mem["ok"] is None and "not judged" in mem["detail"]
    assert all(c["ok"] is True for n, c in names.items() if not n.startswith("memory flat"))

    results = {r["kind"]: r for r in rep["faults"]["list"]}
    assert sorted(results) == sorted(KINDS)
    for kind, r in results.items():
        if kind == "kidnap" and r["outcome"] == "stopped_safely":
            # seed 2 carries the driving rover where the old place still fits middling: it
            # cannot tell that from furniture moved, stops and asks a person; the soak answers
            assert r["help_s"] is not None and any("help answered" in n for n in r["notes"]), r
        else:
            assert r["outcome"] == "recovered", (kind, r)
        assert r["detected_health_s"] is not None and r["detected_log_s"] is not None, r
    m = rep["metrics"]
    assert m["restarts"] == 1 and m["collisions"] == 0 and m["commands_lost"] == 0
    assert m["collisions_rover_at_fault"] == m["collisions_person_at_fault"] == 0
    assert m["faults_planned"] == m["faults_recovered"] + m["faults_stopped_safely"] == 5
    assert m["faults_recovered"] >= 4  # the rover back at work after the help answered

    (restart,) = rep["restarts"]
    assert restart["kind"] == "corrupt_file" and restart["unclean_reported"]
    assert restart["corruption"] is not None and restart["moved_m"] <= 0.05
    assert all(d["ok"] for d in restart["data_after"]), restart["data_after"]
    # every persisted file checked while the rover was dead and at the end
    assert [f["why"] for f in rep["files"]] == ["killed", "end"]
    assert all(c["ok"] for f in rep["files"] for c in f["checks"])
    assert rep["time"]["time_lapse_s"] > 600.0
    assert "PASSED" in proc.stdout and "[FAIL]" not in proc.stdout


def test_ctrl_c_ends_a_soak_early_with_a_report_of_what_ran(tmp_path: Path) -> None:
    """An engineer who stops a day-long soak after an hour gets its findings: the first Ctrl-C
    ends it as at its end (clients stop, unanswered commands asked about, the rover stopped
    cleanly) and writes a report that says it stopped early and fails for that reason only."""
    import os
    import signal

    from curio.core.clock import wall_perf_counter, wall_sleep

    report = tmp_path / "soak.json"
    work = tmp_path / "work"
    proc = subprocess.Popen(
        [sys.executable, "-m", "curio", "soak", "--hours", "24", "--clients", "3",
         "--faults", "0", "--seed", "5", "--disk", "none", "--workdir", str(work),
         "--report", str(report), "--set", f'data_dir="{tmp_path / "data"}"'],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    beats = work / "seed5" / "boot0.jsonl"
    try:
        deadline = wall_perf_counter() + 120.0
        while wall_perf_counter() < deadline:  # until the rover has run a little while
            if beats.exists() and beats.read_text(encoding="utf-8").count('"t":"beat"') >= 5:
                break
            wall_sleep(0.5)
        else:
            raise AssertionError("the rover never reported")
        os.kill(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, out[-3000:]
    rep = json.loads(report.read_text(encoding="utf-8"))
    assert rep["stopped_early"]["why"].startswith("SIGINT at "), rep["stopped_early"]
    assert 0.0 < rep["time"]["building_h"] < 24.0
    failed = [c["name"] for c in rep["checks"] if c["ok"] is False]
    assert failed == ["ran its whole time (24 building hours)"], rep["checks"]
    assert rep["metrics"]["commands_sent"] > 0 and rep["metrics"]["commands_lost"] == 0
    assert [f["why"] for f in rep["files"]] == ["end"]
    assert "stopped early (SIGINT at " in out and "FAILED" in out
    ends = [json.loads(line)["t"] for line in beats.read_text(encoding="utf-8").splitlines()
            if '"t":"stopped"' in line or '"t":"done"' in line]
    assert ends == ["stopped"], ends  # the rover was stopped cleanly, not killed
