"""The event log: an embedded SQLite database that outlives restarts and ``kill -9``.

Records are ``(id, wall_s, kind, source, detail)``: UNIX time in seconds, a dotted kind
(``tour.started``, ``operator.go_home``, ``fault``...), who caused it, and a JSON object.

* **Writes never block the loop.** :meth:`EventLog.append` puts the record on a queue and
  returns; a writer thread takes everything waiting (up to ``batch_rows``) and commits it in
  one transaction. The database is in WAL mode with ``synchronous=NORMAL``: a committed
  transaction survives the process being killed (``kill -9``); a power cut may lose the last
  ones, never corrupt the file. What is still queued when the process is killed (milliseconds
  of records) is lost. A write that fails (the disk is full) keeps its records in memory (up
  to ``max_retry_rows``) and tries again every ``RETRY_S``, so a disk that fills up for a while
  loses nothing; ``stats.failing`` says so meanwhile. :meth:`EventLog.append_committed`
  waits for its record's commit: the command journal writes operator commands and their
  answers ahead of carrying them out and of telling anyone (``curio/eventlog/commands.py``).
* **Bounded:** after every ``prune_every`` records the writer deletes records older than
  ``max_age_days`` before the newest one, and the oldest beyond ``max_rows``. Age is measured
  from the newest record, so no clock is read here.
* **Reads** (:meth:`query`, :meth:`count`, :meth:`export_csv`) open their own connection
  (WAL readers never wait for the writer). They block for the query's duration: call them
  through ``clock.offload`` from the loop.
"""

from __future__ import annotations

import csv
import datetime as dt
import json
import logging
import queue
import sqlite3
import threading
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO
from zoneinfo import ZoneInfo

from curio.core.errors import SetupError
from curio.core.jsonable import to_jsonable

__all__ = ["EventLog", "EventLogError", "LogQuery", "LogRecord"]

log = logging.getLogger("curio.eventlog")

SCHEMA_VERSION = 1
_SCHEMA = """
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    wall_s REAL NOT NULL,
    kind TEXT NOT NULL,
    source TEXT NOT NULL DEFAULT '',
    detail TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS events_wall ON events (wall_s);
CREATE INDEX IF NOT EXISTS events_kind ON events (kind, wall_s);
"""


class EventLogError(SetupError):
    """The event log database cannot be used (the message names the file and the problem)."""


@dataclass(frozen=True, slots=True)
class LogRecord:
    """One logged record."""

    id: int
    wall_s: float
    kind: str
    source: str
    detail: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"id": self.id, "wall_s": self.wall_s, "kind": self.kind, "source": self.source,
                "detail": self.detail}


@dataclass(frozen=True)
class LogQuery:
    """Filters of :meth:`EventLog.query`; every one is optional.

    Attributes:
        since_wall_s, until_wall_s: UNIX time range, seconds (``since <= t < until``).
        kinds: kinds to keep: exact (``tour.started``) or prefixes ending in ``.``
            (``tour.`` keeps every tour record).
        source: only records from this source (exact).
        text: only records whose kind or detail contains this text (case-insensitive).
        limit, offset: paging (limit at most 100 000).
        newest_first: order by time descending.
    """

    since_wall_s: float | None = None
    until_wall_s: float | None = None
    kinds: tuple[str, ...] = ()
    source: str | None = None
    text: str | None = None
    limit: int = 1000
    offset: int = 0
    newest_first: bool = False

    def where(self) -> tuple[str, list[Any]]:
        """The SQL ``WHERE`` clause and its parameters."""
        clauses: list[str] = []
        params: list[Any] = []
        if self.since_wall_s is not None:
            clauses.append("wall_s >= ?")
            params.append(self.since_wall_s)
        if self.until_wall_s is not None:
            clauses.append("wall_s < ?")
            params.append(self.until_wall_s)
        if self.kinds:
            ors = []
            for kind in self.kinds:
                if kind.endswith("."):
                    ors.append("substr(kind, 1, ?) = ?")
                    params += [len(kind), kind]
                else:
                    ors.append("kind = ?")
                    params.append(kind)
            clauses.append("(" + " OR ".join(ors) + ")")
        if self.source is not None:
            clauses.append("source = ?")
            params.append(self.source)
        if self.text:
            clauses.append("(instr(lower(kind), ?) > 0 OR instr(lower(detail), ?) > 0)")
            params += [self.text.lower(), self.text.lower()]
        return (" WHERE " + " AND ".join(clauses)) if clauses else "", params


