"""``curio map``: build maps from logs, inspect and convert map_server maps.

Commands::

    curio map build --log FILE --out MAP.yaml [--trajectory T.csv] [--resolution M]
                    [--max-range M] [--format pgm|png] [--quiet]
    curio map info MAP.yaml
    curio map score TRAJ.csv RELATIONS [--max-dt S] [--json PATH]
    curio map convert IN.yaml OUT.yaml [--format pgm|png] [--mode trinary|scale|raw]
    curio map record --out RUN.jsonl [--duration S] [--config PATH] [--set KEY=VALUE]...

``record`` runs the application (the configured drivers; drive the rover from the dashboard's
teleop, or let the configured behaviour drive it in the simulator) and writes every scan and
odometry message (and, in the simulator, the ground truth) to a Curio run log until Ctrl-C or
``--duration`` seconds (simulated seconds in ``sim`` mode, where it runs as fast as it can).

``--log`` takes a CARMEN log (FLASER / ROBOTLASER1 / ODOM lines, e.g. the public Freiburg and
MIT logs) or a Curio run log (``.jsonl``, see :mod:`curio.estimation.carmen`). The trajectory
CSV has the header ``t,x,y,yaw`` (seconds, metres, metres, radians; the corrected pose of every
scan in the map frame). Exit codes: 0 success, 1 failure, 2 bad arguments or unreadable input.

``score`` rates such a trajectory with the ground-truth relations of the Freiburg SLAM benchmark
(Kümmerle et al. 2009; see :mod:`curio.estimation.relations` for the metric and the formats):
mean ± std of the translational (m) and rotational (deg) relative-relation error, the worst
relation and the number of relations matched. It exits 1 when no relation matched a pose.
"""

from __future__ import annotations

import argparse
import io
import logging
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from curio.commands.signals import stop_on_signals
from curio.core.fileio import atomic_write_text
from curio.estimation.carmen import LogError
from curio.estimation.logs import read_log  # ROS bags and recordings too
from curio.estimation.maps import MapError, load_map, map_stats, save_map

if TYPE_CHECKING:
    from curio.estimation.mapping import MapperParams, ScanMapper

__all__ = ["main"]


class _Progress:
    """A one-line text progress bar on a terminal stream (silent when not a TTY or quiet)."""

    def __init__(self, total: int, stream: TextIO, enabled: bool) -> None:
        self.total = max(1, total)
        self.stream = stream
        self.enabled = enabled
        self._last = -1

    def abort(self) -> None:
        """End a bar left half drawn (an error follows on its own line)."""
        if self.enabled and 0 <= self._last < 100:
            self.stream.write("\n")
            self.stream.flush()

    def __call__(self, n: int) -> None:
        if not self.enabled:
            return
        pct = min(100, int(100 * n / self.total))
        if pct == self._last:
            return
        self._last = pct
        filled = pct * 30 // 100
        self.stream.write(f"\r  [{'#' * filled}{'.' * (30 - filled)}] {pct:3d}% "
                          f"{n}/{self.total} scans")
        if pct >= 100:
            self.stream.write("\n")
        self.stream.flush()


