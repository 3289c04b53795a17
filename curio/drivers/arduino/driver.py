"""The Arduino Mega base driver: ``/cmd_vel`` in, servo commands out, wheel feedback back.

:class:`ArduinoBase` talks the framed protocol of :mod:`curio.drivers.arduino.protocol` over
USB serial (pyserial-asyncio-fast). Per session it:

1. opens the port — which resets the Mega (DTR auto-reset) — and **sends nothing** until the
   firmware announces itself (INFO or STATE(BOOT)) or ``boot_wait_s`` passes, so it never
   streams into the bootloader (the original's runaway-wheels failure, hardware.md §1.2 item 7);
2. sends SET_CONFIG (servo ids, trims, the firmware watchdog ``mcu_cmd_timeout_s``, rates) and
   waits for its ACK, then ARM;
3. every ``1 / cmd_rate_hz`` converts the latest ``/cmd_vel`` with
   :func:`curio.drivers.kinematics.twist_to_servo_command` and sends SERVO_CMD — with zero
   duties when ``/cmd_vel`` is older than ``cmd_timeout_s`` or the e-stop is engaged — plus a
   HEARTBEAT at 5 Hz;
4. publishes ``/wheels`` (raw LX-16A positions from SERVO_POS; ``None`` for failed reads;
   stamped with the sample time, mapped from the Mega's clock by :class:`McuClock`),
   ``/battery`` (BATTERY), ``/servo_cmd`` (what it sent) and ``/health``;
5. re-sends the config and re-arms whenever STATE reports BOOT or the "default config" fault
   (a silent reset of the Mega), and re-arms after the firmware's link watchdog disarmed it;
6. holds all traffic while the board is quiet for more than 0.15 s (it may be in its
   bootloader after a spontaneous reset: never stream into it), and
   declares the link down when no frame arrives for ``link_timeout_s`` or the port fails
   (unplugged cable), closes it and reconnects by itself with back-off up to
   ``reconnect_max_s``. Meanwhile the firmware's own watchdog has stopped the wheels.

Health (``/health``, name ``arduino``): ``state`` is ``starting`` (opening, boot window,
configuring), ``ok``, ``degraded`` (board watchdog tripped, e-stop latched, not armed, servo
reads failing), ``error`` (link down: the message says what to check) or ``off`` (halted).
``counters``: ``crc_errors``, ``resyncs``, ``garbage_bytes``, ``length_errors`` (frames from the
board), ``mcu_rx_crc_err`` (frames to the board, as the board counts them), ``reconnects``,
``link_losses``, ``mcu_resets``, ``watchdog_trips``, ``tx_holds``, ``servo_read_failures``,
``nacks``, ``bad_payloads``, ``rx_frames``, ``tx_frames``, ``heartbeat_echo_age_ms``,
``mcu_state`` (−1 unknown, else :class:`~curio.drivers.arduino.protocol.McuState`).

With ``rc_enabled`` the board reports its RC receiver and the driver turns fresh, valid frames
into ``/cmd_vel_teleop`` (source ``rc``; the original's mapping: 1100..1900 µs to full wheel
speed and yaw rate, a switch channel above 1800 µs turns it off); the safety stage gives teleop
precedence while it is fresh.

The latched ``/estop`` is forwarded as the firmware's ESTOP (latched on the board too) and
released with ARM.

Construction (``curio/drivers/wiring.py``)::

    base = ArduinoBase(cfg.drivers.arduino, robot, bus, clock, port=port)
    parts.add(Part("arduino", run=base.run, close=base.close))
    parts.add_halt_hook(base.halt)

``port`` defaults to ``cfg.port``; in emulated mode pass ``ArduinoEmulator.port_path`` and call
``emulator.pair(base)`` (keeps a fast simulated clock from racing ahead of pty delivery; the
port is opened and closed in a worker thread, and while paired the driver holds the clock
during that work too, so emulated runs are deterministic). All timing uses the injected clock;
nothing blocks the loop. The latest RC channels (raw receiver order) are kept in ``base.rc``;
the latest per-servo status in ``base.servo_status``.

The port is opened exclusively, so a port still closing blocks the next open. :meth:`close`
(the app's last shutdown step, also right after an abrupt cancel of :meth:`run`) sends a stop,
closes the port and returns once the OS has released it (a port whose open was still under way
in its thread is closed too); a new session likewise waits for the previous port's release.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable
from typing import Any, cast

import serial_asyncio_fast

from curio.core.bus import Bus
from curio.core.clock import Clock
from curio.core.config import ArduinoConfig
from curio.core.messages import (
    BatteryState,
    DriverHealth,
    EStop,
    ServoCommand,
    Twist,
    WheelEncoders,
)
from curio.core.topics import BATTERY, CMD_VEL, CMD_VEL_TELEOP, ESTOP, SERVO_CMD, WHEELS
from curio.drivers.arduino import protocol as p
from curio.drivers.base import BaseDriver
from curio.drivers.health import HealthReporter
from curio.drivers.kinematics import twist_to_servo_command
from curio.drivers.pty import BytePacer
from curio.drivers.session import Backoff, DeviceFault, SessionLoop, wait_until
from curio.robot import RobotModel

__all__ = ["ArduinoBase", "CommandFn", "McuClock"]

log = logging.getLogger("curio.drivers.arduino")

Six = tuple[int | None, int | None, int | None, int | None, int | None, int | None]
CommandFn = Callable[[float, float, RobotModel, float], ServoCommand]
HEARTBEAT_PERIOD_S = 0.2
HEALTH_PERIOD_S = 1.0
FIRST_RECONNECT_S = 0.1  # the back-off doubles from here up to reconnect_max_s
RECOVERED_NOTE_S = 60.0  # how long an "ok" health still mentions the last problem
ACK_TIMEOUT_S = 0.3
ACK_RETRIES = 3
TX_HOLD_S = 0.15  # the board sends STATE at 10 Hz and SERVO_POS at 30 Hz: longer silence is odd
CLOSE_TIMEOUT_S = 1.0  # clock time to wait for the OS to release the port (then give up)
PACER_MAX_SPINS = 20_000  # loop turns to wait for the emulator to read what was sent
HOLD_MAX_SPINS = 100_000  # loop turns the paced clock is held for port work in a thread
PORT_HINT = ("is the Mega plugged in? Run `curio check`; on the Pi the udev rule in deploy/ "
             "names it /dev/curio-arduino, and the user needs the dialout group; no other "
             "program (arduino-cli upload, a serial monitor) may hold the port")


class McuClock:
    """Maps the Mega's ``millis()`` stamps to host clock time.

    The offset host − MCU is the smallest ``receipt time − t_ms`` seen over the last
    ``window`` reports (the report that travelled fastest), so USB latency jitter does not
    move the sample times; the window lets it follow the Mega's resonator drift (up to
    ±0.5 %). A jump back of ``t_ms`` (a reset, or the u32 wrap after 49 days) starts over.
    """

    def __init__(self, window: int = 90) -> None:
        self._offsets: deque[float] = deque(maxlen=window)
        self._last_t_ms: int | None = None

    def reset(self) -> None:
        """Forget the estimate (new session)."""
        self._offsets.clear()
        self._last_t_ms = None

    def to_host(self, t_ms: int, received_s: float, extra_ms: float = 0.0) -> float:
        """Host time, seconds, of MCU time ``t_ms`` + ``extra_ms`` (never after receipt)."""
        if self._last_t_ms is not None and t_ms < self._last_t_ms:
            self._offsets.clear()
        self._last_t_ms = t_ms
        self._offsets.append(received_s - (t_ms + extra_ms) / 1000.0)
        return min(received_s, (t_ms + extra_ms) / 1000.0 + min(self._offsets))


class _LinkLost(DeviceFault):
    """The session must end (the message says why and what to check)."""


class ArduinoBase(BaseDriver):
    """The base driver (see the module docstring).

    Args:
        cfg: ``cfg.drivers.arduino``.
        robot: the robot model (geometry and limits for the kinematics).
        bus: the application bus.
        clock: the application clock.
        port: serial device path; defaults to ``cfg.port``.
        command_fn: twist → servo command (defaults to the kinematics module's).
    """

    name = "arduino"

    def __init__(self, cfg: ArduinoConfig, robot: RobotModel, bus: Bus, clock: Clock,
                 port: str | None = None, *,
                 command_fn: CommandFn = twist_to_servo_command) -> None:
        self.cfg = cfg
        self.robot = robot
        self.bus = bus
        self.clock = clock
        self.port = port or cfg.port
        self.command_fn = command_fn
        self.decoder = p.FrameDecoder()
        self.mcu_clock = McuClock()
        self.tx_suspended = False  # test/diagnostic hook: the Pi goes silent
        self.bytes_sent = 0
        self.bytes_received = 0
        # Emulated mode only (see ArduinoEmulator.pair): keeps a simulated clock from racing
        # ahead of pty delivery. Without a peer it does nothing.
        self.pacer = BytePacer(clock, lambda: self.bytes_sent, max_spins=PACER_MAX_SPINS)
        self._writer: asyncio.StreamWriter | None = None
        self._opening: asyncio.Future[tuple[asyncio.StreamReader, asyncio.StreamWriter]] | None \
            = None
        self._closing: list[asyncio.StreamWriter] = []  # closed, not yet released by the OS
        self._closed = False
        self._rx_event = asyncio.Event()
        self._tx_seq = 0
        self._acks: dict[tuple[int, int], int] = {}
        self._twist_sub = bus.subscribe(CMD_VEL)
        self._estop_sub = bus.subscribe(ESTOP)
        self._twist: Twist | None = None
        self._twist_rx_s = -1e9
        self._estop = False
        self._halted = False
        self._quiet_s: float | None = None
        self._opened_before = False
        self._raw_reply: p.ServoRawReply | None = None
        self.rx_error_window_s = 5.0  # how long corrupt input keeps the health "degraded"
        self._rx_bad_seen = 0
        self._rx_bad_base = 0
        self._rx_bad_since_s: float | None = None
        self._rx_bad_last_s = 0.0
        # Session state.
        self.connected = False
        self.mcu_state: p.McuState | None = None
        self.mcu_faults = 0
        self.info: p.Info | None = None
        self.last_state: p.State | None = None
        self.rc: p.RcChannels | None = None
        self.servo_status: p.ServoStatus | None = None
        self._saw_boot = False
        self._configured = False
        self._need_config = False
        self._last_rx_s: float | None = None
        self._phase = "starting"
        # Health.
        self.last_error = ""
        self._last_error_s: float | None = None
        self.counters: dict[str, float] = {
            "reconnects": 0, "link_losses": 0, "rx_frames": 0, "tx_frames": 0,
            "bad_payloads": 0, "nacks": 0, "mcu_resets": 0, "watchdog_trips": 0,
            "servo_read_failures": 0, "mcu_rx_crc_err": 0, "tx_holds": 0,
            "heartbeat_echo_age_ms": -1.0, "rc_teleop": 0,
        }
        self.reporter = HealthReporter(self.name, clock, bus, log, self.counters,
                                       extra=self._link_counters, assess=self._assess,
                                       period_s=HEALTH_PERIOD_S)
        self._backoff = Backoff(FIRST_RECONNECT_S, cfg.reconnect_max_s)

    # --- public -------------------------------------------------------------------------------

    async def run(self) -> None:
        """Connect, configure, arm and drive until cancelled (or :meth:`close`); reconnect after
        any failure."""
        self._backoff.reset()
        await SessionLoop(self.clock, self._session, self._on_fault, self._backoff,
                          faults=(_LinkLost, OSError), after=self._disconnected,
                          stopped=lambda: self._closed).run()

    def _on_fault(self, exc: Exception) -> None:
        if isinstance(exc, _LinkLost):
            self._error(str(exc))
            self.counters["link_losses"] += 1
            if self._configured:
                self._backoff.reset()  # the link worked: try again soon
        else:
            self._error(f"cannot use {self.port}: {exc}; {PORT_HINT}")

    async def _disconnected(self) -> None:
        self._phase = "disconnected"
        self.publish_health(force=True)

    async def halt(self) -> None:
        """Stop the wheels now and disarm (the app's first shutdown step); stays stopped."""
        self._halted = True
        if self._writer is None:
            return
        self._send_stop()
        drained = asyncio.ensure_future(self._writer.drain())
        timer = asyncio.ensure_future(self.clock.sleep(0.2))
        try:
            await asyncio.wait({drained, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            drained.cancel()
            timer.cancel()

    async def close(self) -> None:
        """Stop the wheels, close the port and wait until the OS has released it.

        The app's last shutdown step (``Part.close``); safe after an abrupt cancel of
        :meth:`run` (whose session already closed the port: this waits for the release) and
        while :meth:`run` is still going (it then returns instead of reconnecting). A port
        whose open was still in its worker thread is closed as soon as it opens. Afterwards
        the same port can be opened again at once. Gives up after ``CLOSE_TIMEOUT_S`` of
        clock time per port (logged), dropping bytes the port would not take.
        """
        self._closed = True
        self._halted = True
        writer, self._writer = self._writer, None
        if writer is not None:
            self._send_stop(writer)
            self._retire(writer)
        opening = self._opening
        if opening is not None:
            await self._hold(opening, CLOSE_TIMEOUT_S)
            if opening.done() and not opening.cancelled() and opening.exception() is None:
                self._retire(opening.result()[1])
        await self._release_all()

    async def servo_raw(self, packet: bytes, timeout_s: float = 0.5) -> bytes | None:
        """Forward one LX-16A packet to the servo bus and return the servo's reply packet
        (``None``: no reply, as for every write). For setup tools (servo ids, limits, LEDs);
        the board refuses it while armed, so call :meth:`halt` first.

        Raises:
            RuntimeError: not connected, or the board refused (the message says why).
            TimeoutError: the board did not answer within ``timeout_s``.
        """
        if self._writer is None:
            raise RuntimeError(f"the Arduino link is not up ({self.health().message})")
        self._raw_reply = None
        seq = self._send(p.ServoRaw(packet))
        key = (seq, int(p.MsgId.SERVO_RAW))
        await wait_until(self.clock, lambda: self._raw_reply is not None or key in self._acks,
                         timeout_s, self._rx_event)
        if key in self._acks:
            status = p.AckStatus(self._acks.pop(key))
            hint = ": disarm first (halt())" if status == p.AckStatus.WRONG_STATE else ""
            raise RuntimeError(f"the Mega refused SERVO_RAW ({status.name}){hint}")
        reply = self._raw_reply
        if reply is None:
            raise TimeoutError(f"no SERVO_RAW_REPLY within {timeout_s:g} s")
        return reply.data if reply.status == 0 else None

    def health(self) -> DriverHealth:
        """The driver's health now: state, what is wrong and what to do, counters."""
        return self.reporter.snapshot()

    def publish_health(self, force: bool = False) -> None:
        """Publish ``/health`` (when forced, when due, or when the state or message changed)."""
        self.reporter.publish_if_due(force)

    # --- health -------------------------------------------------------------------------------

    def _link_counters(self) -> dict[str, float]:
        st = self.decoder.stats
        return {"crc_errors": st.crc_errors, "resyncs": st.resyncs,
                "garbage_bytes": st.garbage_bytes, "length_errors": st.length_errors,
                "mcu_state": -1 if self.mcu_state is None else int(self.mcu_state)}

    def _error(self, text: str) -> None:
        self.last_error = text
        self._last_error_s = self.clock.now()
        log.warning("arduino: %s", text)

    def _assess(self) -> tuple[str, str]:
        recent = ""
        if self.last_error and self._last_error_s is not None and \
                self.clock.now() - self._last_error_s < RECOVERED_NOTE_S:
            recent = f" (recovered from: {self.last_error})"
        if self._phase == "disconnected":
            return "error", f"link down: {self.last_error or 'not connected'}; reconnecting"
        if self._phase == "starting":
            return "starting", f"opening {self.port}"
        if self._phase == "booting":
            return "starting", (f"waiting out the Mega's boot window (up to "
                                f"{self.cfg.boot_wait_s:g} s) before sending anything")
        if self._phase == "configuring":
            return "starting", "sending SET_CONFIG and ARM"
        if self._halted:
            return "off", "halted: wheels stopped and disarmed"
        if self._quiet_s is not None:
            return "degraded", (f"the Mega has been silent for {self._quiet_s:.2f} s (resetting?):"
                                " holding all traffic until it speaks again")
        if self.mcu_state == p.McuState.ESTOP:
            return "degraded", "e-stop latched on the Mega; release the e-stop to re-arm"
        if self.mcu_state == p.McuState.TIMEOUT:
            return "degraded", ("the Mega's watchdog stopped the wheels: no valid SERVO_CMD for "
                                f"{self.cfg.mcu_cmd_timeout_s:g} s (commands lost or corrupted; "
                                "check the USB cable)")
        if self.mcu_state != p.McuState.ARMED:
            name = "unknown" if self.mcu_state is None else self.mcu_state.name
            return "degraded", f"the Mega is {name}, not armed; re-arming"
        if self._rx_bad_since_s is not None and \
                self.clock.now() - self._rx_bad_last_s <= self.rx_error_window_s:
            st = self.decoder.stats
            return "degraded", (
                f"corrupt data from the Mega: {self._rx_bad_seen - self._rx_bad_base} bad "
                f"bytes/frames recently (CRC errors {st.crc_errors}, garbage bytes "
                f"{st.garbage_bytes} in total), frames still getting through: check the USB "
                f"cable and that drivers.arduino.baud ({self.cfg.baud}) matches the firmware")
        if self.mcu_faults & p.Fault.SERVO_READ:
            return "degraded", ("a servo did not answer a position read: check the servo bus "
                                "cable, the BusLinker and the servo ids" + recent)
        return "ok", "armed, commands flowing" + recent

    # --- session ------------------------------------------------------------------------------

    async def _session(self) -> None:
        """One link session: open the port, wait out the boot window, configure, arm, drive."""
        connected = await self._connect()
        if connected is None:
            return  # close() ran while the port was opening
        reader, writer = connected
        opened_s = self.clock.now()
        reader_task = asyncio.ensure_future(self._read_loop(reader))
        try:
            await self._boot_and_configure(reader_task)
            await self._drive(reader_task, opened_s)
        except asyncio.CancelledError:
            if self._writer is writer:  # stopped abruptly (no halt first): stop the wheels
                self._send_stop(writer)
            raise
        finally:
            reader_task.cancel()
            with contextlib.suppress(BaseException):
                await reader_task
            self._retire(writer)  # close() or the next session waits for the release
            if self._writer is writer:
                self._writer = None
            self.connected = False
            self.mcu_state = None  # unknown until the board speaks again

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter] | None:
        """Open the port (once the previous one is released) and start a fresh session state;
        None when :meth:`close` ran meanwhile."""
        self._phase = "starting"
        self.publish_health()
        await self._release_all()  # the previous session's port must be free (exclusive open)
        reader, writer = await self._open()
        if self._closed:  # close() ran while the port was opening
            self._retire(writer)
            return None
        self._writer = writer
        if self._opened_before:
            self.counters["reconnects"] += 1
        self._opened_before = True
        self.decoder.reset()
        self.mcu_clock.reset()
        self._acks.clear()
        self.connected = True
        self.mcu_state = None
        self.mcu_faults = 0
        self.info = None
        self._saw_boot = False
        self._configured = False
        self._need_config = False
        self._last_rx_s = None
        return reader, writer

    async def _boot_and_configure(self, reader_task: asyncio.Future[None]) -> None:
        """Send nothing until the board announced itself (or ``boot_wait_s``), then configure
        and arm it."""
        self._phase = "booting"
        self.publish_health()
        await wait_until(self.clock, lambda: self._saw_boot or reader_task.done(),
                         self.cfg.boot_wait_s, self._rx_event)
        self._check_reader(reader_task)
        if self._last_rx_s is None:
            raise _LinkLost(f"nothing heard from {self.port} within boot_wait_s = "
                            f"{self.cfg.boot_wait_s:g} s: wrong port, sketch not flashed "
                            "(see firmware/README.md), or wrong baud rate")
        self._phase = "configuring"
        self.publish_health()
        await self._configure(reader_task)
        self._phase = "running"

    async def _drive(self, reader_task: asyncio.Future[None], opened_s: float) -> None:
        """Every ``1 / cmd_rate_hz``: keep the board configured and armed, send the command and
        the heartbeat, publish ``/health``; until the link fails."""
        next_heartbeat_s = 0.0
        async for now in self.clock.every(1.0 / self.cfg.cmd_rate_hz):
            self._check_reader(reader_task)
            if self._board_quiet(now, opened_s):
                continue
            if self._need_config:
                self._phase = "configuring"
                await self._configure(reader_task)
                self._phase = "running"
            self._handle_estop()
            if self.mcu_state == p.McuState.DISARMED and not self._estop and not self._halted:
                await self._arm(reader_task)
            if now >= next_heartbeat_s:
                next_heartbeat_s = now + HEARTBEAT_PERIOD_S
                self._send(p.Heartbeat(self._host_ms()))
            self._command(now)
            self.publish_health()
            await self.pacer.settle()

    def _board_quiet(self, now: float, opened_s: float) -> bool:
        """True while the board has been quiet too long to send to it (counted as a hold).

        Raises:
            _LinkLost: it has been quiet for ``link_timeout_s``.
        """
        last = self._last_rx_s if self._last_rx_s is not None else opened_s
        if now - last > self.cfg.link_timeout_s:
            raise _LinkLost(f"no frame from the Mega for {now - last:.2f} s "
                            "(stalled or reset board, or a bad cable)")
        if now - last > min(TX_HOLD_S, 0.5 * self.cfg.link_timeout_s):
            # The board went quiet: it may be sitting in its bootloader after a spontaneous
            # reset. Streaming into the bootloader can keep it from starting the sketch (the
            # original's runaway wheels): hold all traffic until the board speaks again (or
            # the link is declared down).
            self.counters["tx_holds"] += 1
            self._quiet_s = now - last
            self.publish_health()
            return True
        self._quiet_s = None
        return False

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """Open the port (in pyserial-asyncio-fast's worker thread), holding a paced clock."""
        opening = asyncio.ensure_future(serial_asyncio_fast.open_serial_connection(
            url=self.port, baudrate=self.cfg.baud, exclusive=True))
        self._opening = opening
        try:
            await self._hold(opening, None)
        except asyncio.CancelledError:
            # The open goes on in its thread: close the port once it is open (close() waits).
            opening.add_done_callback(self._retire_opened)
            raise
        if self._opening is opening:
            self._opening = None
        return opening.result()

    def _retire_opened(
            self, opening: asyncio.Future[tuple[asyncio.StreamReader, asyncio.StreamWriter]]
    ) -> None:
        if not opening.cancelled() and opening.exception() is None:
            self._retire(opening.result()[1])

    def _retire(self, writer: asyncio.StreamWriter) -> None:
        """Start closing ``writer``'s port (buffered bytes are still sent) and remember it
        until the OS has released it (:meth:`_release_all`)."""
        writer.close()
        if writer not in self._closing:
            self._closing.append(writer)

    async def _release_all(self) -> None:
        """Wait until every retired port is released (``CLOSE_TIMEOUT_S`` each, then give up;
        bytes the port would not take are dropped first)."""
        while self._closing:
            writer = self._closing[0]
            closed = asyncio.ensure_future(writer.wait_closed())
            try:
                await self._hold(closed, CLOSE_TIMEOUT_S)
                if not closed.done() and writer.transport.get_write_buffer_size() > 0:
                    writer.transport.abort()  # the device takes no more bytes: drop them
                    await self._hold(closed, CLOSE_TIMEOUT_S)
            finally:
                if not closed.done():
                    closed.cancel()
                elif not closed.cancelled() and closed.exception() is not None:
                    log.debug("arduino: port closed with %r", closed.exception())
            if not closed.done() or closed.cancelled():
                self._error(f"{self.port} did not close within {CLOSE_TIMEOUT_S:g} s; the next "
                            "open may find it busy")
            if writer in self._closing:
                self._closing.remove(writer)

    async def _hold(self, fut: asyncio.Future[Any], timeout_s: float | None) -> None:
        """Wait until ``fut`` (port work in a worker thread) is done, at most ``timeout_s`` of
        clock time (``None``: no limit); ``fut`` is not cancelled.

        Paired with an emulator (emulated mode) it first keeps this task runnable for up to
        ``HOLD_MAX_SPINS`` loop turns, so the ``SimClock`` does not move on by however long
        the thread happens to take (as the RPLidar driver's open does).
        """
        if self.pacer.peer_received is not None:
            for _ in range(HOLD_MAX_SPINS):
                if fut.done():
                    return
                await self.clock.sleep(0.0)
        if fut.done():
            return
        if timeout_s is None:
            await asyncio.wait({fut})
            return
        timer = asyncio.ensure_future(self.clock.sleep(timeout_s))
        try:
            await asyncio.wait({fut, timer}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            timer.cancel()

    def _check_reader(self, task: asyncio.Future[None]) -> None:
        if not task.done():
            return
        exc = task.exception() if not task.cancelled() else None
        if isinstance(exc, _LinkLost):
            raise exc
        raise _LinkLost(f"serial port {self.port} failed: {exc!r}; {PORT_HINT}")

    async def _read_loop(self, reader: asyncio.StreamReader) -> None:
        while True:
            data = await reader.read(4096)
            if not data:
                raise _LinkLost(f"{self.port} closed (cable unplugged?); {PORT_HINT}")
            self.bytes_received += len(data)
            for frame in self.decoder.feed(data):
                self._on_frame(frame)
            st = self.decoder.stats
            bad = st.crc_errors + st.length_errors + st.garbage_bytes
            if bad != self._rx_bad_seen:
                now = self.clock.now()
                if self._rx_bad_since_s is None or \
                        now - self._rx_bad_last_s > self.rx_error_window_s:
                    self._rx_bad_since_s = now
                    self._rx_bad_base = self._rx_bad_seen
                self._rx_bad_seen = bad
                self._rx_bad_last_s = now
            self._rx_event.set()

    async def _request(self, msg: p.Message, reader_task: asyncio.Future[None]) -> int:
        """Send ``msg`` and wait for its ACK (retrying); return the ACK status."""
        for _ in range(ACK_RETRIES):
            seq = self._send(msg)
            key = (seq, int(msg.MSG_ID))
            await self.pacer.settle()

            def answered(key: tuple[int, int] = key) -> bool:
                return key in self._acks or reader_task.done()

            await wait_until(self.clock, answered, ACK_TIMEOUT_S, self._rx_event)
            self._check_reader(reader_task)
            if key in self._acks:
                return self._acks.pop(key)
        raise _LinkLost(f"no ACK to {msg.MSG_ID.name} after {ACK_RETRIES} tries "
                        f"({ACK_TIMEOUT_S:g} s each): is this the Curio firmware?")

    def _set_config_msg(self) -> p.SetConfig:
        c = self.cfg
        return p.SetConfig(wheel_ids=tuple(c.wheel_ids), steer_ids=tuple(c.steer_ids),
                           steer_trim=tuple(c.steer_trim),
                           cmd_timeout_ms=round(c.mcu_cmd_timeout_s * 1000),
                           pos_rate_hz=round(c.feedback_rate_hz), status_rate_hz=1,
                           steer_move_ms=c.steer_move_ms,
                           flags=(1 if c.persist_steer_trim else 0) | (2 if c.rc_enabled else 0))

    async def _configure(self, reader_task: asyncio.Future[None]) -> None:
        if self.info is not None and self.info.proto_ver != p.PROTO_VERSION:
            raise _LinkLost(f"the Mega's firmware speaks protocol {self.info.proto_ver}, this "
                            f"driver {p.PROTO_VERSION}: flash firmware/curio_base "
                            "(firmware/README.md)")
        msg = self._set_config_msg()
        problems = msg.problems()
        if problems:
            raise _LinkLost("drivers.arduino config not accepted by the firmware: "
                            + "; ".join(problems))
        self._need_config = False
        status = await self._request(msg, reader_task)
        if status != p.AckStatus.OK:
            if status == p.AckStatus.WRONG_STATE:  # armed already: disarm, then configure
                await self._request(p.Arm(False), reader_task)
                status = await self._request(msg, reader_task)
            if status != p.AckStatus.OK:
                raise _LinkLost(f"the Mega refused SET_CONFIG ({p.AckStatus(status).name}); "
                                "check drivers.arduino wheel_ids, steer_ids, steer_trim")
        self._configured = True
        if not self._estop and not self._halted:
            await self._arm(reader_task)

    async def _arm(self, reader_task: asyncio.Future[None]) -> None:
        status = await self._request(p.Arm(True), reader_task)
        if status != p.AckStatus.OK:
            self.counters["nacks"] += 1
            self._error(f"the Mega refused ARM ({p.AckStatus(status).name})")

    def _handle_estop(self) -> None:
        for msg in self._estop_sub.drain():
            if isinstance(msg, EStop):
                if msg.engaged and not self._estop:
                    self._estop = True
                    self._send(p.Estop())
                elif not msg.engaged and self._estop:
                    self._estop = False
        if self._estop and self.mcu_state not in (p.McuState.ESTOP, None):
            self._send(p.Estop())
        if not self._estop and self.mcu_state == p.McuState.ESTOP and not self._halted:
            self._send(p.Arm(True))

    def _command(self, now: float) -> None:
        for twist in self._twist_sub.drain():
            self._twist = twist
            self._twist_rx_s = now
        v, w = (self._twist.linear_mps, self._twist.angular_radps) if self._twist else (0.0, 0.0)
        try:
            cmd = self.command_fn(v, w, self.robot, now)
        except ValueError as exc:
            self._error(f"bad /cmd_vel ({v}, {w}): {exc}; sending a stop")
            cmd = self.command_fn(0.0, 0.0, self.robot, now)
        stale = now - self._twist_rx_s > self.cfg.cmd_timeout_s
        if stale or self._estop or self._halted:
            cmd = ServoCommand(stamp=now, wheel_duty=(0, 0, 0, 0, 0, 0),
                               steer_position=cmd.steer_position,
                               steer_move_time_ms=cmd.steer_move_time_ms)
        cmd = ServoCommand(stamp=now, wheel_duty=cmd.wheel_duty,
                           steer_position=cmd.steer_position,
                           steer_move_time_ms=self.cfg.steer_move_ms)
        if self.mcu_state in (p.McuState.ARMED, p.McuState.TIMEOUT):
            moving = any(cmd.wheel_duty)
            self._send(p.ServoCmd(cmd.wheel_duty, cmd.steer_position, 1 if moving else 0))
            self.bus.publish(SERVO_CMD, cmd)

    # --- I/O ----------------------------------------------------------------------------------

    def _host_ms(self) -> int:
        return int(self.clock.now() * 1000.0) & 0xFFFFFFFF

    def _send_stop(self, writer: asyncio.StreamWriter | None = None) -> None:
        """Zero wheel duties (steering unchanged) and disarm, on ``writer`` or the session's."""
        steer = (p.STEER_UNCHANGED,) * 4
        for msg in (p.ServoCmd((0,) * 6, steer, 0), p.Arm(False)):
            self._send(msg, writer)

    def _send(self, msg: p.Message, writer: asyncio.StreamWriter | None = None) -> int:
        seq = self._tx_seq
        self._tx_seq = (seq + 1) & 0xFF
        writer = writer or self._writer
        if writer is None or self.tx_suspended or writer.is_closing():
            return seq
        data = p.encode(msg, seq)
        writer.write(data)
        self.bytes_sent += len(data)
        self.counters["tx_frames"] += 1
        return seq

    def _on_frame(self, frame: p.Frame) -> None:
        now = self.clock.now()
        self._last_rx_s = now
        self.counters["rx_frames"] += 1
        try:
            msg: Any = p.decode_message(frame)
        except p.ProtocolError as exc:
            self.counters["bad_payloads"] += 1
            log.debug("arduino: bad payload: %s", exc)
            return
        if isinstance(msg, p.ServoPos):
            positions = tuple(msg.wheel_pos[i] if msg.wheel_valid(i) else None
                              for i in range(6))
            if msg.valid_mask != 0x3FF:
                self.counters["servo_read_failures"] += 1
            stamp = self.mcu_clock.to_host(msg.t_ms, now,
                                           sum(msg.dt_ms[:6]) / 6.0)
            self.bus.publish(WHEELS, WheelEncoders(stamp=stamp, positions=cast(Six, positions)))
        elif isinstance(msg, p.State):
            self._on_state(msg)
        elif isinstance(msg, p.Ack):
            if msg.status != p.AckStatus.OK:
                self.counters["nacks"] += 1
                log.debug("arduino: NACK %s for id 0x%02X", msg.status, msg.acked_id)
            self._acks[(msg.acked_seq, msg.acked_id)] = msg.status
            if len(self._acks) > 64:
                self._acks.pop(next(iter(self._acks)))
        elif isinstance(msg, p.Battery):
            volts = msg.servo_vin_mv / 1000.0
            charger = (msg.adc_mv / 1000.0 if self.cfg.adc_is_charger
                       and msg.adc_mv != p.ADC_NOT_FITTED else None)
            self.bus.publish(BATTERY, BatteryState(stamp=now, voltage_v=volts,
                                                   low=volts < self.cfg.low_battery_v,
                                                   charger_v=charger))
        elif isinstance(msg, p.Info):
            self.info = msg
            self._saw_boot = True
            if msg.proto_ver != p.PROTO_VERSION:
                self._error(f"firmware speaks protocol {msg.proto_ver}, this driver "
                            f"{p.PROTO_VERSION}: re-flash firmware/ (see firmware/README.md)")
        elif isinstance(msg, p.ServoRawReply):
            self._raw_reply = msg
        elif isinstance(msg, p.ServoStatus):
            self.servo_status = msg
        elif isinstance(msg, p.RcChannels):
            self.rc = msg
            if self.cfg.rc_enabled:
                self._rc_teleop(msg, now)
        elif isinstance(msg, p.Log):
            log.info("mega: %s", msg.text)

    def _rc_teleop(self, msg: p.RcChannels, now: float) -> None:
        """The original's RC teleop: sticks to ``/cmd_vel_teleop`` while the switch allows."""
        c = self.cfg
        if not msg.flags & p.RC_NEW or msg.flags & (p.RC_FAILSAFE | p.RC_LOST):
            return  # no fresh, valid receiver frame: publish nothing (teleop times out)
        ch = msg.channels_us
        if len(ch) <= max(c.rc_linear_channel, c.rc_angular_channel, c.rc_enable_channel):
            return
        if ch[c.rc_enable_channel] > 1800:
            return  # teleop switched off on the transmitter

        def stick(us: int) -> float:
            return max(-1.0, min(1.0, (us - 1500) / 400.0))

        self.counters["rc_teleop"] += 1
        self.bus.publish(CMD_VEL_TELEOP, Twist(
            stamp=now, linear_mps=stick(ch[c.rc_linear_channel]) * self.robot.max_wheel_speed_mps,
            angular_radps=stick(ch[c.rc_angular_channel]) * self.robot.max_angular_radps
            * c.rc_angular_sign, source="rc"))

    def _on_state(self, msg: p.State) -> None:
        try:
            state = p.McuState(msg.state)
        except ValueError:
            self.counters["bad_payloads"] += 1
            return
        previous = self.mcu_state
        self.last_state = msg
        self.mcu_state = state
        self.mcu_faults = msg.faults
        self.counters["mcu_rx_crc_err"] = msg.rx_crc_err
        if msg.last_host_ms:
            age_ms = (self._host_ms() - msg.last_host_ms) & 0xFFFFFFFF
            self.counters["heartbeat_echo_age_ms"] = float(age_ms)
        if state == p.McuState.BOOT:
            self._saw_boot = True
        if state == p.McuState.TIMEOUT and previous != p.McuState.TIMEOUT:
            self.counters["watchdog_trips"] += 1
            self._error("the Mega's motion watchdog stopped the wheels (commands not arriving)")
        rebooted = state == p.McuState.BOOT or bool(msg.faults & p.Fault.DEFAULT_CONFIG)
        if rebooted and self._configured and not self._need_config:
            self.counters["mcu_resets"] += 1
            self._error("the Mega reset (running its default config): re-sending config, "
                        "re-arming")
            self._need_config = True
            self._configured = False
            # Re-arming takes one command cycle: say it now, or /health never shows the reset.
            self.reporter.event("driver.arduino_reset", reset_cause=int(msg.reset_cause),
                                state=state.name)
            self.publish_health(force=True)
