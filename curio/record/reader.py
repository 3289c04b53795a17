"""Reading recordings back: Curio's MCAP files, complete or cut short by a crash.

The records are read in file order with ``mcap``'s stream reader, so a file that lost its end
(``kill -9``, power loss: no summary, maybe half a chunk) is read up to its last whole chunk and
flagged ``truncated``. The ``curio`` metadata record at the start says how the run was
configured (:func:`curio.record.wiring.recording_metadata`); ``curio.summary`` at the end (when
the file was closed properly) counts what is inside.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from curio.core.errors import SetupError

__all__ = ["RecordedMessage", "Recording", "RecordingError", "open_recording"]

MAGIC = b"\x89MCAP0\r\n"
_READ_ERRORS = (McapError, struct.error, ValueError, EOFError, OSError)


class RecordingError(SetupError):
    """A recording that cannot be read (missing, not MCAP), with the path and the reason."""


@dataclass(frozen=True, slots=True)
class RecordedMessage:
    """One recorded message.

    Attributes:
        channel: the channel's topic (``/scan``).
        schema: the schema's name (``foxglove.LaserScan``, ``curio.Imu``).
        log_ns: wall-clock nanoseconds (what Foxglove shows).
        publish_ns: the recording clock's ``now()`` in nanoseconds (what a replay uses).
        seq: the publish order (low 32 bits).
        data: the payload (JSON bytes).
    """

    channel: str
    schema: str
    log_ns: int
    publish_ns: int
    seq: int
    data: bytes


@dataclass
class Recording:
    """An opened recording: its header, metadata and a way to stream its messages."""

    path: Path
    profile: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False

    @property
    def curio(self) -> dict[str, str]:
        """The ``curio`` metadata record (empty for another program's MCAP)."""
        return self.metadata.get("curio", {})

    def config_data(self) -> dict[str, Any] | None:
        """The recorded configuration as plain data, or None."""
        text = self.curio.get("config")
        return json.loads(text) if text else None

    def messages(self) -> Iterator[RecordedMessage]:
        """Every message in file order; stops quietly at a truncated end (``truncated``)."""
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, int]] = {}
        with self.path.open("rb") as fh:
            records = StreamReader(fh, record_size_limit=1 << 30).records
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    return
                except _READ_ERRORS:
                    self.truncated = True
                    return
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, rec.schema_id)
                elif isinstance(rec, Message):
                    topic, sid = channels.get(rec.channel_id, ("?", 0))
                    yield RecordedMessage(topic, schemas.get(sid, ""), rec.log_time,
                                          rec.publish_time, rec.sequence, rec.data)
                elif isinstance(rec, Metadata):
                    self.metadata[rec.name] = dict(rec.metadata)


def _read_head(rec: Recording) -> None:
    """Fill in the profile and the metadata that precede the first message."""
    with rec.path.open("rb") as fh:
        records = StreamReader(fh, record_size_limit=1 << 30).records
        try:
            for item in records:
                if isinstance(item, Header):
                    rec.profile = item.profile
                elif isinstance(item, Metadata):
                    rec.metadata[item.name] = dict(item.metadata)
                elif isinstance(item, Message):
                    return
        except _READ_ERRORS:
            rec.truncated = True


def open_recording(path: Path | str) -> Recording:
    """Open an MCAP recording (its messages are streamed by :meth:`Recording.messages`).

    Raises:
        RecordingError: the file is missing, unreadable or not an MCAP file.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            magic = fh.read(len(MAGIC))
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{p}: a directory, not an MCAP file") from None
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read it ({exc.strerror})") from None
    if magic != MAGIC:
        raise RecordingError(f"{p}: not an MCAP file (it does not start with the MCAP magic)")
    rec = Recording(p)
    _read_head(rec)
    return rec