def _count_scans(path: Path) -> int:
    n = 0
    try:
        with path.open("r", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith(("FLASER", "ROBOTLASER")) or '"type": "scan"' in line:
                    n += 1
    except OSError:
        return 0
    return n


def _build(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from curio.core.clock import wall_perf_counter
    from curio.estimation.mapping import MapperParams, build_map_from_log

    log_path = Path(args.log)
    if not log_path.exists():  # a file, or a rosbag2 directory
        err.write(f"curio map build: --log: no such file: {log_path}\n")
        return 2
    if args.resolution <= 0 or args.max_range <= 0:
        err.write("curio map build: --resolution and --max-range must be > 0\n")
        return 2
    out_path = Path(args.out)
    if out_path.suffix not in (".yaml", ".yml"):
        err.write(f"curio map build: --out must name a .yaml file, got {out_path}\n")
        return 2
    total = _count_scans(log_path)
    progress = _Progress(total, err, enabled=not args.quiet and total > 100 and err.isatty())
    params = MapperParams(resolution_m=args.resolution, max_range_m=args.max_range)
    bad: list[str] | None = [] if args.skip_bad_lines else None
    t0 = wall_perf_counter()
    try:
        mapper = build_map_from_log(read_log(log_path, bad), params, progress)
    except LogError as exc:
        progress.abort()
        hint = "" if args.skip_bad_lines else (
            " (--skip-bad-lines maps the rest of the log and counts what it skipped)")
        err.write(f"curio map build: {exc}{hint}\n")
        return 2
    grid = mapper.occupancy()
    grid.name = out_path.name
    out_path.parent.mkdir(parents=True, exist_ok=True)
    save_map(grid, out_path, image_format=args.format)
    if args.trajectory:
        buf = io.StringIO()
        buf.write("t,x,y,yaw\n")
        for t, p in mapper.trajectory:
            buf.write(f"{t:.6f},{p.x:.4f},{p.y:.4f},{p.yaw:.5f}\n")
        atomic_write_text(Path(args.trajectory), buf.getvalue())
    wall = wall_perf_counter() - t0
    span = mapper.trajectory[-1][0] - mapper.trajectory[0][0] if mapper.trajectory else 0.0
    stats = map_stats(load_map(out_path))  # what was saved: the figures `map info` shows
    out.write(f"built {out_path} from {mapper.scans} scans ({span:.0f} s of log) in {wall:.1f} s"
              f" ({span / wall if wall > 0 else 0:.1f}x real time)\n")
    out.write(f"  {grid.width} x {grid.height} cells at {grid.resolution_m:g} m, "
              f"{len(mapper.keyframes)} keyframes, {len(mapper.loop_edges)} loop closures, "
              f"{mapper.matched} scans matched\n")
    out.write(f"  free {stats['free_pct']:.1f} %, occupied {stats['occupied_pct']:.1f} %, "
              f"unknown {stats['unknown_pct']:.1f} %\n")
    if bad:
        out.write(f"  skipped {len(bad)} bad line{'s' if len(bad) != 1 else ''} "
                  f"(first: {bad[0]})\n")
    if len(mapper.keyframes) < 3:
        out.write(_still_hint(mapper, params))
    if args.trajectory:
        out.write(f"  trajectory: {args.trajectory}\n")
    return 0


def _still_hint(mapper: ScanMapper, params: MapperParams) -> str:
    """Why a log of a rover that hardly moved gives a map with (almost) no free space."""
    poses = [p for _, p in mapper.trajectory]
    moved = max((poses[0].distance_to(p) for p in poses), default=0.0)
    return (f"  note: the rover moved at most {moved:.2f} m in this log, so the map has only "
            f"{len(mapper.keyframes)} keyframe(s) (one every {params.keyframe_d_m:g} m or "
            f"{math.degrees(params.keyframe_a_rad):.0f} deg of motion) and one sighting of a "
            "cell is not enough to call it free: drive the rover around to map a building\n")


def _info(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    try:
        grid = load_map(args.map)
    except MapError as exc:
        err.write(f"curio map info: {exc}\n")
        return 2
    s = map_stats(grid)
    o = grid.origin
    out.write(f"{args.map}\n")
    out.write(f"  size        {grid.width} x {grid.height} cells, {s['width_m']:.2f} x "
              f"{s['height_m']:.2f} m\n")
    out.write(f"  resolution  {grid.resolution_m:g} m/cell\n")
    out.write(f"  origin      x {o.x:g} m, y {o.y:g} m, yaw {o.yaw:g} rad\n")
    out.write(f"  thresholds  free <= {grid.free_thresh:g}, occupied >= {grid.occupied_thresh:g}\n")
    out.write(f"  free        {s['free_pct']:.1f} %\n")
    out.write(f"  occupied    {s['occupied_pct']:.1f} %\n")
    out.write(f"  unknown     {s['unknown_pct']:.1f} %\n")
    return 0


def _convert(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    dst = Path(args.dst)
    if dst.suffix not in (".yaml", ".yml"):
        err.write(f"curio map convert: the output must name a .yaml file, got {dst}\n")
        return 2
    if dst.resolve() == Path(args.src).resolve():
        err.write("curio map convert: the output must differ from the input\n")
        return 2
    try:
        grid = load_map(args.src)
        save_map(grid, dst, image_format=args.format, mode=args.mode)
    except MapError as exc:
        err.write(f"curio map convert: {exc}\n")
        return 2
    out.write(f"wrote {dst} and {dst.with_suffix('.' + args.format).name} ({args.mode})\n")
    return 0


def _fmt_time(t: float) -> str:
    return f"{t:.5f}"


def _score(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from curio.core.fileio import atomic_write_json
    from curio.estimation.relations import (
        RelationError,
        read_relations,
        read_trajectory,
        score_trajectory,
    )

    if not (args.max_dt > 0 and math.isfinite(args.max_dt)):
        err.write(f"curio map score: --max-dt must be a positive number of seconds, got "
                  f"{args.max_dt}\n")
        return 2
    try:
        traj = read_trajectory(args.trajectory)
        rels = read_relations(args.relations)
    except RelationError as exc:
        err.write(f"curio map score: {exc}\n")
        return 2
    sc = score_trajectory(traj, rels, args.max_dt)
    out.write(f"{args.trajectory}: {len(traj)} poses; {args.relations}: {sc.relations} "
              f"relations, {sc.matched} matched (timestamps within {args.max_dt:g} s)\n")
    if sc.matched == 0:
        err.write(f"curio map score: no relation matched the trajectory's timestamps within "
                  f"{args.max_dt:g} s (wrong log, or try a larger --max-dt)\n")
        return 1
    wt, wr = sc.worst_trans, sc.worst_rot
    assert wt is not None and wr is not None
    out.write(f"  translational error  {sc.trans_mean_m:.3f} ± {sc.trans_std_m:.3f} m, "
              f"max {sc.trans_max_m:.3f} m ({_fmt_time(wt.t1_s)} -> {_fmt_time(wt.t2_s)})\n")
    out.write(f"  rotational error     {sc.rot_mean_deg:.2f} ± {sc.rot_std_deg:.2f} deg, "
              f"max {sc.rot_max_deg:.2f} deg ({_fmt_time(wr.t1_s)} -> {_fmt_time(wr.t2_s)})\n")
    if args.json:
        atomic_write_json(Path(args.json), {"trajectory": str(args.trajectory),
                                             "relations_file": str(args.relations),
                                             "max_dt_s": args.max_dt, **sc.as_dict()})
    return 0


def _record(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    import asyncio

    from curio.app import App
    from curio.core.clock import Clock, RealClock, SimClock
    from curio.core.config import ConfigError, load_config
    from curio.core.parts import Part
    from curio.core.topics import GROUND_TRUTH, ODOM, SCAN
    from curio.drivers.modes import driver_mode
    from curio.estimation.carmen import RunRecorder

    try:
        cfg = load_config(args.config, args.set)
    except ConfigError as exc:
        err.write(f"curio map record: {exc}\n")
        return 2
    sim = driver_mode(cfg).simulated
    if sim and args.duration is None:
        err.write("curio map record: in sim mode give --duration (simulated seconds)\n")
        return 2
    if args.duration is not None and args.duration <= 0:
        err.write("curio map record: --duration must be > 0\n")
        return 2
    out_path = Path(args.out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    clock: Clock
    sim_clock = SimClock() if sim else None
    clock = sim_clock if sim_clock is not None else RealClock()
    counts = {"scans": 0, "odom": 0}

    async def main() -> int:
        app = App(cfg, clock)
        with out_path.open("w", encoding="utf-8") as fh:
            rec = RunRecorder(fh, app.robot.laser_in_base)
            scan_sub = app.bus.subscribe(SCAN, maxsize=8)
            odom_sub = app.bus.subscribe(ODOM, maxsize=256)
            truth_sub = app.bus.subscribe(GROUND_TRUTH, maxsize=256)

            async def write() -> None:
                while True:
                    await clock.sleep(0.05)
                    for o in odom_sub.drain():
                        rec.odom(o.stamp, o.pose)
                        counts["odom"] += 1
                    for g in truth_sub.drain():
                        rec.truth(g.stamp, g.pose)
                    for s in scan_sub.drain():
                        rec.scan(s.stamp, s.angle_min_rad, s.angle_increment_rad,
                                 s.range_min_m, s.range_max_m, s.ranges_m)
                        counts["scans"] += 1

            app.add(Part("map.record", run=write))
            stop = stop_on_signals()
            await app.start()
            if sim_clock is not None:
                await sim_clock.run(until_s=float(args.duration),
                                    stop=lambda: stop.is_set() or bool(app.failed_parts()))
            else:
                end = None if args.duration is None else clock.now() + float(args.duration)
                while not stop.is_set() and (end is None or clock.now() < end):
                    await clock.sleep(0.2)
            await app.stop()
            failed = app.failed_parts()
        if failed:
            err.write(f"curio map record: {failed[0][0]} failed: {failed[0][1]}\n")
            return 1
        return 0

    code = asyncio.run(main())
    out.write(f"recorded {counts['scans']} scans and {counts['odom']} odometry messages to "
              f"{out_path}\n")
    return code


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="curio map", description="Build, inspect and convert maps.")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="ACTION",
                           title="actions (build, info, score, convert, record)")
    b = sub.add_parser("build", help="build a map from a CARMEN log or a Curio run log")
    b.add_argument("--log", required=True, help="CARMEN .clf/.log, Curio .jsonl run log or "
                   ".mcap recording, or a ROS bag (.bag, rosbag2 directory, .db3, .mcap)")
    b.add_argument("--out", required=True, help="map YAML to write (image beside it)")
    b.add_argument("--trajectory", help="write the corrected trajectory as CSV t,x,y,yaw")
    b.add_argument("--resolution", type=float, default=0.05, help="metres per cell (0.05)")
    b.add_argument("--max-range", type=float, default=25.0,
                   help="use ranges up to this many metres (25)")
    b.add_argument("--format", choices=("pgm", "png"), default="pgm")
    b.add_argument("--skip-bad-lines", action="store_true",
                   help="skip malformed log lines (counted in the summary) instead of stopping")
    b.add_argument("--quiet", action="store_true", help="no progress bar, no log messages")
    i = sub.add_parser("info", help="size, resolution, origin and content of a map")
    i.add_argument("map", help="map YAML")
    s = sub.add_parser("score", help="score a trajectory with ground-truth relations "
                       "(Freiburg SLAM benchmark metric)")
    s.add_argument("trajectory", help="trajectory CSV t,x,y,yaw (curio map build --trajectory)")
    s.add_argument("relations", help="relations file: t1 t2 x y z roll pitch yaw per line")
    s.add_argument("--max-dt", type=float, default=1e-3,
                   help="largest timestamp gap of a match, seconds (0.001)")
    s.add_argument("--json", help="also write the figures to this JSON file")
    c = sub.add_parser("convert", help="rewrite a map (pgm <-> png, another mode)")
    c.add_argument("src", help="input map YAML")
    c.add_argument("dst", help="output map YAML")
    c.add_argument("--format", choices=("pgm", "png"), default="png")
    c.add_argument("--mode", choices=("trinary", "scale", "raw"), default="trinary")
    r = sub.add_parser("record", help="record scans and odometry of a drive to a run log")
    r.add_argument("--out", required=True, help="run log to write (.jsonl)")
    r.add_argument("--duration", type=float, help="seconds to record (required in sim mode)")
    r.add_argument("--config", help="config file (default: ./config.toml)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key (repeatable)")
    return p


def main(argv: list[str] | None = None, out: TextIO | None = None,
         err: TextIO | None = None) -> int:
    """Run ``curio map`` with ``argv`` (without the ``map`` word); return the exit code."""
    out = out or sys.stdout
    err = err or sys.stderr
    if not argv:
        err.write("curio map: choose an action: build, info, score, convert or record "
                  "(curio map ACTION --help)\n")
        return 2
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return 0 if exc.code == 0 else 2
    if getattr(args, "quiet", False):
        logging.getLogger("curio").setLevel(logging.WARNING)
    if args.cmd == "build":
        return _build(args, out, err)
    if args.cmd == "info":
        return _info(args, out, err)
    if args.cmd == "record":
        return _record(args, out, err)
    if args.cmd == "score":
        return _score(args, out, err)
    return _convert(args, out, err)
