"""A data filesystem that can really fill up, for the disk-full faults.

The rover's data directory lives on a size-limited **tmpfs** mounted by the orchestrator
(``mount -t tmpfs -o size=N``): when the campaign fills it (a ballast file), every write —
SQLite's WAL, the MCAP writer, atomic renames — gets a real ``ENOSPC`` from the kernel, and
removing the ballast gives the space back. Mounting needs root (``CAP_SYS_ADMIN``); without it
the soak runs on an ordinary directory and leaves the disk-full faults out of its campaign
(the report says so). The tmpfs is unmounted at the end (and its content copied out first
when the soak keeps its files).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

__all__ = ["DataDisk"]


class DataDisk:
    """The soak's data filesystem under ``root``.

    Args:
        root: the mount point (created).
        size_mb: the tmpfs size.
        want: ``auto`` (tmpfs when possible), ``tmpfs`` (required) or ``none``.
    """

    def __init__(self, root: Path, size_mb: int, want: str = "auto") -> None:
        self.root = root
        self.size_mb = size_mb
        self.want = want
        self.method = "none"
        self.reason = ""

    @property
    def ballast(self) -> Path | None:
        """The file that fills the disk (None without a size-limited filesystem)."""
        return self.root / "ballast" if self.method == "tmpfs" else None

    def mount(self) -> None:
        """Mount the tmpfs (or explain why not)."""
        self.root.mkdir(parents=True, exist_ok=True)
        if self.want == "none":
            self.reason = "disabled (--disk none)"
            return
        if not hasattr(os, "geteuid") or os.geteuid() != 0:
            self.reason = "mounting a size-limited tmpfs needs root"
        else:
            result = subprocess.run(
                ["mount", "-t", "tmpfs", "-o", f"size={self.size_mb}m,mode=0755", "tmpfs",
                 str(self.root)], capture_output=True, text=True, check=False)
            if result.returncode == 0:
                self.method = "tmpfs"
                return
            self.reason = f"mount failed: {result.stderr.strip() or result.returncode}"
        if self.want == "tmpfs":
            raise RuntimeError(f"--disk tmpfs: {self.reason}")

    def free_mb(self) -> float:
        """Free space on the data filesystem, MB."""
        st = os.statvfs(self.root)
        return st.f_bavail * st.f_frsize / 1e6

    def unmount(self, keep_copy: Path | None = None) -> None:
        """Copy the content to ``keep_copy`` (if given), then unmount."""
        if self.method != "tmpfs":
            return
        if keep_copy is not None:
            with contextlib.suppress(OSError):
                ballast = self.ballast
                if ballast is not None:
                    ballast.unlink(missing_ok=True)
                shutil.copytree(self.root, keep_copy, dirs_exist_ok=True, symlinks=True)
        subprocess.run(["umount", "-l", str(self.root)], capture_output=True, check=False)
        self.method = "none"
