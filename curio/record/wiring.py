"""Recorder wiring: ``build_recorder`` for the composition root.

Builds the :class:`~curio.record.recorder.Recorder` when ``record.enabled`` (MCAP files in
``<data_dir>/<record.directory>/``, or the one file ``record.file``) or ``foxglove.enabled``
(the live server, ``curio[foxglove]``), and registers it as the part ``recorder``. It is built
first, so its bus tap sees every message, the ones published while the other parts are built
included; its part closes last, after the rover has been stopped.

On a :class:`~curio.core.clock.SimClock` the queue waits for the writer instead of dropping
(simulated time stands still meanwhile): scenario recordings are complete.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from curio.core.bus import Bus
from curio.core.clock import Clock, SimClock
from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.core.parts import Part, Parts
from curio.core.topics import COSTMAP, LOCAL_COSTMAP
from curio.record.codec import Codec
from curio.record.mcap_sink import McapSink
from curio.record.queue import RecordQueue
from curio.record.recorder import Recorder, Sink
from curio.robot import RobotModel

__all__ = ["build_recorder", "recording_metadata", "recordings_directory"]

_LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING,
           "error": logging.ERROR}


def _curio_version() -> str:
    try:
        return version("curio")
    except PackageNotFoundError:  # pragma: no cover - a source tree
        return "unknown"


def recording_metadata(cfg: Config, clock: Clock, time_offset_s: float) -> dict[str, str]:
    """The ``curio`` metadata record: what ``curio replay`` needs to rebuild the run.

    ``config`` is the effective configuration (JSON), ``base_dir`` where its relative paths
    were resolved, ``start_s`` the clock's ``now()`` when the application was built (the
    replay's start), ``time_offset_s`` wall time minus ``now()`` (``repr``: exact).
    """
    return {
        "format": "curio-recording",
        "version": "1",
        "curio_version": _curio_version(),
        "config": json.dumps(cfg.model_dump(mode="json"), separators=(",", ":")),
        "base_dir": str(cfg.base_dir),
        "start_s": repr(clock.now()),
        "time_offset_s": repr(time_offset_s),
        "drivers_mode": cfg.drivers.mode,
        "clock": "sim" if isinstance(clock, SimClock) else "real",
    }


def _markers(cfg: Config) -> list[tuple[str, Pose2D]]:
    """The configured waypoints and tour stops, labelled, in ``map``."""
    out: list[tuple[str, Pose2D]] = []
    for path in cfg.bt.paths:
        for k, (x, y) in enumerate(path.points):
            yaw = math.radians(path.yaw_deg[k]) if path.yaw_deg else math.nan
            out.append((f"{path.name} {k + 1}", Pose2D(x, y, yaw)))
    for stop in cfg.bt.tour_stops:
        yaw = math.radians(stop.yaw_deg) if stop.yaw_deg is not None else math.nan
        out.append((stop.name, Pose2D(stop.x_m, stop.y_m, yaw)))
    return out


def recordings_directory(cfg: Config) -> Path | None:
    """Where the recorder writes its rotated files (None: off, or one ``record.file``)."""
    rc = cfg.record
    if not rc.enabled or rc.file:
        return None
    given = Path(rc.directory).expanduser()
    return given if given.is_absolute() else cfg.data_path(rc.directory)


def _mcap_sink(cfg: Config, clock: Clock, offset: float) -> McapSink:
    rc = cfg.record
    file = cfg.resolve(rc.file) if rc.file else None
    directory = recordings_directory(cfg) if file is None else None
    return McapSink(directory=directory, file=file, started_wall_s=clock.wall_time(),
                    metadata=recording_metadata(cfg, clock, offset),
                    max_file_bytes=int(rc.max_file_mb * 1e6), max_file_s=rc.max_file_s,
                    max_total_bytes=int(rc.max_total_mb * 1e6), compression=rc.compression)


def build_recorder(cfg: Config, bus: Bus, clock: Clock, parts: Parts, robot: RobotModel,
                   may_drive: Callable[[str], bool]) -> Recorder | None:
    """Construct the recorder (and the live Foxglove server) and register its part.

    Args:
        may_drive: whether a token presented by a Foxglove client may drive (the dashboard's
            roles: operator or admin).

    Raises:
        SetupError: ``foxglove.enabled`` without the ``curio[foxglove]`` extra installed.
    """
    rc = cfg.record
    if not (rc.enabled or cfg.foxglove.enabled):
        return None
    offset = clock.wall_time() - clock.now()
    codec = Codec(offset)
    sinks: list[Sink] = []
    if rc.enabled:
        sinks.append(_mcap_sink(cfg, clock, offset))
    if cfg.foxglove.enabled:
        from curio.record.foxglove_live import FoxgloveSink

        sinks.append(FoxgloveSink(cfg, bus, clock, may_drive))
    queue = RecordQueue(rc.queue_messages, int(rc.queue_mb * 1e6),
                        "wait" if isinstance(clock, SimClock) else "drop_oldest")
    statics = codec.statics(clock.now(), {"laser": robot.laser_in_base,
                                          "imu_link": robot.imu_in_base},
                            robot.footprint_points, _markers(cfg))
    recorder = Recorder(bus, clock, codec, sinks, queue=queue, flush_s=rc.flush_s,
                        grid_periods_s={COSTMAP.name: 1.0 / rc.costmap_rate_hz,
                                        LOCAL_COSTMAP.name: 1.0 / rc.local_costmap_rate_hz},
                        exclude=frozenset(rc.exclude),
                        log_level=_LEVELS[rc.log_level], statics=statics)
    parts.add(Part("recorder", run=recorder.run, close=recorder.close))
    return recorder
