"""A recorded tour read back with the ``mcap`` reader, and replayed: ``curio sim tour
--record``, ``curio replay``."""

from __future__ import annotations

import asyncio
import io
import json
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from curio.cli import main as cli_main
from curio.commands import replay
from curio.core.config import REPO_ROOT, load_config
from curio.core.topics import ALL_TOPICS, MAP_TO_ODOM, ODOM
from curio.record.codec import primary_channel
from curio.scenarios import get_scenario
from curio.scenarios.base import ScenarioArgs, run_scenario

pytestmark = pytest.mark.slow

FOXGLOVE = {"/scan": "foxglove.LaserScan", "/pose": "foxglove.PoseInFrame",
            "/tf": "foxglove.FrameTransform", "/tf_static": "foxglove.FrameTransform",
            "/map": "foxglove.Grid", "/costmap": "foxglove.Grid",
            "/local_costmap": "foxglove.Grid", "/plan": "foxglove.PosesInFrame",
            "/local_plan": "foxglove.PosesInFrame", "/obstacles": "foxglove.SceneUpdate",
            "/scene": "foxglove.SceneUpdate"}
CURIO = {"/odom": "curio.Odometry", "/wheel_odom": "curio.Odometry", "/imu": "curio.Imu",
         "/wheels": "curio.WheelEncoders", "/cmd_vel": "curio.Twist",
         "/cmd_vel_nav": "curio.Twist", "/servo_cmd": "curio.ServoCommand",
         "/events": "curio.Event", "/tree": "curio.TreeSnapshot", "/health": "curio.DriverHealth",
         "/goal": "curio.NavGoal", "/localization": "curio.LocalizationStatus",
         "/battery": "curio.BatteryState", "/ground_truth": "curio.Odometry",
         "/status": "curio.StatusText", "/estop": "curio.EStop", "/blocked": "curio.BlockedState"}


@dataclass
class Tour:
    path: Path
    report: dict[str, Any]
    published: dict[str, int]
    dropped: Counter[str]
    skipped: Counter[str]
    seen: Counter[str]


@pytest.fixture(scope="module")
def tour(tmp_path_factory: pytest.TempPathFactory) -> Tour:
    tmp = tmp_path_factory.mktemp("tour")
    cfg = load_config(REPO_ROOT / "config.toml", [f'data_dir="{tmp / "data"}"'])
    path = tmp / "tour.mcap"
    apps: list[Any] = []

    async def keep(app: Any) -> None:
        apps.append(app)

    report = asyncio.run(run_scenario(get_scenario("tour"), cfg, ScenarioArgs(record=path),
                                      on_app=keep))
    assert report["success"], report["failure"]
    app = apps[0]
    rec = app.recorder
    return Tour(path, report, {k: v.published for k, v in app.bus.stats().items()},
                rec.queue.dropped, rec.skipped, rec.seen)


def test_every_channel_is_there_with_its_schema_and_every_message(tour: Tour) -> None:
    counts: Counter[str] = Counter()
    last: dict[str, int] = {}
    backwards: defaultdict[str, int] = defaultdict(int)
    with tour.path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert reader.get_header().profile == "curio"
        for schema, channel, msg in reader.iter_messages():
            assert channel.message_encoding == "json" and schema is not None
            assert schema.encoding == "jsonschema"
            expected = FOXGLOVE.get(channel.topic) or CURIO.get(channel.topic)
            if expected is not None:
                assert schema.name == expected, channel.topic
            json.loads(msg.data)
            counts[channel.topic] += 1
            if msg.log_time < last.get(channel.topic, 0):
                backwards[channel.topic] += 1
            last[channel.topic] = msg.log_time
    assert summary is not None and summary.statistics is not None
    assert not backwards, f"log times go backwards on {dict(backwards)}"
    assert set(FOXGLOVE) | set(CURIO) <= set(counts), set(FOXGLOVE) | set(CURIO) - set(counts)
    for topic in ALL_TOPICS:
        name = topic.name
        assert tour.seen[name] == tour.published[name], name  # the tap saw every message
        kept = tour.published[name] - tour.dropped[name] - tour.skipped[name]
        if primary_channel(name) == name:
            assert counts[name] == kept, name
    tf = sum(tour.published[t.name] - tour.dropped[t.name] for t in (ODOM, MAP_TO_ODOM))
    assert counts["/tf"] == tf
    assert counts["/tf_static"] == 2 and counts["/scene"] == 1 and counts["/goal"] == 7
    assert tour.skipped["/local_costmap"] > 0  # thinned to record.local_costmap_rate_hz


def test_replay_reproduces_the_recorded_poses(tour: Tour, tmp_path: Path) -> None:
    out, err = io.StringIO(), io.StringIO()
    code = replay.main([str(tour.path), "--report", str(tmp_path / "r.json")], out, err)
    assert code == 0, out.getvalue() + err.getvalue()
    rep = json.loads((tmp_path / "r.json").read_text())
    pose = rep["pose"]
    assert pose["recorded"] == pose["replayed"] > 1000
    assert pose["max_error_m"] < 0.001 and pose["over_tolerance"] == 0
    assert rep["plan"]["max_hausdorff_m"] < 0.001
    assert rep["cmd_vel"]["max_linear_diff_mps"] < 1e-5
    assert rep["inputs"]["/scan"] == tour.published["/scan"]
    assert rep["inputs"]["/goal"] == 7 and not rep["diverged"]
    assert "reproduced" in out.getvalue()


def test_replay_reports_where_a_changed_localisation_parameter_diverges(tour: Tour) -> None:
    out = io.StringIO()
    code = replay.main([str(tour.path), "--set", "localization.update_min_d_m=0.15"], out,
                       io.StringIO())
    text = out.getvalue()
    assert code == 1, text
    assert "DIVERGED" in text and "pose:" in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("pose:") and "over" in ln)
    assert "first at" in line


def test_replay_of_a_window_starts_from_the_recorded_pose(tour: Tour, tmp_path: Path) -> None:
    out = io.StringIO()
    code = replay.main([str(tour.path), "--from", "20", "--to", "30", "--report",
                        str(tmp_path / "w.json")], out, io.StringIO())
    assert code in (0, 1), out.getvalue()
    rep = json.loads((tmp_path / "w.json").read_text())
    assert rep["seeded_from"] is not None and rep["replayed_s"] == pytest.approx(10.0, abs=0.1)
    assert rep["pose"]["recorded"] > 100
    # Seeded with the recorded pose, the replay follows the recorded run (the localiser takes
    # the seed at its first scan update, 0.1 s in: a few poses differ before).
    assert rep["pose"]["rms_error_m"] < 0.15
    assert rep["truth_rmse_m"]["replayed"] < 0.15


@pytest.mark.parametrize(("argv", "message"), [
    (["replay", "/nonexistent.mcap"], "no such file"),
    (["replay", str(REPO_ROOT / "config.toml")], "not an MCAP file"),
    (["replay", "x.mcap", "--from", "-1"], "--from takes seconds >= 0"),
    (["replay", "x.mcap", "--speed", "fast"], "--speed takes a number"),
    (["sim", "square", "--record", "/tmp"], "--record takes a file"),
])
def test_bad_arguments_are_one_line_and_exit_2(argv: list[str], message: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
