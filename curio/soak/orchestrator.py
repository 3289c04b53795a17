"""The soak's orchestrator (the parent process of ``curio soak``).

It prepares the rover's data directory (on a size-limited tmpfs when it can:
:mod:`curio.soak.disk`) with named tokens for its clients, draws the campaign
(:mod:`curio.soak.plan`), compiles the kernels into the cache when some are missing (``curio
warmup``, as after an install), then starts the rover (``python -m curio.soak.rover SPEC``) and
supervises it:

* every line the rover writes is taken by :class:`~curio.soak.observe.Observations`;
* ``kill_me`` (a ``kill9`` or ``corrupt_file`` fault): after the fault's delay the rover gets
  ``SIGKILL``; the orchestrator checks every persisted file (:mod:`curio.soak.files`),
  damages one for ``corrupt_file``, and starts a new rover where the simulated world stood: its
  clock at the last beat's time plus ``RESTART_S`` (what a real restart takes: systemd's
  ``RestartSec`` and start-up), the simulated rover at the last beat's pose with its battery,
  the campaign's remaining faults;
* a rover that crashes (exits by itself) or stops reporting for ``HUNG_S`` of wall time is
  counted as a failure and restarted the same way (as systemd would);
* when the building's clock reaches the end, the clients stop, the commands still without an
  answer are asked for one last time, and the rover is stopped cleanly.

The scripted clients (:mod:`curio.soak.clients`) run in this process, over real sockets, and
outlive every rover.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import json
import logging
import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from curio.core.clock import RealClock, wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.soak.clients import SoakClient, client_specs
from curio.soak.day import TIMEZONE, schedule_times, start_wall_s
from curio.soak.disk import DataDisk
from curio.soak.files import Expected, check_files, corrupt
from curio.soak.ledger import Ledger
from curio.soak.link import parse_line
from curio.soak.observe import Observations, RestartWatch
from curio.soak.plan import KINDS, PlannedFault, draw_campaign

__all__ = ["RESTART_S", "Orchestrator", "SoakOptions"]

log = logging.getLogger("curio.soak")

RESTART_S = 15.0
HUNG_S = 180.0
FINAL_GRACE_S = 5.0
WALL = RealClock()


@dataclass
class SoakOptions:
    """``curio soak``'s options (see :mod:`curio.commands.soak`)."""

    hours: float = 24.0
    clients: int = 10
    faults: int = 200
    seed: int = 1
    config: Path | None = None
    overrides: list[str] = field(default_factory=list)
    workdir: Path = Path("var/soak")
    disk: str = "auto"
    disk_mb: int = 384
    keep: bool = False
    kinds: list[str] | None = None
    start: dt.time | None = None
    visitors: int = 6
    progress: Callable[[dict[str, Any]], None] | None = None


def tour_starts(start_wall: float, end_wall: float) -> list[float]:
    """The scheduled tours' start times (building clock) between the soak's start and end."""
    from zoneinfo import ZoneInfo

    tz = ZoneInfo(TIMEZONE)
    day = dt.datetime.fromtimestamp(start_wall, tz).date()
    out: list[float] = []
    while True:
        for times in schedule_times():
            for hhmm in times:
                t = dt.datetime.combine(day, dt.time.fromisoformat(hhmm), tzinfo=tz).timestamp()
                if start_wall < t < end_wall:
                    out.append(t)
        day += dt.timedelta(days=1)
        if dt.datetime.combine(day, dt.time(0), tzinfo=tz).timestamp() > end_wall:
            return sorted(out)


