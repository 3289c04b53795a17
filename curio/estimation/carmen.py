"""Laser logs for offline mapping: standard CARMEN logs and Curio's own recorded runs.

Both readers yield :class:`LogScan` records — one laser scan with the odometry pose of the robot
at the scan's time — so the mapper does not care where the data came from.

**CARMEN** (``.clf``/``.log``, text, one message per line; ``#`` comments):

* ``FLASER n r1..rn x y theta odom_x odom_y odom_theta timestamp host logger_timestamp`` — a
  180° front laser, beams from −90° to +90°; ``x y theta`` is the laser's (corrected) pose,
  ``odom_*`` the robot's odometry. Curio uses the odometry and the offset between the two as
  the laser mounting (0 in most logs).
* ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r1..rn
  m rem1..remm laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv fwd_safety
  side_safety turn_axis timestamp host logger_timestamp`` (and ``ROBOTLASER2``).
* ``ODOM x y theta tv rv accel timestamp host logger_timestamp`` — odometry alone; used to
  fill in the robot's pose for laser lines that carry none (``RAWLASER``).
* Other messages (``PARAM``, ``SYNC``, ``TRUEPOS``, ``NMEA`` …) are skipped.

Ranges at or above the laser's maximum (81.91 m in SICK logs) mean "no return". A malformed line
raises :class:`LogError` with the file, the line number and what is wrong.

**Curio run** (``.jsonl``, JSON lines, written by :class:`RunRecorder`):

* first line ``{"type": "header", "format": "curio-run", "version": 1,
  "laser_pose": [x, y, yaw]}`` (``laser`` in ``base_link``, metres/radians);
* ``{"type": "odom", "t": s, "x": m, "y": m, "yaw": rad}`` — ``base_link`` in ``odom``;
* ``{"type": "scan", "t": s, "angle_min": rad, "angle_increment": rad, "range_min": m,
  "range_max": m, "ranges": [m | null, ...]}`` — ``null`` = no/invalid return;
* optionally ``{"type": "truth", "t": s, "x": m, "y": m, "yaw": rad}`` (simulator only).

Scans are paired with the odometry interpolated at their time.
"""

from __future__ import annotations

import bisect
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D

__all__ = ["LogError", "LogScan", "RunRecorder", "read_carmen", "read_log", "read_run"]

F64 = npt.NDArray[np.float64]


class LogError(ValueError):
    """A log that cannot be read, with the file, the line number and the problem."""


@dataclass(frozen=True, slots=True)
class LogScan:
    """One scan of a log with the robot's odometry at that time.

    Attributes:
        stamp: seconds (log time).
        odom: ``base_link`` in ``odom``.
        laser_pose: ``laser`` in ``base_link``.
        angle_min_rad, angle_increment_rad: beam geometry in the laser frame.
        ranges_m: ranges, ``inf`` where there was no return.
        range_max_m: the sensor's maximum range.
    """

    stamp: float
    odom: Pose2D
    laser_pose: Pose2D
    angle_min_rad: float
    angle_increment_rad: float
    ranges_m: F64
    range_max_m: float

    def points(self, max_range_m: float | None = None) -> F64:
        """Valid end points in ``base_link`` as ``(N, 2)``."""
        r = self.ranges_m
        limit = self.range_max_m if max_range_m is None else min(self.range_max_m, max_range_m)
        ok = np.isfinite(r) & (r > 0.05) & (r < limit)
        ang = self.angle_min_rad + np.flatnonzero(ok) * self.angle_increment_rad
        pts = np.stack([r[ok] * np.cos(ang), r[ok] * np.sin(ang)], axis=1)
        return self.laser_pose.transform_points(pts)


def _floats(path: Path, lineno: int, fields: list[str], what: str) -> list[float]:
    out = []
    for i, f in enumerate(fields):
        try:
            v = float(f)
        except ValueError:
            raise LogError(f"{path}:{lineno}: {what}: field {i + 1} is {f!r}, not a number") \
                from None
        if not math.isfinite(v):
            raise LogError(f"{path}:{lineno}: {what}: field {i + 1} is {f!r}, not finite")
        out.append(v)
    return out


def _ranges(values: list[float], max_range: float) -> F64:
    r = np.asarray(values, dtype=np.float64)
    r[(r >= max_range - 1e-6) | (r <= 0.0)] = np.inf
    return r


