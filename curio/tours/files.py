"""Versioned JSON data files: load with migration, save atomically with a ``.bak`` copy.

A data file is an object with ``"version": N``. Loading migrates a file written by an older
Curio step by step (``migrations[n]`` turns version ``n`` into ``n + 1``) and refuses one
written by a newer Curio. Saving writes the new content through a temporary file and a rename
(:func:`curio.core.fileio.atomic_write_text`: a crash leaves the old file or the new one), then
the same to ``<name>.bak``: two copies of the last save. A file that cannot be used (a damaged
SD card, a bad hand edit) is replaced by its backup when that one can be used
(:meth:`VersionedFile.load_recovering`: the damaged file is kept as ``<name>.corrupt-N`` and
:attr:`VersionedFile.restored` says so); otherwise :class:`DataFileError` names the file and
the problem, and the file is left exactly as it is, so nothing is lost. The first save after a
migration keeps the older version's file as ``<name>.v<N>.bak``.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_bytes, atomic_write_text

__all__ = ["DataFileError", "VersionedFile"]

log = logging.getLogger("curio.tours.files")

Migration = Callable[[dict[str, Any]], dict[str, Any]]
T = TypeVar("T")


def _problem(exc: DataFileError) -> str:
    """The problem part of a :meth:`VersionedFile.error` message."""
    text = str(exc)
    start = text.find("cannot be used: ")
    end = text.find("; it was left")
    return text[start + 16:end] if start >= 0 and end > start else text


def _move_aside(path: Path) -> Path | None:
    """Rename ``path`` to the first free ``<name>.corrupt-N``; None when that fails."""
    for n in range(1, 1000):
        aside = path.with_name(f"{path.name}.corrupt-{n}")
        if not aside.exists():
            try:
                path.rename(aside)
            except OSError:
                return None
            return aside
    return None


class DataFileError(SetupError):
    """A data file (tours, schedules) that cannot be used; the message names file and problem."""


@dataclass
class VersionedFile:
    """One versioned JSON file.

    Attributes:
        path: the file.
        kind: what it holds, for messages (``tours``, ``schedules``).
        version: the version this Curio writes.
        migrations: ``{n: fn}``, each turning a version-``n`` object into version ``n + 1``.
    """

    path: Path
    kind: str
    version: int
    migrations: Mapping[int, Migration] = field(default_factory=dict)
    restored: str | None = field(default=None, init=False)
    migrated_from: int | None = field(default=None, init=False)

    @property
    def backup(self) -> Path:
        """The second copy of the last save (``<name>.bak``)."""
        return self.path.with_name(self.path.name + ".bak")

    def error(self, problem: str) -> DataFileError:
        """The error for an unusable file: the file, the problem, what was kept."""
        hint = (f" Its backup {self.backup} cannot be used either: fix one of them."
                if self.backup.exists() else " Fix the file or move it away.")
        return DataFileError(f"the {self.kind} file {self.path} cannot be used: {problem}; it "
                             f"was left as it is.{hint}")

    def load(self) -> dict[str, Any] | None:
        """The file's content migrated to :attr:`version`, or None if there is no file.

        Raises:
            DataFileError: unreadable, not JSON, no version, a newer version.
        """
        return self._load_path(self.path)

    def _load_path(self, path: Path) -> dict[str, Any] | None:
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError) as exc:
            raise self.error(f"it cannot be read ({exc})") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise self.error(f"it is not valid JSON (line {exc.lineno} column {exc.colno}: "
                             f"{exc.msg})") from None
        if not isinstance(data, dict):
            raise self.error(f"it holds {type(data).__name__}, not a JSON object")
        found = data.get("version")
        if isinstance(found, bool) or not isinstance(found, int) or found < 1:
            raise self.error(f"it has no version number (\"version\": {found!r})")
        if found > self.version:
            raise self.error(f"it was written by a newer Curio (version {found}; this one "
                             f"reads versions up to {self.version})")
        if found < self.version:
            self.migrated_from = found
        while found < self.version:
            step = self.migrations.get(found)
            if step is None:
                raise self.error(f"version {found} files can no longer be read")
            try:
                data = step(data)
            except (KeyError, TypeError, ValueError) as exc:
                raise self.error(f"migrating it from version {found} failed ({exc})") from None
            found += 1
            data["version"] = found
        return dict(data)

    def load_recovering(self, parse: Callable[[dict[str, Any]], T]) -> T | None:
        """Load the file and ``parse`` it (``parse`` raises :meth:`error` for bad content);
        None when there is no file. A file that cannot be used while its backup can is moved
        aside (``<name>.corrupt-N``), the backup is copied in its place and used, and
        :attr:`restored` says what happened (for the event log and ``/health``).

        Raises:
            DataFileError: the file cannot be used and neither can its backup.
        """
        try:
            data = self.load()
            return None if data is None else parse(data)
        except DataFileError as damaged:
            try:
                backup = self._load_path(self.backup)
                parsed = parse(backup) if backup is not None else None
            except DataFileError:
                parsed = None
            if parsed is None:
                raise damaged from None
            aside = _move_aside(self.path)
            atomic_write_bytes(self.path, self.backup.read_bytes())
            self.restored = (f"the {self.kind} file {self.path.name} could not be used "
                             f"({_problem(damaged)}); its backup {self.backup.name} was put in "
                             f"its place" + (f" and the damaged file kept as {aside.name}"
                                             if aside is not None else ""))
            return parsed

    def save(self, body: dict[str, Any]) -> None:
        """Write ``body`` (``version`` is set here) to the file, then the same to its backup
        (a second copy: whichever one gets damaged, the other has the last save). The first
        save after a migration keeps the older version's file as ``<name>.v<N>.bak``."""
        if self.migrated_from is not None:
            original = self.path.with_name(f"{self.path.name}.v{self.migrated_from}.bak")
            with contextlib.suppress(FileNotFoundError):
                atomic_write_bytes(original, self.path.read_bytes())
            self.migrated_from = None
        text = json.dumps({**body, "version": self.version}, indent=2, ensure_ascii=False) + "\n"
        atomic_write_text(self.path, text)
        try:
            atomic_write_text(self.backup, text)
        except OSError as exc:  # the save is done; only its second copy is behind
            log.warning("could not update the backup %s: %s", self.backup, exc)
