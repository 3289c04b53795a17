"""``curio replay``: a recording (or a ROS bag) through estimation and navigation again.

Usage::

    curio replay FILE [--from T] [--to T] [--speed N|max] [--web] [--report PATH]
                 [--config PATH] [--set KEY=VALUE]... [--map YAML] [--start X,Y,YAW]
                 [--pose-tol M] [--plan-tol M]

**A Curio recording** (MCAP written by the flight recorder or ``curio sim --record``): the
application is built from the configuration recorded in the file (``--set`` changes it,
``--config`` replaces it) on a :class:`~curio.core.clock.SimClock` starting at the recorded
clock time, with the simulator and the drivers replaced by the recorded inputs
(:class:`~curio.record.replay.ReplaySource`: scans, wheels, IMU, battery, servo commands,
operator commands, initial poses, teleop, scripted goals, each at its recorded time).
Estimation, navigation, the tree and the safety stage run again; their ``/pose``, ``/plan``,
``/cmd_vel`` and ``/cmd_vel_nav`` are compared with the recorded ones
(:mod:`curio.record.compare`) and the report says where they diverge. On the same code a
simulated run is reproduced exactly (the poses to well under a millimetre); a changed parameter
shows as a divergence with its size and its first time. ``--from``/``--to`` are seconds from
the start of the file; starting later seeds the localiser with the recorded pose there
(commands given before it are not replayed). ``--web`` serves the dashboard meanwhile (real
time by default) with a timeline to pause, change the speed and seek
(:mod:`curio.record.timeline`: a seek backwards restarts the run from there on the same
address); at the end of the recording the dashboard stays up until Finish on the page, a seek
back or Ctrl-C, then the report covers the last run (up to where it was finished).

**A ROS bag** (rosbag1, rosbag2, ``curio[ros]``): its ``sensor_msgs/LaserScan`` and
``nav_msgs/Odometry`` drive localisation in ``--map`` (or the configured map) from ``--start``;
the report gives the localisation's quality and the path it estimated (nothing to compare).

Exit codes: 0 reproduced (or a bag replayed), 1 diverged, 2 bad arguments or input.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import math
import shutil
import signal
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any, TextIO

from curio.commands.common import run_command
from curio.core.bus import Bus, Topic
from curio.core.clock import SimClock, wall_perf_counter
from curio.core.config import Config, config_from_data, load_config
from curio.core.errors import SetupError
from curio.core.fileio import atomic_write_json
from curio.core.jsonable import to_jsonable
from curio.core.messages import NavGoal
from curio.core.topics import (
    CMD_VEL,
    CMD_VEL_NAV,
    LOCALIZATION,
    PLAN,
    POSE,
    SCAN,
    WHEEL_ODOM,
)
from curio.record.compare import (
    Tolerances,
    compare_paths,
    compare_poses,
    compare_twists,
    truth_rmse,
)
from curio.record.library import recording_info
from curio.record.reader import Recording, RecordingError, open_recording
from curio.record.replay import Recorded, ReplaySource, TimedInput, recording_inputs
from curio.record.timeline import ReplayTimeline

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="curio replay", description=(
        "Replay a recording (or a ROS bag) through estimation and navigation on simulated "
        "time and report where the new run diverges from the recorded one."))
    p.add_argument("file", help="a Curio recording (.mcap) or a ROS bag (.bag, rosbag2 "
                   "directory, .db3, ROS .mcap)")
    p.add_argument("--from", dest="t_from", type=float, default=0.0, metavar="T",
                   help="start T seconds into the file (default 0)")
    p.add_argument("--to", dest="t_to", type=float, metavar="T",
                   help="stop T seconds into the file (default: its end)")
    p.add_argument("--speed", help="N x real time, or max (default: max; 1 with --web)")
    p.add_argument("--web", action="store_true", help="serve the dashboard during the replay")
    p.add_argument("--report", type=Path, help="write the JSON report here")
    p.add_argument("--config", type=Path, help="use this config instead of the recorded one")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="KEY=VALUE", help="change one config key (repeatable)")
    p.add_argument("--map", dest="map_yaml", help="map YAML to localise in (ROS bags)")
    p.add_argument("--start", help="start pose X,Y,YAW in the map (ROS bags)")
    p.add_argument("--pose-tol", type=float, default=0.001, metavar="M",
                   help="pose divergence threshold, metres (default 0.001)")
    p.add_argument("--plan-tol", type=float, default=0.05, metavar="M",
                   help="plan divergence threshold, metres (default 0.05)")
    return p


def _speed(args: argparse.Namespace) -> float | None:
    if args.speed is None:
        return 1.0 if args.web else None
    if args.speed == "max":
        return None
    try:
        speed = float(args.speed)
    except ValueError:
        raise SetupError(f"--speed takes a number > 0 or 'max', got '{args.speed}'") from None
    if not speed > 0 or not math.isfinite(speed):
        raise SetupError(f"--speed takes a number > 0 or 'max', got '{args.speed}'")
    return speed


def _check_times(args: argparse.Namespace) -> None:
    if not math.isfinite(args.t_from) or args.t_from < 0:
        raise SetupError(f"--from takes seconds >= 0 into the file, got {args.t_from}")
    if args.t_to is not None and not (math.isfinite(args.t_to) and args.t_to > args.t_from):
        raise SetupError(f"--to takes seconds into the file after --from ({args.t_from:g}), "
                         f"got {args.t_to}")
    for name in ("pose_tol", "plan_tol"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise SetupError(f"--{name.replace('_', '-')} takes metres > 0, got {value}")


def _replay_config(base: Config, web: bool, data_dir: Path, recorded_mode: str) -> Config:
    """The config a replay runs with: the recorded one, drivers replaced, nothing recorded."""
    def section(name: str, **changes: Any) -> Any:
        return getattr(base, name).model_copy(update=changes)

    updates: dict[str, Any] = {
        "data_dir": str(data_dir), "drivers": section("drivers", mode="sim"),
        "record": section("record", enabled=False),
        "foxglove": section("foxglove", enabled=False), "web": section("web", enabled=web)}
    if recorded_mode == "real":  # the real rover started at home, whatever sim.start says
        updates["sim"] = section("sim", start=None)
    return base.model_copy(update=updates)


def _recorded_config(rec: Recording, args: argparse.Namespace) -> Config:
    if args.config is not None:
        return load_config(args.config, args.overrides)
    data = rec.config_data()
    if data is None:
        raise SetupError(f"{rec.path}: the recording holds no configuration; give --config")
    return config_from_data(data, Path(rec.curio.get("base_dir", ".")), args.overrides,
                            f"the configuration recorded in {rec.path.name}")


class _Capture:
    """Keeps the replayed outputs, ``(now, message)``, through a bus tap."""

    TOPICS = (POSE, PLAN, CMD_VEL, CMD_VEL_NAV, LOCALIZATION)

    def __init__(self, bus: Bus, clock: SimClock) -> None:
        self.clock = clock
        self.bus = bus
        self.series: dict[str, list[tuple[float, Any]]] = {t.name: [] for t in self.TOPICS}
        bus.add_tap(self._tap)

    def _tap(self, topic: Topic[Any], msg: Any) -> None:
        store = self.series.get(topic.name)
        if store is not None:
            store.append((self.clock.now(), msg))

    def stop(self) -> None:
        """Capture no more."""
        self.bus.remove_tap(self._tap)


def _first_time(rec: Recording) -> float:
    for m in rec.messages():
        return m.publish_ns / 1e9
    raise SetupError(f"{rec.path}: the recording holds no messages")


async def _run_app(cfg: Config, clock: SimClock, source: ReplaySource, web: bool,
                   end_s: float | None, out: TextIO, halt_recorded: bool,
                   timeline: ReplayTimeline | None = None,
                   ) -> tuple[_Capture, list[tuple[str, BaseException]]]:
    """Build and run the application on the replayed inputs; return what it published.

    With a ``timeline`` (``--web``) the page's timeline drives the clock (pause, speed, seek),
    and at the end of the recording the dashboard stays up until Finish, a seek back or
    Ctrl-C."""
    from curio.app import App

    captured: list[_Capture] = []

    def inputs(bus: Bus, clock_: Any, parts: Any) -> None:
        captured.append(_Capture(bus, clock))  # before any part is built: sees it all
        source.register(bus, clock_, parts)

    app = App(cfg, clock, web=web, inputs=inputs)
    capture = captured[0]

    def give_goal(goal: NavGoal) -> None:
        if goal.action == "cancel":
            app.navigator.cancel(goal.reason or "canceled")
        else:
            poses = goal.poses[0] if len(goal.poses) == 1 else list(goal.poses)
            app.navigator.send_goal(poses, tag=goal.tag)

    source.on_goal = give_goal
    if timeline is not None and app.web is not None:
        _attach_timeline(timeline, app.web, clock)
    await app.start()
    if app.web_url:
        out.write(f"dashboard: {app.web_url}\n")
        out.flush()
    if timeline is None:
        await clock.run(stop=lambda: source.done or bool(app.failed_parts()))
    else:
        await timeline.drive(clock, lambda: source.done or bool(app.failed_parts()))
    leaving = timeline is not None and (timeline.finished or timeline.restart_from_s is not None)
    if end_s is not None and not app.failed_parts() and clock.now() < end_s and not leaving:
        await clock.run(until_s=end_s, stop=lambda: bool(app.failed_parts()))
    if timeline is not None and not leaving and not app.failed_parts():
        await timeline.hold_at_end()
    failed = app.failed_parts()
    if not halt_recorded or (timeline is not None and not timeline.at_end):
        capture.stop()  # the recording goes on past the end: its shutdown is not compared
    await app.stop()
    capture.stop()
    return capture, failed


def _attach_timeline(timeline: ReplayTimeline, web: Any, clock: SimClock) -> None:
    """Give the page the timeline; Ctrl-C (or SIGTERM) finishes the replay."""
    timeline.new_run(clock)
    timeline.port = web.port
    web.services.replay = timeline
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        # not on every platform's loop, nor outside the main thread (a test runs it in one)
        with contextlib.suppress(NotImplementedError, ValueError, RuntimeError):
            loop.add_signal_handler(sig, timeline.finish)


def _timeline(rec: Recording, args: argparse.Namespace, t0: float, first: float
              ) -> ReplayTimeline:
    """The timeline of ``--web``: the recording's length from its summary (or a scan)."""
    try:
        length: float | None = (first - t0) + recording_info(rec.path).duration_s
    except (RecordingError, OSError):
        length = None
    if args.t_to is not None:
        length = args.t_to if length is None else min(length, args.t_to)
    return ReplayTimeline(rec.path.name, t0, length, _speed(args), args.t_from)


