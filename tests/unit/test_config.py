"""Configuration: defaults, overrides, and clear errors for every kind of bad input."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from curio.cli import main
from curio.core.config import REPO_ROOT, ConfigError, dump_config, load_config


def test_shipped_config_runs_the_simulator() -> None:
    cfg = load_config(REPO_ROOT / "config.toml")
    assert cfg.drivers.mode == "sim"
    assert cfg.web.port == 8080 and cfg.web.host == "127.0.0.1"
    assert cfg.resolve(cfg.sim.world).is_file()
    assert cfg.robot.wheel_radius_multiplier == pytest.approx(1.04)


def test_set_overrides_parse_toml_values() -> None:
    cfg = load_config(None, [
        "drivers.mode=emulated",
        "nav.controller.max_speed_mps=0.25",
        "robot.footprint=[[0.3,0.3],[0.3,-0.3],[-0.3,-0.3],[-0.3,0.3]]",
        "bt.speak=false",
    ])
    assert cfg.drivers.mode == "emulated"
    assert cfg.nav.controller.max_speed_mps == 0.25
    assert cfg.robot.footprint[0] == (0.3, 0.3)
    assert cfg.bt.speak is False


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("drivers.mod=real", r"unknown config key 'drivers.mod'.*Did you mean 'mode'"),
        ("nav.controler.max_speed_mps=1", r"Did you mean 'controller'"),
        ("drivers.mode=warp", r"drivers.mode = 'warp'.*'sim', 'emulated' or 'real'"),
        ("nav.controller.max_speed_mps=abc", r"max_speed_mps = 'abc'.*valid number"),
        ("robot.wheel_radius_m=-1", r"robot.wheel_radius_m = -1.*greater than 0"),
        ("drivers.imu.address=0x30", r"0x28 \(40\) or 0x29 \(41\)"),
        ("robot.footprint=[[0,0],[1,1]]", r"at least 3 points"),
        ("drivers=1", r"'drivers' is a section"),
        ("novalue", r"KEY=VALUE"),
    ],
)
def test_bad_overrides_name_key_value_and_what_is_allowed(override: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        load_config(None, [override])


def test_unknown_key_in_file_is_reported_with_suggestion(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[nav.safety]\nmax_sped_mps = 0.2\n")
    with pytest.raises(ConfigError, match=r"nav.safety.max_sped_mps.*Did you mean 'max_speed_mps'"):
        load_config(path)


def test_unreadable_and_invalid_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot\nname = 1\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)
    with pytest.raises(ConfigError, match="directory"):
        load_config(tmp_path)
    if os.geteuid() != 0:  # root can read anything
        locked = tmp_path / "locked.toml"
        locked.write_text("")
        locked.chmod(0)
        with pytest.raises(ConfigError, match="permission"):
            load_config(locked)


def test_relative_paths_resolve_against_the_config_file(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "c.toml"
    path.parent.mkdir()
    path.write_text('data_dir = "state"\n[sim]\nworld = "w.yaml"\n')
    cfg = load_config(path)
    assert cfg.resolve(cfg.sim.world) == path.parent / "w.yaml"
    assert cfg.data_path("x.json") == path.parent / "state" / "x.json"
    assert (path.parent / "state").is_dir()


def test_dump_round_trips(tmp_path: Path) -> None:
    cfg = load_config(None, ["nav.controller.max_speed_mps=0.2", "drivers.mode=real"])
    text = dump_config(cfg)
    path = tmp_path / "dumped.toml"
    path.write_text(text.replace('"none"', '""'))
    again = load_config(path)
    assert again.nav.controller.max_speed_mps == 0.2
    assert again.drivers.mode == "real"
    assert again.bt.paths == cfg.bt.paths


def test_cli_exits_2_on_config_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "show", "--set", "drivers.mod=real"]) == 2
    err = capsys.readouterr().err
    assert "Did you mean 'mode'" in err
    assert main(["config", "show", "--set", "drivers.mode=real"]) == 0
    assert 'mode = "real"' in capsys.readouterr().out
