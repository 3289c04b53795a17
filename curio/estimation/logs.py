"""Every laser log ``curio map build`` reads, by file name: ROS bags and Curio recordings
(:mod:`curio.estimation.rosbag`), Curio run logs and CARMEN logs
(:mod:`curio.estimation.carmen`). All yield :class:`~curio.estimation.carmen.LogScan`."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from curio.estimation import carmen
from curio.estimation.carmen import LogScan
from curio.estimation.rosbag import read_bag

__all__ = ["BAG_SUFFIXES", "read_log"]

BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def read_log(path: Path | str, *options: Any) -> Iterator[LogScan]:
    """A ROS bag or Curio recording (``.bag``, ``.db3``, ``.mcap``, a rosbag2 directory), else
    what :func:`curio.estimation.carmen.read_log` reads (a run log or a CARMEN log); ``options``
    go to that reader (bags have none).

    Raises:
        LogError: an unreadable or malformed log (lazily, while iterating, for bags).
    """
    p = Path(path)
    if p.suffix.lower() in BAG_SUFFIXES or p.is_dir():
        return read_bag(p)
    return carmen.read_log(p, *options)
