"""Versioned JSON data files: load with migration, save atomically with a ``.bak`` copy.

A data file is an object with ``"version": N``. Loading migrates a file written by an older
Curio step by step (``migrations[n]`` turns version ``n`` into ``n + 1``) and refuses one
written by a newer Curio. A file that cannot be used raises :class:`DataFileError` naming the
file and the problem; the file is left exactly as it is, so nothing is lost. Saving first
copies the current file (when it is readable JSON: the last good version) to ``<name>.bak``,
then writes the new content through a temporary file and a rename
(:func:`curio.core.fileio.atomic_write_text`): a crash leaves the old file or the new one.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_bytes, atomic_write_text

__all__ = ["DataFileError", "VersionedFile"]

Migration = Callable[[dict[str, Any]], dict[str, Any]]


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

    @property
    def backup(self) -> Path:
        """The previous good version (``<name>.bak``)."""
        return self.path.with_name(self.path.name + ".bak")

    def error(self, problem: str) -> DataFileError:
        """The error for an unusable file: the file, the problem, what was kept."""
        hint = (f" The previous good version is {self.backup}: fix the file or copy that one "
                "over it." if self.backup.exists() else " Fix the file or move it away.")
        return DataFileError(f"the {self.kind} file {self.path} cannot be used: {problem}; it "
                             f"was left as it is.{hint}")

    def load(self) -> dict[str, Any] | None:
        """The file's content migrated to :attr:`version`, or None if there is no file.

        Raises:
            DataFileError: unreadable, not JSON, no version, a newer version.
        """
        try:
            text = self.path.read_text(encoding="utf-8")
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

    def save(self, body: dict[str, Any]) -> None:
        """Write ``body`` (``version`` is set here), keeping the previous good file as .bak."""
        try:
            previous = self.path.read_bytes()
            json.loads(previous)
        except (OSError, ValueError):
            previous = b""
        if previous:
            atomic_write_bytes(self.backup, previous)
        atomic_write_text(self.path, json.dumps({**body, "version": self.version}, indent=2,
                                                ensure_ascii=False) + "\n")