def _compare(recorded: Recorded, capture: _Capture, t0: float,
             tol: Tolerances) -> dict[str, Any]:
    s = capture.series
    out: dict[str, Any] = {
        "pose": compare_poses(recorded.poses, s[POSE.name], t0, tol),
        "plan": compare_paths(recorded.plans, s[PLAN.name], t0, tol),
        "cmd_vel": compare_twists(recorded.cmd_vel, s[CMD_VEL.name], t0, tol),
        "cmd_vel_nav": compare_twists(recorded.cmd_vel_nav, s[CMD_VEL_NAV.name], t0, tol),
    }
    if recorded.truth:
        out["truth_rmse_m"] = {"recorded": truth_rmse(recorded.poses, recorded.truth),
                               "replayed": truth_rmse(s[POSE.name], recorded.truth)}
    return out


def _verdict(result: dict[str, Any]) -> tuple[bool, list[str]]:
    """Whether the replay diverged, and the lines that say where."""
    why = []
    for key in ("pose", "plan", "cmd_vel", "cmd_vel_nav"):
        r = result[key]
        if r["over_tolerance"]:
            why.append(f"{key}: {r['over_tolerance']} of {r['recorded']} over tolerance, first "
                       f"at {r['first_divergence_s']} s")
        elif r["recorded"] != r["replayed"]:
            why.append(f"{key}: {r['recorded']} recorded but {r['replayed']} replayed")
    return bool(why), why


