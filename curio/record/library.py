"""The recordings of a rover: a list with a summary each, and safe download paths.

The backend of the dashboard's recordings list (the page itself comes with the web layer's
restructuring): :func:`list_recordings` says, per file, when it started, how long it lasts,
how big it is and what happened (from ``/events``), newest first; :func:`resolve_download`
turns a name a client sent into a path inside the recordings directory, or refuses it.

A file closed properly carries its summary (``curio.summary``, read through the MCAP summary
index without decompressing anything); a file cut short by a crash is scanned instead and
marked ``complete = False``. This reads files: call it off the loop (``clock.offload``).
"""

from __future__ import annotations

import contextlib
import json
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from curio.core.errors import SetupError
from curio.record.reader import MAGIC, RecordingError, open_recording

__all__ = ["RecordingInfo", "list_recordings", "recording_info", "resolve_download",
           "summarize"]

# Event kinds worth a word in a one-line summary, in the order they are told.
NOTABLE = ("collision", "safety.estop", "help.requested", "nav.goal_aborted",
           "nav.goal_rejected", "nav.recovery", "nav.blocked", "driver.lidar_lost",
           "driver.imu_lost", "nav.goal_succeeded", "path.finished")


@dataclass
class RecordingInfo:
    """One recording for the list.

    Attributes:
        name: the file name (what :func:`resolve_download` takes back).
        start_s: UNIX time of its first message (0 when empty).
        duration_s: from its first to its last message, seconds.
        size_bytes: on disk.
        messages: how many.
        complete: closed properly (False: cut short by a crash, or being written).
        events: event kind → count.
        summary: one line: what happened.
    """

    name: str
    start_s: float
    duration_s: float
    size_bytes: int
    messages: int
    complete: bool
    events: dict[str, int] = field(default_factory=dict)
    summary: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {"name": self.name, "start_s": self.start_s, "duration_s": self.duration_s,
                "size_bytes": self.size_bytes, "messages": self.messages,
                "complete": self.complete, "events": self.events, "summary": self.summary}


def summarize(events: Counter[str]) -> str:
    """A one-line account of the notable events (``2 collision, 7 nav.waypoint_reached``)."""
    parts = [f"{events[k]} {k}" for k in NOTABLE if events.get(k)]
    return ", ".join(parts) if parts else "no notable events"


def _complete(path: Path) -> bool:
    with path.open("rb") as fh:
        fh.seek(0, 2)
        if fh.tell() < 2 * len(MAGIC):
            return False
        fh.seek(-len(MAGIC), 2)
        return fh.read() == MAGIC


def _from_summary(path: Path) -> RecordingInfo | None:
    with path.open("rb") as fh:
        try:
            meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
        except (McapError, ValueError, OSError):
            return None
    summ = meta.get("curio.summary")
    if summ is None:
        return None
    start, end = int(summ["start_ns"]), int(summ["end_ns"])
    events = Counter(e["kind"] for e in json.loads(summ.get("events", "[]")))
    return RecordingInfo(path.name, start / 1e9, (end - start) / 1e9, path.stat().st_size,
                         int(summ["messages"]), True, dict(events), summarize(events))


def _from_scan(path: Path) -> RecordingInfo:
    rec = open_recording(path)
    count, first, last = 0, 0, 0
    events: Counter[str] = Counter()
    for msg in rec.messages():
        count += 1
        first = msg.log_ns if count == 1 else min(first, msg.log_ns)
        last = max(last, msg.log_ns)
        if msg.channel == "/events":
            with contextlib.suppress(ValueError, KeyError, TypeError):
                events[json.loads(msg.data)["kind"]] += 1
    return RecordingInfo(path.name, first / 1e9, (last - first) / 1e9, path.stat().st_size,
                         count, False, dict(events), summarize(events))


def _from_chunks(path: Path) -> RecordingInfo:
    """An unfinished file without decompressing it: its span from the chunks' headers (what
    the recorder has flushed so far)."""
    open_recording(path)  # a clear error for what is not a recording
    start = end = None
    with path.open("rb") as fh:
        records = StreamReader(fh, emit_chunks=True, record_size_limit=1 << 30).records
        with contextlib.suppress(McapError, struct.error, ValueError, EOFError):
            for rec in records:
                if isinstance(rec, Chunk) and rec.message_end_time:
                    start = rec.message_start_time if start is None else \
                        min(start, rec.message_start_time)
                    end = rec.message_end_time if end is None else max(end, rec.message_end_time)
    size = path.stat().st_size
    if start is None or end is None:
        return RecordingInfo(path.name, 0.0, 0.0, size, 0, False, {}, "no messages yet")
    return RecordingInfo(path.name, start / 1e9, (end - start) / 1e9, size, 0, False, {},
                         "not read through (still being written or cut short)")


def recording_info(path: Path, scan: bool = True) -> RecordingInfo:
    """One recording's summary: from its summary record, or for a file without one (being
    written, or cut short by a crash) a scan of it all (``scan``) or of its start only.

    Raises:
        RecordingError, OSError: the file cannot be read as a recording.
    """
    info = _from_summary(path) if _complete(path) else None
    if info is not None:
        return info
    return _from_scan(path) if scan else _from_chunks(path)


def list_recordings(directory: Path, scan: bool = True) -> list[RecordingInfo]:
    """Every recording in ``directory`` (``*.mcap``), newest first; unreadable files are left
    out (they are not Curio's). ``scan=False`` reads only the start of unfinished files (the
    one being written may be tens of megabytes)."""
    if not directory.is_dir():
        return []
    out: list[RecordingInfo] = []
    for path in directory.glob("*.mcap"):
        try:
            out.append(recording_info(path, scan))
        except (RecordingError, OSError):
            continue
    out.sort(key=lambda r: (r.start_s, r.name), reverse=True)
    return out


def resolve_download(directory: Path, name: str) -> Path:
    """The path of the recording ``name`` inside ``directory``, for a download.

    Only a plain ``.mcap`` file name of a file directly in the directory is accepted: no
    separators, no ``..``, no hidden files, no symbolic link leading out of the directory.

    Raises:
        SetupError: the name is not acceptable or names no recording (say which).
    """
    if not name or name != Path(name).name or name.startswith(".") or "\\" in name:
        raise SetupError(f"recording name {name!r} is not a plain file name like "
                         "curio-20250101T120000Z-001.mcap")
    if not name.endswith(".mcap"):
        raise SetupError(f"recording name {name!r} must end in .mcap")
    root = directory.resolve()
    path = (root / name).resolve()
    if path.parent != root or not path.is_file():
        raise SetupError(f"no recording named {name!r} in {directory}")
    return path