@dataclass
class _Row:
    wall_s: float
    kind: str
    source: str
    detail: str


@dataclass
class WriterStats:
    """What the writer thread has done.

    Attributes:
        failing: the last write failed; ``retrying`` records wait to be written again.
        lost: records dropped because more than ``max_retry_rows`` waited.
    """

    written: int = 0
    batches: int = 0
    pruned: int = 0
    errors: int = 0
    last_error: str = ""
    queued: int = 0
    failing: bool = False
    retrying: int = 0
    lost: int = 0
    extra: dict[str, float] = field(default_factory=dict)


_STOP = object()
RETRY_S = 2.0  # while writes fail, they are tried again this often (wall seconds)
# append_committed waits at most this long (wall seconds): a commit takes milliseconds, even
# on an SD card; longer means the disk is in trouble, and a command must not wait for it.
COMMIT_WAIT_S = 0.5
WRITER_CACHE_KIB = 256  # the writer connection's page cache (SQLite's default: 2000 KiB)


class EventLog:
    """The SQLite event log (see the module docstring).

    Args:
        path: the database file (created with its folder).
        max_age_days: records this much older than the newest are deleted.
        max_rows: the oldest records beyond this many are deleted.
        batch_rows: most records per transaction.
        prune_every: records written between two prunes.
        readonly: only read (``curio report``): no writer, the file must exist.
        max_retry_rows: records kept in memory while writes fail (a full disk), written when
            they work again; older ones beyond are dropped and counted (``stats.lost``).

    Raises:
        EventLogError: the file is not an SQLite database or cannot be opened.
    """

    def __init__(self, path: Path | str, *, max_age_days: float = 400.0,
                 max_rows: int = 500_000, batch_rows: int = 500,
                 prune_every: int = 5000, readonly: bool = False,
                 max_retry_rows: int = 20_000) -> None:
        self.path = Path(path)
        self.max_age_s = max_age_days * 86400.0
        self.max_rows = max_rows
        self.batch_rows = batch_rows
        self.prune_every = prune_every
        self.stats = WriterStats()
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._since_prune = 0
        self.max_retry_rows = max_retry_rows
        self._retry: deque[_Row] = deque()
        self._thread = threading.Thread(target=self._writer, name="eventlog-writer",
                                        daemon=True)
        if readonly:
            if not self.path.is_file():
                raise EventLogError(f"there is no event log at {self.path} (Curio writes it "
                                    "while it runs, with eventlog.enabled = true)")
            self._read().close()
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        conn = self._connect()  # fail here, in the caller, on a bad file
        conn.close()
        self._thread.start()

    # --- connections ------------------------------------------------------------------------

    def _connect(self, readonly: bool = False) -> sqlite3.Connection:
        try:
            if readonly:
                conn = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=10.0)
            else:
                conn = sqlite3.connect(self.path, timeout=10.0)
                conn.execute("PRAGMA journal_mode=WAL")
                conn.execute("PRAGMA synchronous=NORMAL")
                # The writer appends: it needs the B-trees' right edges, not SQLite's default
                # 2 MB page cache, which it would fill over hours as the file grows (the
                # soak's slow RSS growth, docs/reliability.md).
                conn.execute(f"PRAGMA cache_size=-{WRITER_CACHE_KIB}")
                conn.executescript(_SCHEMA)
                version = conn.execute("PRAGMA user_version").fetchone()[0]
                if version > SCHEMA_VERSION:
                    conn.close()
                    raise EventLogError(
                        f"the event log {self.path} was written by a newer Curio (schema "
                        f"{version}; this one knows {SCHEMA_VERSION}); move it away")
                conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
            return conn
        except sqlite3.DatabaseError as exc:
            raise EventLogError(f"the event log {self.path} cannot be used ({exc}); move it "
                                "away and Curio starts a new one") from None

    # --- writing ----------------------------------------------------------------------------

    def append(self, kind: str, detail: Mapping[str, Any] | None = None, *, wall_s: float,
               source: str = "") -> None:
        """Queue one record (returns at once; the writer thread commits it)."""
        text = json.dumps(to_jsonable(dict(detail or {}), 6), separators=(",", ":"),
                          allow_nan=False, ensure_ascii=False)
        self._queue.put(_Row(float(wall_s), kind, source, text))
        self.stats.queued += 1

    def append_committed(self, kind: str, detail: Mapping[str, Any] | None = None, *,
                         wall_s: float, source: str = "",
                         timeout_s: float = COMMIT_WAIT_S) -> bool:
        """Queue one record and block until the writer thread has committed it (a write
        ahead: once this returns True the record survives ``kill -9``). Returns False at once
        while writes fail (a full disk: the record stays queued and is written when they work
        again) or with a stopped writer, and after ``timeout_s`` wall seconds otherwise. Call
        it through ``clock.offload`` from the loop."""
        self.append(kind, detail, wall_s=wall_s, source=source)
        if self.stats.failing:
            return False
        return self._committed(timeout_s)

    def _committed(self, timeout_s: float) -> bool:
        """Block until everything queued so far is committed; False on timeout, while writes
        fail, or with a stopped writer."""
        if not self._thread.is_alive():
            return False
        done = threading.Event()
        self._queue.put(done)
        return done.wait(timeout_s)

    def pending(self) -> int:
        """Records (and requests) queued for the writer thread, not yet taken."""
        return self._queue.qsize()

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Block until everything queued so far is committed; False on timeout or a stopped
        writer (for tests, reports and shutdown — not for the loop's hot path)."""
        return self._committed(timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Commit what is queued and stop the writer."""
        if self._thread.is_alive():
            self._queue.put(_STOP)
            self._thread.join(timeout_s)

    def _take(self) -> list[Any]:
        """The next batch: blocks for the first item, or for ``RETRY_S`` while records wait
        to be written again (then an empty batch, so they are retried)."""
        try:
            first = self._queue.get(timeout=RETRY_S) if self._retry else self._queue.get()
        except queue.Empty:
            return []
        batch = [first]
        while len(batch) < self.batch_rows:
            try:
                batch.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return batch

    def _writer(self) -> None:
        conn = self._connect()
        try:
            while True:
                batch = self._take()
                rows = [b for b in batch if isinstance(b, _Row)]
                if rows or self._retry:
                    self._write(conn, rows)
                for item in batch:
                    if isinstance(item, threading.Event) and not self._retry:
                        item.set()  # committed (while writes fail, flush() times out)
                if any(item is _STOP for item in batch):
                    return
        finally:
            self.stats.lost += len(self._retry)
            conn.close()

    def _write(self, conn: sqlite3.Connection, rows: list[_Row]) -> None:
        """Commit the records waiting for a retry, then ``rows``, in one transaction; when it
        fails (disk full, I/O error) keep them all for the next try, up to
        ``max_retry_rows`` (the oldest beyond are dropped and counted as lost)."""
        todo = [*self._retry, *rows]
        try:
            with conn:
                conn.executemany(
                    "INSERT INTO events (wall_s, kind, source, detail) VALUES (?, ?, ?, ?)",
                    [(r.wall_s, r.kind, r.source, r.detail) for r in todo])
        except sqlite3.Error as exc:
            self.stats.errors += 1
            self.stats.last_error = str(exc)
            if not self.stats.failing:
                log.error("event log write failed (records kept and retried every %.0f s): "
                          "%s", RETRY_S, exc)
            self.stats.failing = True
            self._retry.extend(rows)
            while len(self._retry) > self.max_retry_rows:
                self._retry.popleft()
                self.stats.lost += 1
            self.stats.retrying = len(self._retry)
            return
        if self.stats.failing:
            log.info("event log writes work again (%d records written late, %d lost)",
                     len(self._retry), self.stats.lost)
        self._retry.clear()
        self.stats.failing = False
        self.stats.retrying = 0
        self.stats.written += len(todo)
        self.stats.batches += 1
        self._since_prune += len(todo)
        if self._since_prune >= self.prune_every:
            self._since_prune = 0
            try:
                self.stats.pruned += self._prune(conn)
            except sqlite3.Error as exc:
                log.warning("event log pruning failed (retried later): %s", exc)

    def _prune(self, conn: sqlite3.Connection) -> int:
        with conn:
            newest = conn.execute("SELECT max(wall_s) FROM events").fetchone()[0]
            removed = 0
            if newest is not None:
                removed += conn.execute("DELETE FROM events WHERE wall_s < ?",
                                        (newest - self.max_age_s,)).rowcount
            removed += conn.execute(
                "DELETE FROM events WHERE id <= (SELECT id FROM events ORDER BY id DESC "
                "LIMIT 1 OFFSET ?)", (self.max_rows,)).rowcount
        return removed

    def prune_now(self) -> None:
        """Ask the writer to prune at its next batch (tests, ``curio`` maintenance)."""
        self._since_prune = self.prune_every

    # --- reading ----------------------------------------------------------------------------

    def _read(self) -> sqlite3.Connection:
        conn = self._connect(readonly=True)
        try:
            conn.execute("SELECT count(*) FROM events LIMIT 1")
        except sqlite3.DatabaseError as exc:
            conn.close()
            raise EventLogError(f"the event log {self.path} cannot be read ({exc})") from None
        return conn

    def query(self, q: LogQuery | None = None) -> list[LogRecord]:
        """Records matching ``q``, oldest first unless ``q.newest_first``."""
        return list(self.iter_query(q))

    def iter_query(self, q: LogQuery | None = None) -> Iterator[LogRecord]:
        """Like :meth:`query`, one record at a time (exports of a whole year)."""
        q = q or LogQuery()
        where, params = q.where()
        order = "DESC" if q.newest_first else "ASC"
        sql = (f"SELECT id, wall_s, kind, source, detail FROM events{where} "
               f"ORDER BY wall_s {order}, id {order} LIMIT ? OFFSET ?")
        conn = self._read()
        try:
            for rid, wall_s, kind, source, detail in conn.execute(
                    sql, [*params, max(0, min(q.limit, 100_000)), max(0, q.offset)]):
                yield LogRecord(rid, wall_s, kind, source, json.loads(detail))
        finally:
            conn.close()

    def count(self, q: LogQuery | None = None) -> int:
        """How many records match ``q`` (limit and offset ignored)."""
        where, params = (q or LogQuery()).where()
        conn = self._read()
        try:
            return int(conn.execute(f"SELECT count(*) FROM events{where}",
                                    params).fetchone()[0])
        finally:
            conn.close()

    def export_csv(self, out: TextIO, q: LogQuery | None = None,
                   timezone: ZoneInfo | None = None) -> int:
        """Write the records matching ``q`` as CSV (``id, time, wall_s, kind, source,
        detail``; time in ISO 8601 in ``timezone``, UTC by default); return how many."""
        tz = timezone or ZoneInfo("UTC")
        writer = csv.writer(out)
        writer.writerow(["id", "time", "wall_s", "kind", "source", "detail"])
        n = 0
        for rec in self.iter_query(q):
            when = dt.datetime.fromtimestamp(rec.wall_s, tz).isoformat(timespec="milliseconds")
            writer.writerow([rec.id, when, f"{rec.wall_s:.3f}", rec.kind, rec.source,
                             json.dumps(rec.detail, ensure_ascii=False, sort_keys=True)])
            n += 1
        return n