def _print_result(result: dict[str, Any], out: TextIO) -> None:
    p, pl = result["pose"], result["plan"]
    out.write(f"  pose:   {p['recorded']} recorded, {p['replayed']} replayed; max error "
              f"{_fmt(p['max_error_m'])} m, RMS {_fmt(p['rms_error_m'])} m, max yaw error "
              f"{_fmt(p['max_yaw_error_rad'])} rad\n")
    out.write(f"  plan:   {pl['recorded']} recorded, {pl['replayed']} replayed; max Hausdorff "
              f"distance {_fmt(pl['max_hausdorff_m'])} m\n")
    for key in ("cmd_vel", "cmd_vel_nav"):
        c = result[key]
        out.write(f"  {key}: {c['recorded']} recorded, {c['replayed']} replayed; max "
                  f"difference {_fmt(c['max_linear_diff_mps'])} m/s, "
                  f"{_fmt(c['max_angular_diff_radps'])} rad/s\n")
    if "truth_rmse_m" in result:
        t = result["truth_rmse_m"]
        out.write(f"  localisation against ground truth: RMSE {t['recorded']} m recorded, "
                  f"{t['replayed']} m replayed\n")


def _fmt(v: float | None) -> str:
    return "inf" if v is None else f"{v:.6f}"


def _replay_recording(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    rec = open_recording(args.file)
    if not rec.curio:
        raise SetupError(f"{rec.path}: not a Curio recording (MCAP profile {rec.profile!r}) "
                         "nor a ROS bag with LaserScan and Odometry")
    run_start = float(rec.curio.get("start_s", "0"))
    first = _first_time(rec)
    t0 = first if int(rec.curio.get("part", "1")) > 1 else min(run_start, first)
    end = None if args.t_to is None else t0 + args.t_to
    data_dir = Path(tempfile.mkdtemp(prefix="curio-replay-"))
    timeline = _timeline(rec, args, t0, first) if args.web else None
    try:
        cfg = _replay_config(_recorded_config(rec, args), args.web, data_dir,
                             rec.curio.get("drivers_mode", "sim"))
        offset = float(rec.curio.get("time_offset_s", "0"))
        start = t0 + args.t_from
        wall0 = wall_perf_counter()
        while True:  # one run, or one more after each seek backwards on the page
            clock = SimClock(speed=_speed(args), start_s=start, epoch_wall_s=offset + start)
            recorded = Recorded()
            source = ReplaySource(recording_inputs(rec, start, end, run_start, recorded))
            capture, failed = asyncio.run(_run_app(cfg, clock, source, args.web, end, out,
                                                   end is None, timeline))
            if timeline is None or timeline.restart_from_s is None or failed:
                break
            start = t0 + timeline.restart_from_s
            cfg = _on_port(cfg, timeline.port)
        wall = wall_perf_counter() - wall0
        if timeline is not None and not timeline.at_end:
            recorded.until(clock.now())  # finished early: compare what was replayed
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)
    if source.error is not None:
        raise SetupError(f"{rec.path}: {source.error}")
    if recorded.last_t is None:
        raise SetupError(f"--from {args.t_from:g}: the recording holds nothing from there on "
                         f"(it starts at 0 s and has no inputs or outputs after {args.t_from:g} s)")
    if failed:
        err.write(f"curio replay: part {failed[0][0]} failed: {failed[0][1]}\n")
        return 1
    tol = Tolerances(pose_tol_m=args.pose_tol, plan_tol_m=args.plan_tol)
    result = _compare(recorded, capture, start, tol)
    diverged, why = _verdict(result)
    span = clock.now() - start
    out.write(f"replayed {rec.path.name}: {span:.1f} s from {args.t_from:g} s in {wall:.1f} s "
              f"wall ({span / wall if wall > 0 else 0:.0f}x real time)"
              f"{' (truncated file)' if rec.truncated else ''}\n")
    out.write("  inputs: " + ", ".join(f"{k} {v}" for k, v in sorted(source.published.items()))
              + "\n")
    if recorded.seeded_from is not None:
        p = recorded.seeded_from.pose
        out.write(f"  started from the recorded pose ({p.x:.3f}, {p.y:.3f}, {p.yaw:.3f}); "
                  "commands before the start are not replayed\n")
    _print_result(result, out)
    out.write("DIVERGED:\n    " + "\n    ".join(why) + "\n" if diverged
              else f"reproduced: every pose within {args.pose_tol:g} m\n")
    if args.report:
        atomic_write_json(args.report, {
            "file": str(rec.path), "from_s": args.t_from, "to_s": args.t_to,
            "replayed_s": round(span, 3), "wall_time_s": round(wall, 3),
            "inputs": dict(source.published), "diverged": diverged, "divergences": why,
            "seeded_from": to_jsonable(recorded.seeded_from, 6), **to_jsonable(result)})
        out.write(f"  report: {args.report}\n")
    return 1 if diverged else 0


