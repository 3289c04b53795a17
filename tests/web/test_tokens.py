"""Named tokens: ``curio token`` creates, lists, revokes and rotates them in a 0600 file; an
older install's single token becomes the admin token; bad input is one line and exit 2."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from curio.cli import main
from curio.web.tokens import TokenError, TokenStore


def run(capsys: pytest.CaptureFixture[str], data: Path, *args: str) -> tuple[int, str, str]:
    code = main(["token", "--set", f'data_dir="{data}"', *args])
    out, err = capsys.readouterr()
    return code, out, err


def stored(data: Path) -> dict[str, dict[str, str]]:
    body = json.loads((data / "web_tokens.json").read_text())
    return {t["name"]: t for t in body["tokens"]}


def test_create_list_rotate_revoke(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "data"
    code, out, _ = run(capsys, data, "create", "Alice")
    assert code == 0 and "made the admin token 'admin' first" in out
    alice = stored(data)["Alice"]
    assert alice["role"] == "operator"
    assert f"dashboard link: http://127.0.0.1:8080/?token={alice['token']}" in out
    assert stat.S_IMODE(os.stat(data / "web_tokens.json").st_mode) == 0o600
    code, out, _ = run(capsys, data, "create", "lobby screen", "--role", "kiosk")
    assert code == 0 and stored(data)["lobby screen"]["role"] == "kiosk"
    code, out, _ = run(capsys, data, "list")
    assert code == 0 and alice["token"] not in out and f"…{alice['token'][-4:]}" in out
    assert [line.split()[:2] for line in out.splitlines()[2:]] == [
        ["admin", "admin"], ["Alice", "operator"], ["lobby", "screen"]]
    code, out, _ = run(capsys, data, "rotate", "alice")
    new = stored(data)["Alice"]
    assert code == 0 and new["token"] != alice["token"] and new["token"] in out
    code, out, _ = run(capsys, data, "revoke", "ALICE")
    assert code == 0 and "Alice" not in stored(data)


@pytest.mark.parametrize(("args", "message"), [
    (("create", "admin"), "a token named 'admin' exists already"),
    (("create", "a/b"), "token name 'a/b' is not allowed"),
    (("revoke", "nobody"), "there is no token named 'nobody'; tokens: admin"),
    (("rotate", "nobody"), "there is no token named 'nobody'"),
])
def test_mistakes_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          args: tuple[str, ...], message: str) -> None:
    code, _, err = run(capsys, tmp_path / "data", *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_bad_role_is_refused_by_the_parser(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        run(capsys, tmp_path / "data", "create", "x", "--role", "superuser")
    assert exc.value.code == 2


def test_the_single_token_of_an_older_install_becomes_admin(tmp_path: Path) -> None:
    legacy = tmp_path / "web_token"
    legacy.write_text("an-old-token-0123456789abcdef\n")
    store = TokenStore(tmp_path / "web_tokens.json", legacy)
    made = store.ensure_admin()
    assert made is not None and made.token == "an-old-token-0123456789abcdef"
    assert (made.name, made.role) == ("admin", "admin")
    assert not legacy.exists()
    assert store.identify("an-old-token-0123456789abcdef") == made
    assert TokenStore(tmp_path / "web_tokens.json").ensure_admin() is None  # only once


def test_a_corrupt_file_names_itself_and_the_server_keeps_its_tokens(tmp_path: Path) -> None:
    path = tmp_path / "web_tokens.json"
    store = TokenStore(path)
    admin = store.ensure_admin()
    assert admin is not None
    path.write_text("{not json")
    assert store.reload_if_changed() is False  # a running server keeps what it had
    assert store.identify(admin.token) == admin
    with pytest.raises(TokenError, match=str(path)):
        TokenStore(path)
