"""``curio pose``: relocalise a running rover, or set its pose, from the command line.

    curio pose relocalise [--url URL] [--token TOKEN] [--config PATH] [--set KEY=VALUE]...
    curio pose set X,Y,YAW [--std-xy M] [--std-yaw RAD] [--url URL] [--token TOKEN] ...

Both call the running rover's REST API (``POST /api/relocalise``, ``POST /api/pose``; see
``curio/web/unattended_api.py``), the same calls as the dashboard's buttons. The URL defaults
to the dashboard's address from the configuration (``web.host``, ``web.port``), the token to
the one ``curio run`` keeps in ``<data_dir>/web_token``. X, Y in metres and YAW in radians, in
``map``.

Exit codes: 0 accepted; 2 on bad arguments, no rover answering, or a refusal (the rover's
sentence is printed).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import urllib.error
import urllib.request
from typing import Any

from curio.core.config import ConfigError, load_config

__all__ = ["main", "post"]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="curio pose", description="Relocalise a running rover or "
                                 "set its pose on the map.")
    sub = ap.add_subparsers(dest="action", required=True)
    rel = sub.add_parser("relocalise", help="forget the pose and search the whole map")
    put = sub.add_parser("set", help="set the pose on the map: X,Y,YAW (m, m, rad)")
    put.add_argument("pose", help="X,Y,YAW in map (m, m, rad)")
    put.add_argument("--std-xy", type=float, default=0.25, help="position spread, m")
    put.add_argument("--std-yaw", type=float, default=0.2, help="heading spread, rad")
    for p in (rel, put):
        p.add_argument("--url", help="the dashboard's URL (default: from the config)")
        p.add_argument("--token", help="the control token (default: <data_dir>/web_token)")
        p.add_argument("--config", help="config file (default: ./config.toml or the shipped)")
        p.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="KEY=VALUE", help="config override (repeatable)")
    return ap


def _target(args: argparse.Namespace) -> tuple[str, str]:
    cfg = load_config(args.config, args.overrides)
    host = "127.0.0.1" if cfg.web.host in ("0.0.0.0", "", "::") else cfg.web.host
    url = (args.url or f"http://{host}:{cfg.web.port}").rstrip("/")
    token = args.token
    if token is None:
        path = cfg.resolve(cfg.data_dir) / cfg.web.token_file
        token = path.read_text(encoding="utf-8").strip() if path.is_file() else ""
    return url, token


def post(url: str, token: str, path: str, body: dict[str, Any],
         timeout_s: float = 5.0) -> tuple[int, dict[str, Any]]:
    """POST ``body`` as JSON to ``url + path`` with the token; the status and the JSON answer.

    Raises:
        OSError: nothing answers at ``url``.
    """
    req = urllib.request.Request(
        f"{url}{path}", data=json.dumps(body).encode("utf-8"), method="POST",
        headers={"Content-Type": "application/json", "Authorization": f"Bearer {token}"})
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            return resp.status, json.loads(resp.read() or b"{}")
    except urllib.error.HTTPError as exc:
        try:
            return exc.code, json.loads(exc.read() or b"{}")
        except ValueError:
            return exc.code, {"error": exc.reason}


def _pose(text: str) -> tuple[float, float, float]:
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"the pose takes X,Y,YAW (m, m, rad), got '{text}'") from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError(f"the pose must be finite numbers, got '{text}'")
    return x, y, yaw


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        url, token = _target(args)
        if args.action == "relocalise":
            path, body = "/api/relocalise", {}
        else:
            x, y, yaw = _pose(args.pose)
            path, body = "/api/pose", {"x_m": x, "y_m": y, "yaw_rad": yaw,
                                       "std_xy_m": args.std_xy, "std_yaw_rad": args.std_yaw}
        status, answer = post(url, token, path, body)
    except (ConfigError, ValueError) as exc:
        print(f"curio pose: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"curio pose: error: no rover answers at {url} ({exc}); is `curio run` running "
              "there?", file=sys.stderr)
        return 2
    if status // 100 != 2:
        print(f"curio pose: refused ({status}): {answer.get('error', answer)}", file=sys.stderr)
        return 2
    print(answer.get("message") or json.dumps(answer))
    return 0
