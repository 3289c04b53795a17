"""MCAP files for the recorder: rotation by size and time, a disk budget, a flush policy.

Runs on the recorder's writer thread only (never on the loop).

* **Files.** In directory mode each run writes ``curio-<UTC start>-NNN.mcap`` (``NNN`` the part
  of the run) and starts a new part once a file reaches ``max_file_bytes`` or covers
  ``max_file_s``. The last message of every latched channel (the map, the pose, the plan, the
  fixed frames, ...) is written again at the start of each new part, so every file opens on its
  own in Foxglove. In single-file mode (``curio sim --record FILE``) there is one file.
* **Disk budget.** Before a new part is opened the oldest recordings of the directory (only
  files named like the recorder's own) are deleted until the directory, plus the new file's
  maximum, fits ``max_total_bytes``.
* **Flush.** :meth:`McapSink.flush` closes the chunk being built and hands it to the OS; the
  recorder calls it every ``record.flush_s``, so a crash or ``kill -9`` loses at most that much
  (the file then has no summary; :mod:`curio.record.reader` reads it all the same).
* Each file's header has the profile ``curio``; a metadata record ``curio`` holds what a replay
  needs (the configuration, the clock offsets, the part number), and ``curio.summary``, written
  when the file is closed, what it holds: ``messages``, ``start_ns`` and ``end_ns`` (wall
  clock), ``channels`` (JSON: topic → count) and ``events`` (JSON: the first
  ``MAX_SUMMARY_EVENTS`` of ``/events``, ``{t_ns, kind}``), so a list of recordings needs
  no scan.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal

from mcap.writer import CompressionType, IndexType, Writer

from curio.record.codec import ChannelSpec

__all__ = ["PROFILE", "RECORDING_NAME", "McapSink"]

log = logging.getLogger("curio.record")

PROFILE = "curio"
MAX_SUMMARY_EVENTS = 200
RECORDING_NAME = re.compile(r"curio-\d{8}T\d{6}Z(-r\d+)?-\d{3}\.mcap")
# Chunk, attachment and metadata indexes; no per-message index (16 bytes a message, about 13 %
# of a file): readers find messages by chunk, which Foxglove and the mcap readers do.
INDEXES = IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}


@dataclass
class _Latched:
    publish_ns: int
    seq: int
    data: bytes


class McapSink:
    """Writes channel payloads to MCAP files (see the module docstring).

    Args:
        directory: rotating files go here (directory mode), or None.
        file: the one file to write (single-file mode), or None.
        started_wall_s: UNIX time of the run's start (names the files).
        metadata: strings for the ``curio`` metadata record of every file.
    """

    def __init__(self, *, directory: Path | None, file: Path | None, started_wall_s: float,
                 metadata: dict[str, str], max_file_bytes: int, max_file_s: float,
                 max_total_bytes: int, compression: Literal["zstd", "lz4", "none"] = "zstd",
                 ) -> None:
        if (directory is None) == (file is None):
            raise ValueError("give a directory or a file")
        self.directory = directory
        self.file = file
        self.metadata = dict(metadata)
        self.max_file_bytes = max_file_bytes
        self.max_file_s = max_file_s
        self.max_total_bytes = max_total_bytes
        self.compression = _COMPRESSION[compression]
        stamp = datetime.fromtimestamp(started_wall_s, UTC).strftime("%Y%m%dT%H%M%SZ")
        self._run = f"curio-{stamp}"
        self._part = 0
        self._fh: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._file_start_ns: int | None = None
        self._latched: dict[ChannelSpec, _Latched] = {}
        self._counts: Counter[str] = Counter()
        self._span: list[int] = []
        self._events: list[dict[str, Any]] = []
        self.current: Path | None = None
        self.files: list[Path] = []
        self.deleted: list[Path] = []
        self.messages = 0
        self.bytes_closed = 0
        self._open_bytes_seen = 0

    # --- files ------------------------------------------------------------------------------
    def _next_path(self) -> Path:
        if self.file is not None:
            if self.files:  # reopening would truncate what was written before an error
                raise OSError(f"{self.file}: writing failed before; not starting it again")
            return self.file
        assert self.directory is not None
        if self._part == 0:
            run, n = self._run, 1
            while any(self.directory.glob(f"{run}-*.mcap")):
                n += 1
                run = f"{self._run}-r{n}"
            self._run = run
        self._part += 1
        return self.directory / f"{self._run}-{self._part:03d}.mcap"

    def _enforce_budget(self) -> None:
        """Delete the oldest recordings until the directory plus one new file fits."""
        if self.directory is None:
            return
        own = sorted((p for p in self.directory.glob("curio-*.mcap")
                      if RECORDING_NAME.fullmatch(p.name)),
                     key=lambda p: (p.stat().st_mtime, p.name))
        total = sum(p.stat().st_size for p in own)
        while own and total + self.max_file_bytes > self.max_total_bytes:
            oldest = own.pop(0)
            size = oldest.stat().st_size
            oldest.unlink(missing_ok=True)
            total -= size
            self.deleted.append(oldest)
            log.info("recording budget: deleted %s (%.1f MB)", oldest.name, size / 1e6)

    def _open(self, log_ns: int) -> None:
        path = self._next_path()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._enforce_budget()
        self._fh = path.open("wb")
        self._writer = Writer(self._fh, chunk_size=4 * 1024 * 1024, compression=self.compression,
                              index_types=INDEXES)
        self._writer.start(profile=PROFILE, library="curio")
        self._writer.add_metadata("curio", {**self.metadata, "part": str(self._part or 1)})
        self._channels.clear()
        self._schemas.clear()
        self._counts.clear()
        self._span = []
        self._events = []
        self._file_start_ns = log_ns
        self.current = path
        self.files.append(path)
        for spec, held in list(self._latched.items()):
            self._add(spec, log_ns, held.publish_ns, held.seq, held.data)

    def _close_file(self) -> None:
        if self._writer is not None:
            self._writer.add_metadata("curio.summary", {
                "messages": str(sum(self._counts.values())),
                "start_ns": str(self._span[0] if self._span else 0),
                "end_ns": str(self._span[-1] if self._span else 0),
                "channels": json.dumps(dict(sorted(self._counts.items()))),
                "events": json.dumps(self._events)})
            self._writer.finish()  # type: ignore[no-untyped-call]
        fh, self._fh = self._fh, None  # health (another thread) must not read a closing file
        if fh is not None:
            fh.close()
            if self.current is not None and self.current.exists():
                self.bytes_closed += self.current.stat().st_size
        self._writer = None

    def _channel_id(self, spec: ChannelSpec) -> int:
        assert self._writer is not None
        cid = self._channels.get(spec.topic)
        if cid is None:
            sid = self._schemas.get(spec.schema_name)
            if sid is None:
                sid = self._writer.register_schema(spec.schema_name, "jsonschema", spec.schema)
                self._schemas[spec.schema_name] = sid
            cid = self._writer.register_channel(spec.topic, "json", sid)
            self._channels[spec.topic] = cid
        return cid

    def _add(self, spec: ChannelSpec, log_ns: int, publish_ns: int, seq: int,
             data: bytes) -> None:
        assert self._writer is not None
        self._writer.add_message(self._channel_id(spec), log_time=log_ns, data=data,
                                 publish_time=publish_ns, sequence=seq & 0xFFFFFFFF)
        self.messages += 1
        self._counts[spec.topic] += 1
        if not self._span:
            self._span = [log_ns, log_ns]
        else:
            self._span[0] = min(self._span[0], log_ns)
            self._span[1] = max(self._span[1], log_ns)
        if spec.topic == "/events" and len(self._events) < MAX_SUMMARY_EVENTS:
            with contextlib.suppress(ValueError, KeyError, TypeError):
                self._events.append({"t_ns": log_ns, "kind": json.loads(data)["kind"]})

    # --- the sink interface -----------------------------------------------------------------
    def write(self, spec: ChannelSpec, log_ns: int, publish_ns: int, seq: int,
              data: bytes) -> None:
        """Add one message (opening or rotating files as needed).

        Raises:
            OSError: the file cannot be opened or written (disk full, permissions).
        """
        if self._writer is None:
            self._open(log_ns)
        elif self.file is None and self._due(log_ns):
            self._close_file()
            self._open(log_ns)
        self._add(spec, log_ns, publish_ns, seq, data)
        if spec.latched:
            self._latched[spec] = _Latched(publish_ns, seq, data)

    def _due(self, log_ns: int) -> bool:
        assert self._fh is not None and self._file_start_ns is not None
        return (self._fh.tell() >= self.max_file_bytes
                or log_ns - self._file_start_ns >= self.max_file_s * 1e9)

    def flush(self) -> None:
        """Write the chunk being built and hand everything to the OS."""
        if self._writer is not None:
            self._writer.flush()  # type: ignore[no-untyped-call]

    @property
    def bytes_written(self) -> int:
        """Bytes in the files written so far (the open one included). Safe to read from
        another thread than the writer's (health): a file the writer closes meanwhile counts
        as its last size seen (once the soak saw ``tell()`` on a file closed by a rotation
        crash the recorder part, and so the rover)."""
        fh = self._fh
        open_bytes = 0
        if fh is not None:
            try:
                open_bytes = self._open_bytes_seen = fh.tell()
            except (ValueError, OSError):  # closed by the writer thread just now
                open_bytes = self._open_bytes_seen
        return self.bytes_closed + open_bytes

    def close(self) -> None:
        """Finish the open file (summary and index) and close it."""
        self._close_file()

    def abandon(self) -> None:
        """Drop the open file after a write error (what was flushed stays readable)."""
        fh, self._fh, self._writer = self._fh, None, None
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()

    def describe(self) -> dict[str, Any]:
        """Counters for health."""
        return {"files": len(self.files), "bytes_written": self.bytes_written,
                "deleted_files": len(self.deleted)}
