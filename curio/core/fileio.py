"""Atomic file writes: a crash or power loss leaves either the old file or the new one.

Files get the mode a plain ``open()`` would give them (``0o666`` less the process umask), so a
map made by an administrator can be read by the ``curio`` service user; only secrets (the
dashboard tokens) are written ``private`` (``0o600``).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_text", "modified_ns",
           "read_json"]


def _umask() -> int:
    """The process umask, read without changing it (Linux), else by setting it back."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: Path | str, data: bytes, *, private: bool = False) -> None:
    """Write ``data`` to ``path`` through a temporary file, fsync and rename.

    Args:
        path: the file to (re)place.
        data: its new content.
        private: owner-only permissions (``0o600``, for secrets) instead of the umask's.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        if not private:
            os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
        dir_fd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path | str, text: str, *, private: bool = False) -> None:
    """Write UTF-8 ``text`` atomically (``private``: owner-only permissions)."""
    atomic_write_bytes(path, text.encode("utf-8"), private=private)


def atomic_write_json(path: Path | str, obj: Any) -> None:
    """Write ``obj`` as indented JSON atomically."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def read_json(path: Path | str) -> Any:
    """The JSON value in ``path``, or None when there is no such file.

    Raises:
        OSError: the file cannot be read; ValueError: it is not JSON.
    """
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None


def modified_ns(path: Path | str) -> int | None:
    """The file's modification time (ns), or None when it cannot be seen."""
    try:
        return Path(path).stat().st_mtime_ns
    except OSError:
        return None
