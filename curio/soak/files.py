"""The rover's persisted files, checked while it is dead (after every ``kill -9``) and damaged
on purpose (the ``corrupt_file`` faults).

:func:`check_files` reads every file the rover keeps in its data directory — tours, schedules,
paths, the named tokens, the IMU calibration, the last pose, the tour journal and the run
marker (JSON: parsed and version-checked), the SQLite event log (``PRAGMA integrity_check``,
no record lost since the previous check, no gap in the ids), the newest flight recording
(read to its last whole chunk) and the map — and compares them with what the soak knows must
be there: the tours and schedules it authored, the tokens it made, every path edit the rover
acknowledged to a client (:class:`~curio.soak.clients.PathEdits`). Leftover temporary files of
interrupted atomic writes are counted.

:func:`corrupt` truncates a file, fills it with garbage or empties it, as a bad SD card or a
person with an editor would.
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from curio.soak.clients import PathEdits

__all__ = ["Expected", "FileCheck", "check_files", "corrupt"]

FILES = {"tours": "tours.json", "schedules": "schedules.json", "paths": "paths.json"}


@dataclass
class Expected:
    """What the data directory must hold (filled in as the soak learns it)."""

    tours: list[tuple[int, str, int]] = field(default_factory=list)
    schedules: int = 0
    tokens: dict[str, str] = field(default_factory=dict)
    path_edits: list[PathEdits] = field(default_factory=list)
    events_count: int = 0
    events_max_id: int = 0


@dataclass
class FileCheck:
    """The verdict on one file."""

    name: str
    ok: bool
    detail: str = ""


def _json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"))


def _tours(data_dir: Path, exp: Expected) -> FileCheck:
    path = data_dir / FILES["tours"]
    try:
        data = _json(path)
        tours = [(int(t["id"]), str(t["name"]), len(t["stops"])) for t in data["tours"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return FileCheck("tours", False, f"{path.name}: {type(exc).__name__}: {exc}")
    if exp.tours and sorted(tours) != sorted(exp.tours):
        return FileCheck("tours", False, f"holds {tours}, expected {exp.tours}")
    if not exp.tours:
        exp.tours = tours
    return FileCheck("tours", True, f"{len(tours)} tours")


def _schedules(data_dir: Path, exp: Expected) -> FileCheck:
    path = data_dir / FILES["schedules"]
    try:
        n = len(_json(path)["schedules"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return FileCheck("schedules", False, f"{path.name}: {type(exc).__name__}: {exc}")
    if exp.schedules and n != exp.schedules:
        return FileCheck("schedules", False, f"holds {n} schedules, expected {exp.schedules}")
    exp.schedules = exp.schedules or n
    return FileCheck("schedules", True, f"{n} schedules")


def _paths(data_dir: Path, exp: Expected) -> FileCheck:
    path = data_dir / FILES["paths"]
    try:
        data = _json(path)
        paths = {int(p["id"]): [(round(float(w["x_m"]), 3), round(float(w["y_m"]), 3))
                                for w in p["waypoints"]] for p in data["paths"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return FileCheck("paths", False, f"{path.name}: {type(exc).__name__}: {exc}")
    if 0 not in paths:
        return FileCheck("paths", False, "path 0 (Home) is missing")
    lost = []
    for edits in exp.path_edits:
        if edits.path_id is None:
            continue
        have = paths.get(edits.path_id)
        allowed = [edits.acked] + ([edits.in_flight] if edits.in_flight is not None else [])
        if have not in allowed:
            lost.append(f"path {edits.path_id} ({edits.name}) holds {have}, acknowledged "
                        f"{edits.acked}")
    if lost:
        return FileCheck("paths", False, "; ".join(lost))
    return FileCheck("paths", True, f"{len(paths)} paths, "
                     f"{sum(e.edits for e in exp.path_edits)} acknowledged edits kept")


def _tokens(data_dir: Path, exp: Expected) -> FileCheck:
    path = data_dir / "web_tokens.json"
    try:
        entries = {str(t["name"]): str(t["token"]) for t in _json(path)["tokens"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return FileCheck("tokens", False, f"{path.name}: {type(exc).__name__}: {exc}")
    missing = [n for n, tok in exp.tokens.items() if entries.get(n) != tok]
    return FileCheck("tokens", not missing, f"missing or changed: {missing}" if missing
                     else f"{len(entries)} tokens")


def _small_json(data_dir: Path) -> list[FileCheck]:
    out = []
    for name in sorted(p.name for p in data_dir.glob("*.json")):
        if name in (*FILES.values(), "web_tokens.json"):
            continue
        try:
            _json(data_dir / name)
            out.append(FileCheck(name, True))
        except (OSError, ValueError) as exc:
            out.append(FileCheck(name, False, f"{type(exc).__name__}: {exc}"))
    return out


def _events(data_dir: Path, exp: Expected) -> FileCheck:
    path = data_dir / "events.sqlite3"
    if not path.exists():
        return FileCheck("events", False, "the event log is missing")
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            integrity = conn.execute("PRAGMA integrity_check").fetchone()[0]
            count, lo, hi = conn.execute("SELECT count(*), min(id), max(id) FROM events"
                                         ).fetchone()
        finally:
            conn.close()
    except sqlite3.Error as exc:
        return FileCheck("events", False, f"{type(exc).__name__}: {exc}")
    problems = []
    if integrity != "ok":
        problems.append(f"integrity_check: {integrity}")
    if count < exp.events_count or (hi or 0) < exp.events_max_id:
        problems.append(f"records lost: {count} (max id {hi}) after {exp.events_count} "
                        f"(max id {exp.events_max_id})")
    if count and hi - lo + 1 != count:
        problems.append(f"gaps in the ids: {count} records from {lo} to {hi}")
    exp.events_count, exp.events_max_id = count, hi or 0
    return FileCheck("events", not problems, "; ".join(problems) or f"{count} records")


def _recording(data_dir: Path) -> FileCheck:
    from curio.record.reader import open_recording

    files = sorted((data_dir / "recordings").glob("curio-*.mcap"),
                   key=lambda p: p.stat().st_mtime)
    if not files:
        return FileCheck("recording", True, "no recording")
    newest = files[-1]
    try:
        rec = open_recording(newest)
        n = sum(1 for _ in rec.messages())
    except Exception as exc:  # any failure to read is the verdict
        return FileCheck("recording", False, f"{newest.name}: {type(exc).__name__}: {exc}")
    return FileCheck("recording", True, f"{newest.name}: {n} messages, "
                     f"{'truncated' if getattr(rec, 'truncated', False) else 'complete'}")


def _map(map_yaml: Path) -> FileCheck:
    from curio.estimation.maps import load_map

    try:
        grid = load_map(map_yaml)
    except Exception as exc:  # the map must load
        return FileCheck("map", False, f"{type(exc).__name__}: {exc}")
    return FileCheck("map", True, f"{grid.data.shape[1]}x{grid.data.shape[0]}")


def check_files(data_dir: Path, exp: Expected, map_yaml: Path) -> list[FileCheck]:
    """Every persisted file (see the module docstring)."""
    checks = [_tours(data_dir, exp), _schedules(data_dir, exp), _paths(data_dir, exp),
              _tokens(data_dir, exp), _events(data_dir, exp), *_small_json(data_dir),
              _recording(data_dir), _map(map_yaml)]
    leftovers = [p.name for p in data_dir.glob(".*.json.*")]
    checks.append(FileCheck("temp_files", True, f"{len(leftovers)} left by interrupted "
                            "writes" if leftovers else "none"))
    return checks


def corrupt(data_dir: Path, which: str, how: str, rng: np.random.Generator) -> dict[str, Any]:
    """Damage ``which`` (``tours``, ``paths``, ``schedules``) by ``how`` (``truncate``,
    ``garbage``, ``empty``); return what was done."""
    path = data_dir / FILES[which]
    before = path.read_bytes() if path.exists() else b""
    if how == "empty":
        after = b""
    elif how == "truncate":
        after = before[: max(1, len(before) // 2)]
    else:
        junk = rng.integers(0, 256, size=max(16, len(before) // 8), dtype=np.uint8).tobytes()
        at = len(before) // 3
        after = before[:at] + junk + before[at + len(junk):]
    path.write_bytes(after)
    return {"file": path.name, "how": how, "bytes_before": len(before),
            "bytes_after": len(after)}
