"""The ``curio`` command's contract: exit codes and messages for bad arguments."""

from __future__ import annotations

import pytest

from curio.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sim", "nosuch"], "unknown scenario 'nosuch'; known scenarios:"),
        (["sim", "square", "--start", "1,2"], "--start takes 3 comma-separated numbers"),
        (["sim", "square", "--goal", "a,b"], "--goal takes numbers"),
        (["sim", "goto", "--goal", "1,nan"], "must be finite"),
        (["sim", "square", "--speed", "fast"], "--speed takes a number > 0 or 'max'"),
        (["sim", "square", "--speed", "-2"], "--speed takes a number > 0 or 'max'"),
        (["sim", "square", "--duration", "0"], "--duration takes simulated seconds > 0"),
        (["sim", "square", "--map", "/nonexistent.yaml"], "no such file"),
        (["sim", "square", "--set", "sim.sed=3"], "Did you mean 'seed'"),
        (["bench", "nosuch"], "unknown benchmark 'nosuch'; known:"),
        (["bench", "sim", "--pairs", "0"], "--pairs takes a whole number > 0"),
        (["sim", "crowd", "--visitors", "-1"], "--visitors takes a whole number 0..100"),
        (["soak", "--visitors", "101"], "--visitors takes a whole number 0..100, got 101"),
        (["bench", "crowd", "--set", "counts=5,x"], "counts= takes visitor counts 0..100"),
        (["bench", "crowd", "--set", "maps=atlantis"], "unknown map 'atlantis'"),
    ],
)
def test_bad_arguments_exit_2_with_a_message(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_argparse_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as excinfo:
        main(["sim"])
    assert excinfo.value.code == 2
    assert "scenario" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["map", "check", "emulate"])
def test_delegated_commands_have_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main([command, "--help"])
    except SystemExit as exc:  # argparse's own exit
        code = exc.code  # type: ignore[assignment]
    assert code == 0
    assert f"usage: curio {command}" in capsys.readouterr().out


def test_map_info_on_the_default_world(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["map", "info", "maps/curio_building.yaml"]) == 0
    out = capsys.readouterr().out
    assert "600 x 400 cells" in out and "0.05 m/cell" in out