class Orchestrator:
    """Runs one soak (see the module docstring)."""

    def __init__(self, opts: SoakOptions) -> None:
        self.opts = opts
        self.dir = opts.workdir.resolve() / f"seed{opts.seed}"
        self.disk = DataDisk(self.dir / "disk", opts.disk_mb, opts.disk)
        self.data_dir = self.dir / "disk" / "data"
        self.ledger = Ledger()
        self.obs = Observations(self.ledger)
        self.expected = Expected()
        self.rng = np.random.default_rng([opts.seed, 7])
        self.start_wall = start_wall_s(opts.start)
        self.end_wall = self.start_wall + opts.hours * 3600.0
        self.plan: list[PlannedFault] = []
        self.boot = 0
        self.port: int | None = None
        self.up = False
        self.clients: list[SoakClient] = []
        self.failures: list[str] = []
        self.file_checks: list[dict[str, Any]] = []
        self.started = wall_perf_counter()
        self.proc: asyncio.subprocess.Process | None = None
        self.kill_request: dict[str, Any] | None = None
        self.load: list[list[float]] = []
        self.child_cpu_s = 0.0
        self.notes: list[str] = []
        self._lines: Any = None
        # Set when the soak is stopped before its end (Ctrl-C, SIGTERM): why, and when.
        self.stopped_early: dict[str, Any] | None = None
        self._finisher: asyncio.Task[None] | None = None

    # --- setup --------------------------------------------------------------------------------

    def _overrides(self) -> list[str]:
        cfg_overrides = [
            f'data_dir="{self.data_dir}"', 'drivers.mode="emulated"', f"sim.seed={self.opts.seed}",
            'bt.tree="tour"', "bt.speak=false", "bt.tour_stops=[]", "bt.tour_loop=false",
            "web.enabled=true", "web.port=0",
            f'tours.timezone="{TIMEZONE}"', "record.enabled=true", "record.max_total_mb=96",
            "record.max_file_mb=16", "foxglove.enabled=false",
            f"sim.crowd.visitors={self.opts.visitors}",
            # The dock at home, its contacts read on the Arduino's A0 (emulated): the rover
            # docks after every tour and charges there (--set dock.enabled=false: no dock).
            "dock.enabled=true", "drivers.arduino.adc_is_charger=true",
        ]
        # the data directory is the soak's own (checked between runs): it comes last
        return cfg_overrides + list(self.opts.overrides) + [f'data_dir="{self.data_dir}"']

    def prepare(self) -> None:
        """The work directory, the data filesystem, the tokens and the campaign."""
        import shutil

        if self.dir.exists():
            self._umount_stale()
            shutil.rmtree(self.dir, ignore_errors=True)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.disk.mount()
        self.data_dir.mkdir(parents=True, exist_ok=True)
        from curio.web.tokens import TokenStore

        store = TokenStore(self.data_dir / "web_tokens.json")
        admin = store.ensure_admin()
        tokens = {"admin": admin.token} if admin is not None else {}
        for i in range(self.opts.clients):
            if i % 3 != 0 and i != 2:
                tokens[f"op{i}"] = store.create(f"op{i}", "operator").token
        tokens["kiosk"] = store.create("kiosk", "kiosk").token
        self.expected.tokens = dict(tokens)
        kinds = [k for k in (self.opts.kinds or KINDS)
                 if k != "disk_full" or self.disk.method == "tmpfs"]
        if self.disk.method != "tmpfs":
            self.notes.append(f"disk_full faults left out: {self.disk.reason}")
        self.plan = draw_campaign(self.opts.seed, self.start_wall, self.end_wall,
                                  self.opts.faults, tour_starts(self.start_wall, self.end_wall),
                                  kinds)
        specs = client_specs(self.opts.clients, tokens)
        self.clients = [SoakClient(s, self.ledger, np.random.default_rng([self.opts.seed, 99,
                                                                            s.index]),
                                   self._address) for s in specs]
        self.expected.path_edits = [c.path for c in self.clients if c.path is not None]
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """As after an install: ``curio warmup`` once, before the first rover, when some
        kernel has nothing in the cache. Each rover then starts as ``curio run`` does and only
        loads them; compiling inside a rover's start took longer than ``HUNG_S`` on a busy
        machine."""
        from curio import kernels
        from curio.commands.warmup import config_args, run_warmup

        cfg = load_config(self.opts.config, self._overrides())
        kernels.use_cache_dir(cfg)
        if all(k.cached for k in kernels.status()):
            return
        log.info("soak: compiling the kernels first (curio warmup)")
        run_warmup(config_args(self.opts.config, self._overrides()))

    def _umount_stale(self) -> None:
        """A tmpfs left mounted by an earlier soak that was killed."""
        import subprocess

        if os.path.ismount(self.dir / "disk"):
            subprocess.run(["umount", "-l", str(self.dir / "disk")], capture_output=True,
                           check=False)

    def _address(self) -> tuple[str, int] | None:
        return ("127.0.0.1", self.port) if self.up and self.port else None

    # --- one rover ------------------------------------------------------------------------------

    def _spec(self, restart: dict[str, Any] | None) -> dict[str, Any]:
        beat = self.obs.beat
        spec: dict[str, Any] = {
            "config": str(self.opts.config) if self.opts.config else None,
            "overrides": self._overrides(), "boot": self.boot, "seed": self.opts.seed,
            "end_wall_s": self.end_wall, "restart": restart,
            "ballast": str(self.disk.ballast) if self.disk.ballast else None,
        }
        if beat is None:
            spec.update(start_sim_s=0.0, start_wall_s=self.start_wall - 10.0, lapsed_s=0.0)
        else:
            spec.update(start_sim_s=float(beat["sim_s"]) + RESTART_S,
                        start_wall_s=float(beat["wall_s"]) + RESTART_S,
                        battery_v=beat.get("battery_v"), lapsed_s=beat.get("lapsed_s", 0.0))
            truth = beat["truth"]
            spec["overrides"].append(f"sim.start=[{truth[0]!r}, {truth[1]!r}, {truth[2]!r}]")
        done = {*self.obs.faults, *self.obs.injected}
        if restart:
            done.add(restart["fault"]["id"])
        spec["faults"] = [f.to_json() for f in self.plan if f.id not in done]
        return spec

    async def _start(self, restart: dict[str, Any] | None) -> asyncio.subprocess.Process:
        spec_path = self.dir / f"boot{self.boot}.json"
        spec_path.write_text(json.dumps(self._spec(restart), indent=1), encoding="utf-8")
        stderr = open(self.dir / f"boot{self.boot}.log", "wb")  # noqa: SIM115 - the child's
        try:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "curio.soak.rover", str(spec_path),
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=stderr,
                cwd=str(REPO_ROOT), env={**os.environ, "PYTHONUNBUFFERED": "1"},
                limit=1 << 22)
        finally:
            stderr.close()
        self.proc = proc
        if self._lines is not None:
            self._lines.close()
        self._lines = open(self.dir / f"boot{self.boot}.jsonl", "wb")  # noqa: SIM115
        return proc

    async def _supervise(self, proc: asyncio.subprocess.Process) -> str:
        """Read the rover's lines until it exits; return why it ended."""
        assert proc.stdout is not None
        ended = "exited"
        killer: asyncio.Task[None] | None = None
        self._finisher = None
        if self.stopped_early is not None:  # stopped while no rover ran: end this one at once
            self._finisher = asyncio.ensure_future(self._finish(proc))
        while True:
            try:
                line = await WALL.wait_for(proc.stdout.readline(), HUNG_S)
            except TimeoutError:
                ended = "hung"
                with contextlib.suppress(ProcessLookupError):
                    proc.send_signal(signal.SIGKILL)
                break
            if not line:
                break
            if self._lines is not None:
                self._lines.write(line)
            msg = parse_line(line)
            if msg is None:
                continue
            self.obs.take(msg)
            t = msg["t"]
            if t == "hello":
                self.port = int(msg["port"])
                self.up = True
                self._after_hello()
            elif t == "kill_me" and killer is None:
                self.kill_request = msg
                killer = asyncio.ensure_future(self._kill_later(proc, msg))
            elif t == "end" and self._finisher is None:
                self._finisher = asyncio.ensure_future(self._finish(proc))
            elif t == "beat":
                self._progress()
            elif t == "soak_error":
                self.failures.append(f"the soak's {msg.get('part')} failed in run {self.boot}: "
                                     f"{msg.get('error')}")
        self.up = False
        await proc.wait()
        if self._finisher is not None:
            self._finisher.cancel()
            with contextlib.suppress(BaseException):
                await self._finisher
        if killer is not None:
            with contextlib.suppress(BaseException):
                await killer
            return "killed"
        if ended == "hung":
            return "hung"
        return "done" if any(e.get("t") == "done" for e in self.obs.ends[-1:]) else (
            f"exited {proc.returncode}")

    async def _kill_later(self, proc: asyncio.subprocess.Process, msg: dict[str, Any]) -> None:
        delay = float((msg.get("params") or {}).get("delay_ms", 0)) / 1000.0
        await WALL.sleep(delay)
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGKILL)

    async def _finish(self, proc: asyncio.subprocess.Process) -> None:
        """The end: stop the clients, ask about unanswered commands, stop the rover."""
        for client in self.clients:
            client.stopping = True
        try:
            await WALL.sleep(FINAL_GRACE_S)
            await self._last_lookups()
        except Exception:  # the rover must be stopped whatever happened here
            log.exception("soak: the last lookups failed")
            self.notes.append("the last lookups of unanswered commands failed (see the log)")
        if proc.stdin is not None:
            with contextlib.suppress(ConnectionError):
                proc.stdin.write(b'{"t": "stop"}\n')
                await proc.stdin.drain()

    async def _last_lookups(self) -> None:
        """Ask the rover about every command still without an answer."""
        for client in self.clients:
            for rec in self.ledger.pending(client.spec.label):
                got = await client.lookup(rec.rid)
                if got is None:
                    continue
                rec.lookups.append(str(got.get("state", "")))
                answer = got.get("answer")
                if isinstance(answer, dict) and answer.get("kind"):
                    self.ledger.answer(rec.rid, str(answer["kind"]),
                                       str(answer.get("message", "")),
                                       float(answer.get("stamp", 0.0)), "lookup")

    def _after_hello(self) -> None:
        w = self.obs.watch
        if w is None or w.boot != self.boot or w.corruption is None:
            return
        checks = check_files(self.data_dir, self.expected, self._map_yaml())
        w.data_after = [c.__dict__ for c in checks if c.name in ("tours", "schedules", "paths")]

    def _map_yaml(self) -> Path:
        cfg = load_config(self.opts.config, self._overrides())
        return cfg.resolve(cfg.sim.world)

    # --- restarts -------------------------------------------------------------------------------

    def _after_kill(self, why: str) -> dict[str, Any] | None:
        """Check the files of the dead rover; corrupt one if asked; describe the restart."""
        beat = self.obs.beat or {}
        req = self.kill_request if why == "killed" else None
        self.kill_request = None
        self._lost_with_the_rover(why)
        checks = check_files(self.data_dir, self.expected, self._map_yaml())
        record: dict[str, Any] = {"boot": self.boot, "why": why,
                                  "checks": [c.__dict__ for c in checks]}
        self.file_checks.append(record)
        fault = None
        if req is not None:
            fault = next((f for f in self.plan if f.id == int(req["id"])), None)
        if fault is None:
            fault = PlannedFault(0, why, float(beat.get("wall_s", 0.0)), {})
        watch = RestartWatch(self.boot + 1, fault.id, fault.kind, float(beat.get("sim_s", 0.0)),
                             float(beat.get("wall_s", 0.0)), list(beat.get("truth") or []),
                             beat.get("tour"), bool(beat.get("estop")))
        watch.files = record["checks"]
        if fault.kind == "corrupt_file":
            watch.corruption = corrupt(self.data_dir, str(fault.params["file"]),
                                       str(fault.params["how"]), self.rng)
        self.obs.restart_begins(watch)
        return {"fault": fault.to_json(), "killed_sim_s": watch.killed_sim_s,
                "killed_wall_s": watch.killed_wall_s}

    def _lost_with_the_rover(self, why: str) -> None:
        """A fault injected but never judged because the rover died (crashed, hung) is a
        failed fault, not a missing one."""
        for fid, msg in self.obs.injected.items():
            if fid not in self.obs.faults:
                self.obs.faults[fid] = {
                    "t": "fault", "phase": "result", "id": fid, "kind": msg.get("kind"),
                    "params": msg.get("params"), "injected_s": msg.get("sim_s"),
                    "outcome": "failed", "detected_health_s": None, "detected_log_s": None,
                    "recover_s": None, "outage_s": None,
                    "notes": [f"the rover {why} while this fault was judged"]}

    # --- the whole soak -------------------------------------------------------------------------

    async def run(self) -> None:
        """Run the soak (:func:`curio.soak.report.build_report` makes its report after)."""
        self.prepare()
        tasks = [asyncio.ensure_future(c.run()) for c in self.clients]
        sampler = asyncio.ensure_future(self._sample_load())
        restart: dict[str, Any] | None = None
        try:
            while True:
                proc = await self._start(restart)
                why = await self._supervise(proc)
                self._child_cpu()
                if why == "done" or self._ended() or self.stopped_early is not None:
                    break
                if why != "killed":
                    self.failures.append(f"rover run {self.boot} ended: {why}")
                if self.obs.beat is None or len(self.failures) > 5:
                    self.failures.append("the rover cannot be restarted: giving up")
                    break
                restart = self._after_kill(why)
                self.boot += 1
        finally:
            for client in self.clients:
                client.stopping = True
            for task in (*tasks, sampler):
                task.cancel()
            for task in (*tasks, sampler):
                with contextlib.suppress(BaseException):
                    await task
            if self.proc is not None and self.proc.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    self.proc.kill()
            final = check_files(self.data_dir, self.expected, self._map_yaml())
            self.file_checks.append({"boot": self.boot, "why": "end",
                                     "checks": [c.__dict__ for c in final]})
            self.disk.unmount(self.dir / "data-copy" if self.opts.keep else None)

    def stop_early(self, why: str) -> None:
        """End the soak now, as at its end (the clients stop, unanswered commands are asked
        about, the rover stops cleanly), and mark the report as stopped early with ``why``."""
        if self.stopped_early is not None:
            return
        self.stopped_early = {"why": why,
                              "wall_s": round(wall_perf_counter() - self.started, 1),
                              "building_h": round(self._building_h(), 3)}
        log.warning("soak: stopping early (%s); the report covers what ran", why)
        proc = self.proc
        if proc is not None and proc.returncode is None and self._finisher is None:
            self._finisher = asyncio.ensure_future(self._finish(proc))

    def _building_h(self) -> float:
        """Building hours run so far (the last beat's clock since the start)."""
        beat = self.obs.beat or {}
        return max(0.0, (float(beat.get("wall_s", self.start_wall)) - self.start_wall) / 3600.0)

    def progress_text(self) -> str:
        """Where the soak is, for people: ``7.90 of 24 building hours``."""
        return f"{self._building_h():.2f} of {self.opts.hours:g} building hours"

    def _ended(self) -> bool:
        """The building's clock reached the end: a rover that dies now is not restarted."""
        beat = self.obs.beat
        return beat is not None and float(beat["wall_s"]) >= self.end_wall

    def _child_cpu(self) -> None:
        """CPU seconds used by the rovers so far (every finished child process)."""
        import resource

        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.child_cpu_s = ru.ru_utime + ru.ru_stime

    async def _sample_load(self) -> None:
        while True:
            with contextlib.suppress(OSError):
                self.load.append([round(wall_perf_counter() - self.started, 1),
                                  *[round(x, 2) for x in os.getloadavg()]])
            await WALL.sleep(30.0)

    def _progress(self) -> None:
        beat = self.obs.beat
        if beat is None or self.opts.progress is None:
            return
        span = self.end_wall - self.start_wall
        done = min(1.0, max(0.0, (float(beat["wall_s"]) - self.start_wall) / span))
        self.opts.progress({
            "fraction": done, "sim_s": beat["sim_s"], "wall_s": wall_perf_counter() - self.started,
            "faults": len(self.obs.faults), "planned": len(self.plan), "boot": self.boot,
            "collisions": len(self.obs.collisions), "commands": len(self.ledger.commands)})
