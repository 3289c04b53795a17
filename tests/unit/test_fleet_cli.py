"""``curio fleet``: bad arguments are one line and exit 2; keys are managed from the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest

from curio.cli import main


@pytest.mark.parametrize("argv, says", [
    (["fleet", "sim", "--rovers", "0"], "--rovers takes 1 to 6"),
    (["fleet", "sim", "--scenario", "nope"], "unknown fleet scenario 'nope'"),
    (["fleet", "sim", "--speed", "fast"], "--speed takes a number"),
    (["fleet", "sim", "--transport", "carrier-pigeon"], "--transport takes zenoh or memory"),
    (["fleet", "sim", "--scenario", "doorway", "--rovers", "3", "--transport", "memory"],
     "the doorway scenario has 2 rovers"),
    (["fleet", "key", "create"], "needs a NAME"),
    (["fleet", "key", "create", "x", "--role", "root"], "role 'root'"),
    (["fleet", "send", "r/1", "estop"], "rover name 'r/1' is not allowed"),
    (["fleet", "send", "r1", "dance"], "ACTION must be one of"),
    (["fleet", "run", "--set", "fleet.manager.port=99999"], "fleet.manager.port"),
])
def test_mistakes_are_one_line_and_exit_2(argv: list[str], says: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    code = main([*argv, "--set", f'data_dir="{tmp_path}"'])
    err = capsys.readouterr().err
    assert code == 2 and says in err and "Traceback" not in err
    assert len(err.strip().splitlines()) <= 3


def test_keys_are_created_listed_and_revoked(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    data = ["--set", f'data_dir="{tmp_path}"']
    assert main(["fleet", "key", "create", "fleet", "--role", "operator", *data]) == 0
    secret = next(line.split()[1] for line in capsys.readouterr().out.splitlines()
                  if line.startswith("secret:"))
    assert main(["fleet", "key", "create", "lobby", "--role", "kiosk", "--secret", "z" * 20,
                 *data]) == 0
    capsys.readouterr()
    assert main(["fleet", "key", "list", *data]) == 0
    listing = capsys.readouterr().out
    assert "fleet\toperator\t…" + secret[-4:] in listing and "lobby\tkiosk" in listing
    assert secret not in listing
    assert main(["fleet", "key", "revoke", "lobby", *data]) == 0
    assert main(["fleet", "key", "revoke", "lobby", *data]) == 2


def test_without_the_extra_a_fleet_rover_stops_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "zenoh", None)  # as if curio[fleet] were not installed
    code = main(["run", "--set", "fleet.enabled=true", "--set", "web.enabled=false",
                 "--set", f'data_dir="{tmp_path}"'])
    err = capsys.readouterr().err
    assert code == 2 and "pip install 'curio[fleet]'" in err and "Traceback" not in err