def _on_port(cfg: Config, port: int | None) -> Config:
    """``cfg`` with the dashboard on ``port`` (a restarted replay keeps the page's address)."""
    if port is None:
        return cfg
    return cfg.model_copy(update={"web": cfg.web.model_copy(update={"port": port})})


def _bag_config(args: argparse.Namespace, data_dir: Path, laser: Any) -> Config:
    sets = [
        *args.overrides, "drivers.mode=sim", "ekf.enabled=false", "record.enabled=false",
        "foxglove.enabled=false", f"web.enabled={'true' if args.web else 'false'}",
        f'data_dir="{data_dir}"', f"robot.laser_pose=[{laser.x}, {laser.y}, {laser.yaw}]"]
    if args.map_yaml:
        if not Path(args.map_yaml).is_file():
            raise SetupError(f"--map: no such file: {args.map_yaml}")
        sets.append(f'localization.map_yaml="{Path(args.map_yaml).resolve()}"')
    if args.start:
        try:
            x, y, yaw = (float(v) for v in args.start.split(","))
        except ValueError:
            raise SetupError(f"--start takes X,Y,YAW (m, m, rad), got '{args.start}'") from None
        sets.append(f"sim.start=[{x}, {y}, {yaw}]")
    return load_config(args.config, sets)


