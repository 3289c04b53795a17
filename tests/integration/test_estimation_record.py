"""``curio map record`` on the simulator, then ``curio map build`` from the recording."""

from __future__ import annotations

import io
from pathlib import Path

from curio.commands.map import main as map_main
from curio.core.config import REPO_ROOT
from curio.estimation.carmen import read_run
from curio.estimation.maps import load_map


def test_record_then_build(tmp_path: Path) -> None:
    run = tmp_path / "run.jsonl"
    out, err = io.StringIO(), io.StringIO()
    code = map_main(["record", "--out", str(run), "--duration", "3",
                     "--config", str(REPO_ROOT / "config.toml"),
                     "--set", "web.enabled=false", "--set", f'data_dir="{tmp_path / "data"}"'],
                    out, err)
    assert code == 0, err.getvalue()
    assert "recorded" in out.getvalue()
    scans = list(read_run(run))
    assert 25 <= len(scans) <= 31  # 10 Hz for 3 s
    assert '"type": "truth"' in run.read_text()
    code = map_main(["build", "--log", str(run), "--out", str(tmp_path / "m.yaml"), "--quiet"],
                    io.StringIO(), err)
    assert code == 0, err.getvalue()
    assert load_map(tmp_path / "m.yaml").occupied_mask().sum() > 100


def test_record_needs_a_duration_in_sim_mode(tmp_path: Path) -> None:
    err = io.StringIO()
    code = map_main(["record", "--out", str(tmp_path / "r.jsonl"),
                     "--config", str(REPO_ROOT / "config.toml")], io.StringIO(), err)
    assert code == 2 and "--duration" in err.getvalue()