def _parse_flaser(path: Path, lineno: int, tok: list[str]) -> LogScan:
    if len(tok) < 2:
        raise LogError(f"{path}:{lineno}: FLASER: missing the number of readings")
    try:
        n = int(tok[1])
    except ValueError:
        raise LogError(f"{path}:{lineno}: FLASER: number of readings {tok[1]!r} is not an "
                       "integer") from None
    if n <= 0 or n > 100_000:
        raise LogError(f"{path}:{lineno}: FLASER: number of readings {n} is out of range")
    need = 2 + n + 7
    if len(tok) < need:
        raise LogError(f"{path}:{lineno}: FLASER: {n} readings need at least {need} fields "
                       f"(readings, x y theta, odom_x odom_y odom_theta, timestamp), got "
                       f"{len(tok)}")
    ranges = _floats(path, lineno, tok[2:2 + n], "FLASER reading")
    x, y, th, ox, oy, oth, stamp = _floats(path, lineno, tok[2 + n:2 + n + 7],
                                           "FLASER pose/timestamp")
    odom = Pose2D(ox, oy, oth)
    laser_in_base = odom.inverse() @ Pose2D(x, y, th)
    if laser_in_base.distance_to(Pose2D()) > 1.0:
        laser_in_base = Pose2D()  # corrected pose, not an offset: ignore it
    # Front laser, 180° field of view.
    inc = math.pi / (n - 1) if n > 1 else 0.0
    max_range = 81.9 if max(ranges, default=0.0) > 50.0 else 50.0
    return LogScan(stamp, odom, laser_in_base, -math.pi / 2, inc, _ranges(ranges, max_range),
                   max_range)


def _parse_robotlaser(path: Path, lineno: int, tok: list[str]) -> LogScan:
    head = _floats(path, lineno, tok[1:8], f"{tok[0]} header")
    if len(head) < 7:
        raise LogError(f"{path}:{lineno}: {tok[0]}: the header needs 7 fields (type, start "
                       "angle, field of view, resolution, maximum range, accuracy, remission "
                       "mode)")
    _, start, _fov, res, max_range, _, _ = head
    try:
        n = int(tok[8])
    except (IndexError, ValueError):
        raise LogError(f"{path}:{lineno}: {tok[0]}: field 9 must be the number of readings") \
            from None
    i = 9
    ranges = _floats(path, lineno, tok[i:i + n], f"{tok[0]} reading")
    if len(ranges) != n:
        raise LogError(f"{path}:{lineno}: {tok[0]}: expected {n} readings, got {len(ranges)}")
    i += n
    try:
        m = int(tok[i])
    except (IndexError, ValueError):
        raise LogError(f"{path}:{lineno}: {tok[0]}: missing the number of remission values") \
            from None
    i += 1 + m
    vals = _floats(path, lineno, tok[i:i + 12], f"{tok[0]} poses/timestamp")
    if len(vals) < 12:
        raise LogError(f"{path}:{lineno}: {tok[0]}: the line ends before the laser pose, robot "
                       "pose, velocities and timestamp")
    lx, ly, lth, rx, ry, rth = vals[:6]
    stamp = vals[11]
    odom = Pose2D(rx, ry, rth)
    laser = odom.inverse() @ Pose2D(lx, ly, lth)
    if max_range <= 0:
        raise LogError(f"{path}:{lineno}: {tok[0]}: maximum range {max_range} must be > 0")
    return LogScan(stamp, odom, laser, start, res, _ranges(ranges, max_range), max_range)


def read_carmen(path: Path | str) -> Iterator[LogScan]:
    """Yield the scans of a CARMEN log, in file order.

    Raises:
        LogError: an unreadable file or a malformed laser/odometry line (with its number).
    """
    p = Path(path)
    try:
        fh = p.open("r", encoding="utf-8", errors="replace")
    except OSError as exc:
        raise LogError(f"{p}: cannot open the log ({exc})") from None
    odom_t: list[float] = []
    odom_p: list[Pose2D] = []
    found = False
    with fh:
        for lineno, line in enumerate(fh, start=1):
            tok = line.split()
            if not tok or tok[0].startswith("#"):
                continue
            kind = tok[0]
            if kind == "FLASER":
                found = True
                yield _parse_flaser(p, lineno, tok)
            elif kind in ("ROBOTLASER1", "ROBOTLASER2"):
                found = True
                yield _parse_robotlaser(p, lineno, tok)
            elif kind == "ODOM":
                vals = _floats(p, lineno, tok[1:8], "ODOM")
                if len(vals) < 7:
                    raise LogError(f"{p}:{lineno}: ODOM needs x y theta tv rv accel timestamp")
                odom_t.append(vals[6])
                odom_p.append(Pose2D(vals[0], vals[1], vals[2]))
            elif kind.isupper() and kind.replace("_", "").isalnum():
                continue  # another CARMEN message
            else:
                raise LogError(f"{p}:{lineno}: not a CARMEN message: starts with {kind[:20]!r} "
                               "(expected FLASER, ROBOTLASER1, ODOM, ... or a # comment)")
    if not found:
        raise LogError(f"{p}: no FLASER or ROBOTLASER lines: nothing to map")


def _interp(ts: list[float], poses: list[Pose2D], t: float) -> Pose2D | None:
    if not ts:
        return None
    i = bisect.bisect_left(ts, t)
    if i <= 0:
        return poses[0]
    if i >= len(ts):
        return poses[-1]
    a, b = poses[i - 1], poses[i]
    span = ts[i] - ts[i - 1]
    f = 0.0 if span <= 0 else (t - ts[i - 1]) / span
    d = a.inverse() @ b
    return a @ Pose2D(d.x * f, d.y * f, d.yaw * f)