def _replay_bag(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from dataclasses import replace

    from curio.estimation.rosbag import iter_bag, laser_mount

    path = Path(args.file)
    items = sorted(iter_bag(path), key=lambda b: b.t_s)
    if not items:
        raise SetupError(f"{path}: the bag holds no scans or odometry")
    t0 = items[0].t_s
    chosen = [b for b in items if args.t_from <= b.t_s - t0
              and (args.t_to is None or b.t_s - t0 <= args.t_to)]
    inputs = [TimedInput(b.t_s - t0, i, SCAN if b.kind == "scan" else WHEEL_ODOM,
                         replace(b.msg, stamp=b.t_s - t0)) for i, b in enumerate(chosen)]
    data_dir = Path(tempfile.mkdtemp(prefix="curio-replay-"))
    try:
        cfg = _bag_config(args, data_dir, laser_mount(path))
        start = inputs[0].t_s if inputs else 0.0
        clock = SimClock(speed=_speed(args), start_s=start, epoch_wall_s=t0 + start)
        source = ReplaySource(iter(inputs))
        wall0 = wall_perf_counter()
        capture, failed = asyncio.run(_run_app(cfg, clock, source, args.web, None, out, True))
        wall = wall_perf_counter() - wall0
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)
    if failed:
        err.write(f"curio replay: part {failed[0][0]} failed: {failed[0][1]}\n")
        return 1
    return _bag_report(args, path, source, capture, clock.now() - start, wall, out)


def _bag_report(args: argparse.Namespace, path: Path, source: ReplaySource, capture: _Capture,
                span: float, wall: float, out: TextIO) -> int:
    poses = capture.series[POSE.name]
    states = Counter(m.state for _, m in capture.series[LOCALIZATION.name])
    total = max(1, sum(states.values()))
    length = sum(a.pose.distance_to(b.pose) for (_, a), (_, b) in itertools.pairwise(poses))
    final = poses[-1][1].pose if poses else None
    out.write(f"replayed the ROS bag {path.name}: {span:.1f} s in {wall:.1f} s wall; "
              f"{source.published[SCAN.name]} scans, {source.published[WHEEL_ODOM.name]} "
              "odometry messages\n")
    out.write(f"  localisation: {len(poses)} poses; "
              + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in states.most_common())
              + f"; estimated path {length:.2f} m\n")
    if final is not None:
        out.write(f"  final pose in the map: ({final.x:.3f}, {final.y:.3f}, {final.yaw:.3f})\n")
    if args.report:
        atomic_write_json(args.report, {
            "file": str(path), "kind": "rosbag", "replayed_s": round(span, 3),
            "wall_time_s": round(wall, 3), "inputs": dict(source.published),
            "poses": len(poses), "localization_states": dict(states),
            "path_length_m": round(length, 4), "final_pose": to_jsonable(final, 6)})
    return 0


def _run(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from curio.estimation.rosbag import is_bag

    _check_times(args)
    _speed(args)
    path = Path(args.file)
    if not path.exists():
        raise SetupError(f"no such file: {path}")
    if is_bag(path):
        return _replay_bag(args, out, err)
    return _replay_recording(args, out, err)


def main(argv: list[str] | None = None, out: TextIO | None = None,
         err: TextIO | None = None) -> int:
    """Run ``curio replay`` with ``argv`` (without the ``replay`` word); return the exit code."""
    return run_command("replay", _parser(), argv, out, err, _run)
