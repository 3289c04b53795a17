"""``curio token``: the dashboard's named tokens (who may do what on the dashboard).

    curio token list                             [--config PATH] [--set KEY=VALUE]...
    curio token create NAME [--role ROLE]        (ROLE: operator (default), admin, kiosk)
    curio token revoke NAME
    curio token rotate NAME                      (a new secret; the old one stops working)

Tokens live in ``<data_dir>/<web.tokens_file>`` (mode 0600; :mod:`curio.web.tokens`). A new or
rotated token is printed once, with the dashboard link that carries it; ``list`` shows only
each token's last four characters. A running rover notices the change within a second and
closes the pages of a revoked or rotated token. The first command also makes the admin token
``admin`` (or migrates the single token of an older install), like the first ``curio run``.

Exit codes: 0 done, 2 bad arguments or a token that cannot be found, made or read (one line).
"""

from __future__ import annotations

import argparse
import socket
import sys

from curio.core.config import Config, ConfigError, load_config
from curio.web.tokens import ROLES, TokenEntry, TokenError, TokenStore

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="curio token",
        description="Create, list, revoke and rotate the dashboard's named tokens. Roles: "
                    "operator (drives, sends goals and paths, e-stop), admin (also releases "
                    "anybody's e-stop), kiosk (starts and stops tours only). No token: view only.")
    ap.add_argument("--config", help="config file (default: ./config.toml or the shipped one)")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="KEY=VALUE", help="config override (repeatable)")
    sub = ap.add_subparsers(dest="action", required=True, metavar="ACTION")
    sub.add_parser("list", help="list the tokens (names, roles, last four characters)")
    create = sub.add_parser("create", help="make a token and print it once")
    create.add_argument("name", help="who uses it (shown to every page as who did what)")
    create.add_argument("--role", default="operator", choices=ROLES,
                        help="what it may do (default: operator)")
    for name, text in (("revoke", "delete a token (its pages are disconnected)"),
                       ("rotate", "give a token a new secret (the old one stops working)")):
        sub.add_parser(name, help=text).add_argument("name", help="the token's name")
    return ap


def _link(cfg: Config, entry: TokenEntry) -> str:
    host = cfg.web.host
    if host in ("0.0.0.0", "::", ""):
        host = socket.gethostname()
    elif ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{cfg.web.port}/?token={entry.token}"


def _run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config, args.overrides)
    store = TokenStore(cfg.data_path(cfg.web.tokens_file), cfg.data_path(cfg.web.token_file))
    made = store.ensure_admin()
    if made is not None and args.action != "list":
        print("(made the admin token 'admin' first; 'curio token list' shows it)")
    if args.action == "list":
        entries = store.entries()
        print(f"tokens in {store.path}:")
        width = max(4, *(len(e.name) for e in entries))
        print(f"  {'NAME':<{width}}  {'ROLE':<8}  {'CREATED':<20}  ENDS WITH")
        for e in entries:
            print(f"  {e.name:<{width}}  {e.role:<8}  {e.created:<20}  …{e.token[-4:]}")
        return 0
    if args.action == "create":
        entry = store.create(args.name, args.role)
        print(f"token '{entry.name}' ({entry.role}): {entry.token}")
    elif args.action == "rotate":
        entry = store.rotate(args.name)
        print(f"token '{entry.name}' ({entry.role}) has a new secret: {entry.token}")
    else:
        entry = store.revoke(args.name)
        print(f"revoked token '{entry.name}' ({entry.role}); its pages are disconnected")
        if store.first_admin() is None:
            print("no admin token is left: make one with 'curio token create NAME --role admin'")
        return 0
    print(f"dashboard link: {_link(cfg, entry)}")
    print("keep it like a password: anyone with the link can do what the role allows")
    return 0


def main(argv: list[str]) -> int:
    """Entry point of ``curio token``; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        return _run(args)
    except (TokenError, ConfigError) as exc:
        print(f"curio token: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