def read_run(path: Path | str) -> Iterator[LogScan]:
    """Yield the scans of a Curio run log (JSON lines), each with interpolated odometry.

    Raises:
        LogError: unreadable file, bad JSON, a missing field or a wrong type (with the line).
    """
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise LogError(f"{p}: cannot read the run log ({exc})") from None
    laser = Pose2D()
    odom_t: list[float] = []
    odom_p: list[Pose2D] = []
    scans: list[tuple[int, dict[str, Any]]] = []
    for lineno, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise LogError(f"{p}:{lineno}: not valid JSON ({exc.msg})") from None
        if not isinstance(rec, dict) or "type" not in rec:
            raise LogError(f"{p}:{lineno}: each line must be an object with a 'type'")
        kind = rec["type"]
        try:
            if kind == "header":
                if rec.get("format") != "curio-run":
                    raise LogError(f"{p}:{lineno}: header format must be 'curio-run', got "
                                   f"{rec.get('format')!r}")
                lp = rec.get("laser_pose", [0.0, 0.0, 0.0])
                laser = Pose2D(float(lp[0]), float(lp[1]), float(lp[2]))
            elif kind == "odom":
                t = float(rec["t"])
                if odom_t and t < odom_t[-1]:
                    raise LogError(f"{p}:{lineno}: odom time {t} goes backwards")
                odom_t.append(t)
                odom_p.append(Pose2D(float(rec["x"]), float(rec["y"]), float(rec["yaw"])))
            elif kind == "scan":
                float(rec["t"])
                float(rec["angle_min"])
                float(rec["angle_increment"])
                float(rec["range_max"])
                if not isinstance(rec["ranges"], list):
                    raise LogError(f"{p}:{lineno}: scan field 'ranges' must be a list")
                scans.append((lineno, rec))
            elif kind == "truth":
                continue
            else:
                raise LogError(f"{p}:{lineno}: unknown record type {kind!r} (header, odom, "
                               "scan, truth)")
        except KeyError as exc:
            raise LogError(f"{p}:{lineno}: {kind} record is missing field {exc}") from None
        except (TypeError, ValueError, IndexError) as exc:
            if isinstance(exc, LogError):
                raise
            raise LogError(f"{p}:{lineno}: {kind} record has a bad value ({exc})") from None
    if not scans:
        raise LogError(f"{p}: no scan records: nothing to map")
    if not odom_t:
        raise LogError(f"{p}: no odom records: scans need odometry")
    for lineno, rec in scans:
        t = float(rec["t"])
        odom = _interp(odom_t, odom_p, t)
        assert odom is not None
        try:
            r = np.array([np.inf if v is None else float(v) for v in rec["ranges"]])
        except (TypeError, ValueError):
            raise LogError(f"{p}:{lineno}: scan ranges must be numbers or null") from None
        rmax = float(rec["range_max"])
        r[~np.isfinite(r) | (r > rmax) | (r < float(rec.get("range_min", 0.0)))] = np.inf
        yield LogScan(t, odom, laser, float(rec["angle_min"]), float(rec["angle_increment"]),
                      r, rmax)


def read_log(path: Path | str) -> Iterator[LogScan]:
    """A run log (``.jsonl``/``.json``) or a CARMEN log (anything else), by file name."""
    p = Path(path)
    if p.suffix.lower() in (".jsonl", ".json"):
        return read_run(p)
    return read_carmen(p)


class RunRecorder:
    """Writes a Curio run log (see the module docstring) to an open text stream."""

    def __init__(self, out: IO[str], laser_pose: Pose2D) -> None:
        self._out = out
        self._out.write(json.dumps({"type": "header", "format": "curio-run", "version": 1,
                                    "laser_pose": list(laser_pose.as_tuple())}) + "\n")

    def odom(self, t: float, pose: Pose2D) -> None:
        """Record ``base_link`` in ``odom`` at ``t``."""
        self._out.write(json.dumps({"type": "odom", "t": round(t, 6), "x": round(pose.x, 6),
                                    "y": round(pose.y, 6), "yaw": round(pose.yaw, 7)}) + "\n")

    def truth(self, t: float, pose: Pose2D) -> None:
        """Record the true pose in ``map`` (simulator only)."""
        self._out.write(json.dumps({"type": "truth", "t": round(t, 6), "x": round(pose.x, 6),
                                    "y": round(pose.y, 6), "yaw": round(pose.yaw, 7)}) + "\n")

    def scan(self, t: float, angle_min: float, angle_increment: float, range_min: float,
             range_max: float, ranges: npt.NDArray[Any]) -> None:
        """Record one scan (``laser`` frame)."""
        vals = [None if not math.isfinite(float(v)) else round(float(v), 4) for v in ranges]
        self._out.write(json.dumps({"type": "scan", "t": round(t, 6), "angle_min": angle_min,
                                    "angle_increment": angle_increment, "range_min": range_min,
                                    "range_max": range_max, "ranges": vals}) + "\n")
