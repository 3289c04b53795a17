"""Byte-exact emulator of the Arduino Mega base controller, served on a pseudo-terminal.

It speaks the protocol of :mod:`curio.drivers.arduino.protocol` exactly as the firmware does
(``firmware/curio_base/src/controller.cpp``): :class:`FirmwareModel` mirrors the firmware's
state machine (BOOT → DISARMED → ARMED ⇄ TIMEOUT, latched ESTOP), its motion watchdog (wheels
to 0 after ``cmd_timeout_ms`` without SERVO_CMD), its link watchdog (DISARMED after 2 s
without any valid frame), its ACK rules and its report rates.
``tests/integration/test_firmware_host.py`` checks that the compiled firmware core and this
emulator answer a scripted session byte for byte alike (timestamps aside). Differences: the
servo side is the simulator's world rather than LX-16A packets (so SERVO_RAW gets "no
reply"), and SERVO_POS leaves at the start of a sweep rather than at its end.

The servo side is the simulator's world (helper H1's ``curio/sim``), through three calls:

* ``world.apply_servo_command(ServoCommand)`` — what the wheels and steering servos are told,
  every control cycle (duties already zeroed by the watchdog, e-stop or disarm);
* ``world.wheel_positions()`` — six raw LX-16A wheel readings (with the dead zone);
* ``world.battery_voltage()`` — the servo supply, volts.

**Construction for emulated mode** (``curio/drivers/wiring.py``)::

    emu = ArduinoEmulator(world, clock, seed=cfg.sim.seed)
    emu.open()                       # creates the pty; emu.port_path is a stable symlink
    base = ArduinoBase(cfg.drivers.arduino, robot, bus, clock, port=emu.port_path)
    emu.pair(base)                   # SimClock: hold virtual time until pty bytes are read
    parts.add(Part("arduino-emulator", run=emu.run, close=emu.aclose))
    parts.add(Part("arduino", run=base.run, close=base.close))
    parts.add_halt_hook(base.halt)

``port_path`` is a symlink in a private temporary directory that always points at the current
pseudo-terminal (like the udev name ``/dev/curio-arduino``), so an unplug/replug cycle, which
makes a new pty, keeps the same path.

**Like the real board, opening the port resets it** (the Mega's DTR auto-reset): the emulator
notices the host opening the pty (the master's hang-up condition clears), drops everything
during ``boot_delay_s`` (the bootloader), then boots: wheels stopped, STATE(BOOT), INFO,
DISARMED with the "default config" fault.

**Fault knobs** (methods, usable while running): :meth:`unplug` / :meth:`replug` (the USB
cable: the pty disappears, and comes back as a fresh one), :meth:`inject_garbage`,
:meth:`corrupt_tx` (corrupt the CRC of the next N frames sent to the host),
:meth:`corrupt_rx` (drop frames from the host as CRC errors for a while), :meth:`truncate_tx`,
:meth:`reset` (a reboot: wheels stopped, boot window, disarmed), :meth:`stall` (the board stops
talking and listening for a while, its watchdogs still running), ``servo_read_fail_rate``
(per-read failures in SERVO_POS) and ``firmware.proto_version`` (an old firmware). An RC
receiver: set ``firmware.rc_channels_us`` (µs, raw receiver order) and ``firmware.rc_flags``
(``protocol.RC_FAILSAFE`` / ``RC_LOST``). Times are in seconds of the injected clock.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from curio.core.clock import Clock, SimClock
from curio.core.config import Config
from curio.core.messages import ServoCommand
from curio.core.parts import Part
from curio.drivers.arduino import protocol as p
from curio.drivers.pty import BytePacer, PtyDevice

__all__ = ["ArduinoEmulator", "EmulatorWorld", "FirmwareModel", "ServoSide"]

log = logging.getLogger("curio.drivers.arduino.emulator")

FW_MAJOR = 1
FW_MINOR = 0
FW_BUILD = 20261121
LINK_TIMEOUT_MS = 2000
STATE_PERIOD_MS = 100
INTER_BYTE_TIMEOUT_MS = 20
RESET_POWER_ON = 0x01
RESET_EXTERNAL = 0x02
PACER_MAX_SPINS = 20000  # loop turns to hold a fast simulated clock for the driver's reads
Six = tuple[int, int, int, int, int, int]
Four = tuple[int, int, int, int]


class EmulatorWorld(Protocol):
    """What the emulator needs from the simulator world."""

    def apply_servo_command(self, cmd: ServoCommand) -> None:
        """Drive the wheels and steering servos."""
        ...

    def wheel_positions(self) -> Any:
        """Six raw LX-16A wheel position readings (FL, ML, BL, FR, MR, BR)."""
        ...

    def battery_voltage(self) -> float:
        """Servo supply voltage, volts."""
        ...


class ServoSide(Protocol):
    """The servo bus as the firmware model sees it (the world, or a test double)."""

    def write(self, duties: tuple[int, ...], steer: tuple[int, ...], move_ms: int,
              now_ms: int) -> None:
        """Send the wheel duties and steering targets of one control cycle."""
        ...

    def read_positions(self) -> tuple[int, tuple[int, ...], tuple[int, ...]]:
        """One sweep: (valid_mask, six wheel readings, four steering readings)."""
        ...

    def read_vin_mv(self) -> tuple[int, ...]:
        """Ten supply readings, mV."""
        ...


def _median(values: list[int]) -> int:
    s = sorted(values)
    n = len(s)
    return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) // 2


@dataclass
class FirmwareModel:
    """The firmware core's behaviour in Python (mirrors ``firmware/curio_base/src/controller.cpp``).

    Time enters only as ``now_ms`` arguments (milliseconds, like ``millis()``); output frames go
    to ``send(bytes)``. Call :meth:`boot` once, :meth:`on_bytes` with received bytes and
    :meth:`tick` often (every few ms).
    """

    servos: ServoSide
    send: Callable[[bytes], None]
    config: p.SetConfig = field(default_factory=p.SetConfig)
    state: p.McuState = p.McuState.BOOT
    faults: int = 0
    duties: tuple[int, ...] = (0,) * 6
    steer: tuple[int, ...] = (500,) * 4
    last_cmd_ms: int = 0
    last_rx_ms: int = 0
    last_host_ms: int = 0
    rx_crc_err: int = 0
    rx_ok: int = 0
    reset_cause: int = RESET_POWER_ON
    tx_seq: int = 0
    last_byte_ms: int = 0
    next_control_ms: int = 0
    next_state_ms: int = 0
    next_status_ms: int = 0
    decoder: p.FrameDecoder = field(default_factory=p.FrameDecoder)
    proto_version: int = p.PROTO_VERSION  # what INFO announces (a knob: "old firmware")
    rc_channels_us: tuple[int, ...] | None = None  # an RC receiver (None: none fitted)
    rc_flags: int = 0  # extra RC flags (failsafe, lost)
    rc_frames: int = 0
    next_rc_ms: int = 0

    # --- output ---------------------------------------------------------------------------------

    def _emit(self, msg: p.Message) -> None:
        frame = p.encode(msg, self.tx_seq)
        self.tx_seq = (self.tx_seq + 1) & 0xFF
        self.send(frame)

    def _emit_state(self, now_ms: int) -> None:
        self._emit(p.State(t_ms=now_ms, state=self.state, faults=self.faults,
                           last_host_ms=self.last_host_ms, rx_crc_err=self.rx_crc_err,
                           rx_ok=self.rx_ok, loop_max_us=0, reset_cause=self.reset_cause))
        self.next_state_ms = now_ms + STATE_PERIOD_MS

    def _set_state(self, state: p.McuState, now_ms: int) -> None:
        if state != self.state:
            self.state = state
            self._emit_state(now_ms)

    def _stop_wheels(self) -> None:
        self.duties = (0,) * 6

    def _config_crc(self) -> int:
        return p.crc16(self.config.pack())

    # --- lifecycle ------------------------------------------------------------------------------

    def boot(self, now_ms: int, reset_cause: int = RESET_POWER_ON) -> None:
        """``setup()``: wheels stopped first, default config, BOOT + INFO, then DISARMED."""
        self.config = p.SetConfig()
        self.reset_cause = reset_cause
        self.state = p.McuState.BOOT
        self.faults = int(p.Fault.DEFAULT_CONFIG)
        self._stop_wheels()
        self.steer = (500,) * 4
        self.decoder.reset()
        self.tx_seq = 0
        self.rx_crc_err = 0
        self.rx_ok = 0
        self.last_host_ms = 0
        self.servos.write(self.duties, self.steer, self.config.steer_move_ms, now_ms)
        self._emit_state(now_ms)
        self._emit(p.Info(self.proto_version, FW_MAJOR, FW_MINOR, FW_BUILD, self._config_crc()))
        self.last_rx_ms = now_ms
        self.last_cmd_ms = now_ms
        self.next_control_ms = now_ms
        self.next_status_ms = now_ms
        self._set_state(p.McuState.DISARMED, now_ms)

    # --- input ----------------------------------------------------------------------------------

    def on_bytes(self, data: bytes, now_ms: int) -> None:
        """Feed bytes received from the host."""
        if self.decoder.pending and now_ms - self.last_byte_ms > INTER_BYTE_TIMEOUT_MS:
            self.decoder.reset()  # a frame cut short: drop it, as the firmware does
        self.last_byte_ms = now_ms
        before = self.decoder.stats.crc_errors
        frames = self.decoder.feed(data)
        self.rx_crc_err = (self.rx_crc_err + self.decoder.stats.crc_errors - before) & 0xFFFF
        for frame in frames:
            self.rx_ok = (self.rx_ok + 1) & 0xFFFF
            self.last_rx_ms = now_ms
            self._on_frame(frame, now_ms)

    def _ack(self, frame: p.Frame, status: p.AckStatus) -> None:
        self._emit(p.Ack(frame.seq, frame.msg_id, status))

    def _on_frame(self, frame: p.Frame, now_ms: int) -> None:
        mid = frame.msg_id
        payload = frame.payload
        if mid == p.MsgId.SERVO_CMD:
            if len(payload) != p.ServoCmd.SIZE:
                self._ack(frame, p.AckStatus.BAD_LENGTH)
                return
            cmd = p.ServoCmd.unpack(payload)
            if self.state not in (p.McuState.ARMED, p.McuState.TIMEOUT):
                self._ack(frame, p.AckStatus.WRONG_STATE)
                return
            self.duties = tuple(max(-1000, min(1000, d)) for d in cmd.wheel_duty)
            self.steer = tuple(old if new == p.STEER_UNCHANGED else min(new, 1000)
                               for old, new in zip(self.steer, cmd.steer_pos, strict=True))
            self.last_cmd_ms = now_ms
            self.faults &= ~int(p.Fault.MOTION_WATCHDOG)
            self._set_state(p.McuState.ARMED, now_ms)
        elif mid == p.MsgId.HEARTBEAT:
            if len(payload) != 4:
                self._ack(frame, p.AckStatus.BAD_LENGTH)
                return
            self.last_host_ms = p.Heartbeat.unpack(payload).host_ms
        elif mid == p.MsgId.SET_CONFIG:
            if len(payload) != p.SetConfig.SIZE:
                self._ack(frame, p.AckStatus.BAD_LENGTH)
                return
            cfg = p.SetConfig.unpack(payload)
            if cfg.problems():
                self._ack(frame, p.AckStatus.BAD_VALUE)
                return
            if self.state == p.McuState.ARMED:
                self._ack(frame, p.AckStatus.WRONG_STATE)
                return
            self.config = cfg
            self.faults &= ~int(p.Fault.DEFAULT_CONFIG)
            self._ack(frame, p.AckStatus.OK)
        elif mid == p.MsgId.ESTOP:
            if payload:
                self._ack(frame, p.AckStatus.BAD_LENGTH)
                return
            self._stop_wheels()
            self.servos.write(self.duties, self.steer, self.config.steer_move_ms, now_ms)
            self._set_state(p.McuState.ESTOP, now_ms)
            self._ack(frame, p.AckStatus.OK)
        elif mid == p.MsgId.ARM:
            if len(payload) != 1 or payload[0] > 1:
                self._ack(frame, p.AckStatus.BAD_LENGTH if len(payload) != 1
                          else p.AckStatus.BAD_VALUE)
                return
            self._stop_wheels()
            if payload[0] == 1:
                if self.state == p.McuState.BOOT:
                    self._ack(frame, p.AckStatus.WRONG_STATE)
                    return
                self.last_cmd_ms = now_ms
                self.faults &= ~int(p.Fault.MOTION_WATCHDOG)
                self._set_state(p.McuState.ARMED, now_ms)
            else:
                self._set_state(p.McuState.DISARMED, now_ms)
            self._ack(frame, p.AckStatus.OK)
        elif mid == p.MsgId.GET_INFO:
            self._emit(p.Info(self.proto_version, FW_MAJOR, FW_MINOR, FW_BUILD, self._config_crc()))
        elif mid == p.MsgId.SERVO_RAW:
            if self.state == p.McuState.ARMED:
                self._ack(frame, p.AckStatus.WRONG_STATE)
                return
            # The emulator's servos are the simulator's: raw frames get no reply.
            self._emit(p.ServoRawReply(status=1))
        else:
            self._ack(frame, p.AckStatus.UNKNOWN_ID)

    # --- periodic -------------------------------------------------------------------------------

    def tick(self, now_ms: int) -> None:
        """Run the watchdogs and the periodic reports due at ``now_ms``."""
        if self.state == p.McuState.ARMED and now_ms - self.last_cmd_ms > \
                self.config.cmd_timeout_ms:
            self._stop_wheels()
            self.faults |= int(p.Fault.MOTION_WATCHDOG)
            self._set_state(p.McuState.TIMEOUT, now_ms)
        if self.state in (p.McuState.ARMED, p.McuState.TIMEOUT) and \
                now_ms - self.last_rx_ms > LINK_TIMEOUT_MS:
            self._stop_wheels()
            self._set_state(p.McuState.DISARMED, now_ms)
        if now_ms >= self.next_control_ms:
            self.next_control_ms = max(self.next_control_ms + 1000 // self.config.pos_rate_hz,
                                       now_ms)
            if self.state != p.McuState.ARMED:
                self._stop_wheels()
            self.servos.write(self.duties, self.steer, self.config.steer_move_ms, now_ms)
            mask, wheels, steer = self.servos.read_positions()
            if mask != 0x3FF:
                self.faults |= int(p.Fault.SERVO_READ)
            else:
                self.faults &= ~int(p.Fault.SERVO_READ)
            dt = tuple(min(255, 2 * i) for i in range(10))
            self._emit(p.ServoPos(now_ms, mask, wheels, steer, dt))
        if now_ms >= self.next_status_ms:
            self.next_status_ms = max(self.next_status_ms + 1000 // self.config.status_rate_hz,
                                      now_ms)
            vin = list(self.servos.read_vin_mv())
            ids = (*self.config.wheel_ids, *self.config.steer_ids)
            entries = tuple(
                p.ServoStatusEntry(sid, v, 0xFF, 1 if i < 6 else 0, 0xFF, 0)
                for i, (sid, v) in enumerate(zip(ids, vin, strict=True)))
            self._emit(p.ServoStatus(now_ms, entries))
            charger = getattr(self.servos, "read_charger_mv", None)
            self._emit(p.Battery(_median(vin), charger() if charger is not None
                                 else p.ADC_NOT_FITTED))
        if now_ms >= self.next_state_ms:
            self._emit_state(now_ms)
        if self.config.flags & 0x02 and self.rc_channels_us is not None and \
                now_ms >= self.next_rc_ms:  # RC at 20 Hz when enabled and a receiver talks
            self.next_rc_ms = now_ms + 50
            self.rc_frames = (self.rc_frames + 1) & 0xFF
            self._emit(p.RcChannels(now_ms, p.RC_NEW | self.rc_flags, self.rc_frames,
                                    self.rc_channels_us))


@dataclass
class _WorldServos:
    """Adapts the simulator world to :class:`ServoSide`, with steering slew and read faults."""

    world: EmulatorWorld
    rng: np.random.Generator
    read_fail_rate: float = 0.0
    steer_trim: tuple[int, ...] = (0, 0, 0, 0)
    steer_units_per_s: float = 1560.0
    _steer_now: list[float] = field(default_factory=lambda: [500.0] * 4)
    _last_ms: int | None = None
    _last_wheels: tuple[int, ...] = (0,) * 6

    def write(self, duties: tuple[int, ...], steer: tuple[int, ...], move_ms: int,
              now_ms: int) -> None:
        dt_s = 0.0 if self._last_ms is None else max(0, now_ms - self._last_ms) / 1000.0
        self._last_ms = now_ms
        for i, target in enumerate(steer):
            step = self.steer_units_per_s * dt_s
            cur = self._steer_now[i]
            self._steer_now[i] = cur + max(-step, min(step, target - cur))
        self.world.apply_servo_command(ServoCommand(
            stamp=now_ms / 1000.0, wheel_duty=cast(Six, tuple(duties)),
            steer_position=cast(Four, tuple(steer)), steer_move_time_ms=move_ms))

    def read_positions(self) -> tuple[int, tuple[int, ...], tuple[int, ...]]:
        wheels = [int(w) for w in self.world.wheel_positions()]
        mask = 0x3FF
        if self.read_fail_rate > 0.0:
            for i in range(6):
                if self.rng.random() < self.read_fail_rate:
                    mask &= ~(1 << i)
                    wheels[i] = self._last_wheels[i]
        self._last_wheels = tuple(wheels)
        steer = tuple(round(s) for s in self._steer_now)
        return mask, tuple(wheels), steer

    def read_vin_mv(self) -> tuple[int, ...]:
        mv = round(self.world.battery_voltage() * 1000.0)
        return (max(0, min(0xFFFF, mv)),) * 10

    def read_charger_mv(self) -> int:
        """A0: the dock contacts' voltage through a divider (0xFFFF: no dock in the world)."""
        read = getattr(self.world, "charger_voltage", None)
        volts = read() if read is not None else None
        if volts is None:
            return p.ADC_NOT_FITTED
        return max(0, min(0xFFFE, round(float(volts) * 1000.0)))


class ArduinoEmulator:
    """The Arduino Mega base controller on a pseudo-terminal (see the module docstring).

    Args:
        world: the simulator world (:class:`EmulatorWorld`).
        clock: the application clock (a ``SimClock`` in emulated mode, real time in tests).
        boot_delay_s: the bootloader window after a reset / port open, seconds.
        tick_s: how often the firmware loop runs, seconds.
        seed: seeds the fault randomness (``servo_read_fail_rate``).
        link_dir: where the stable ``port_path`` symlink lives (default: a private temp dir).
    """

    def __init__(self, world: EmulatorWorld, clock: Clock, *, boot_delay_s: float = 0.5,
                 tick_s: float = 0.01, seed: int = 0, link_dir: str | Path | None = None,
                 name: str = "curio-arduino") -> None:
        self.world = world
        self.clock = clock
        self.boot_delay_s = boot_delay_s
        self.tick_s = tick_s
        self._rng = np.random.default_rng(seed)
        self.device = PtyDevice(name, self._on_bytes, None if link_dir is None else Path(link_dir),
                                watch_host=True)
        self.servos = _WorldServos(world, self._rng)
        self.firmware = FirmwareModel(self.servos, self._send)
        self._booting_until: float | None = None
        self._booted = False
        self._stalled_until = -1.0
        self._corrupt_rx_until = -1.0
        self._corrupt_tx = 0
        self._truncate_tx = 0
        self._pending_reset_cause = RESET_POWER_ON
        # Counters for tests and `curio emulate`.
        self.boots = 0
        self.opens = 0
        self.pacer = BytePacer(clock, lambda: self.bytes_out, max_spins=PACER_MAX_SPINS)

    @classmethod
    def for_world(cls, world: EmulatorWorld, clock: Clock, cfg: Config, seed: int,
                  link: Path | None = None) -> ArduinoEmulator:
        """The board on the simulator's ``world`` (emulated mode, ``curio emulate arduino``).

        Args:
            world: the simulator's world (servos and battery).
            clock: the application clock.
            cfg: the configuration (unused: the board's config comes from the driver).
            seed: the fault randomness.
            link: the device path to serve (default: ``curio-arduino`` in a temp dir).
        """
        return cls(world, clock, seed=seed, link_dir=link.parent if link else None,
                   name=link.name if link else "curio-arduino")

    def parts(self) -> list[Part]:
        """What runs the emulator: its firmware loop."""
        return [Part("arduino-emulator", run=self.run, close=self.aclose)]

    # --- properties -----------------------------------------------------------------------------

    @property
    def state(self) -> p.McuState:
        """The firmware state (BOOT while the bootloader runs)."""
        return self.firmware.state if self._booted else p.McuState.BOOT

    @property
    def wheel_duties(self) -> tuple[int, ...]:
        """The duties the wheels are running at now (zero unless ARMED and commanded)."""
        return self.firmware.duties if self._booted else (0,) * 6

    @property
    def host_connected(self) -> bool:
        """Whether a client has the port open."""
        return self.device.host_open

    @property
    def port_path(self) -> str:
        """The stable device path a driver opens (a symlink to the current pty)."""
        return self.device.path

    @property
    def path(self) -> str:
        """:attr:`port_path` (every serial emulator has a ``path``)."""
        return self.device.path

    @property
    def bytes_in(self) -> int:
        """Bytes read from the host so far (also those the bootloader dropped)."""
        return self.device.bytes_read

    @property
    def bytes_out(self) -> int:
        """Bytes sent to the host so far."""
        return self.device.bytes_written

    @property
    def servo_read_fail_rate(self) -> float:
        """Probability that one wheel read fails in a sweep (its valid bit is cleared)."""
        return self.servos.read_fail_rate

    @servo_read_fail_rate.setter
    def servo_read_fail_rate(self, rate: float) -> None:
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"servo_read_fail_rate must be 0..1, got {rate}")
        self.servos.read_fail_rate = rate

    # --- pty management -------------------------------------------------------------------------

    def open(self) -> str:
        """Create the pseudo-terminal and the ``port_path`` symlink; return ``port_path``."""
        self.device.open()
        return self.port_path

    def close(self) -> None:
        """Close the pty and remove the symlink (and its directory if the emulator made it)."""
        self.device.close()

    def pair(self, driver: Any) -> None:
        """Pace virtual time with ``driver`` (an ``ArduinoBase`` on this emulator's port).

        Acts only on a ``SimClock`` running faster than 2× real time (emulated mode): each side
        then holds the clock until the other has read what it wrote, so pty delivery delays
        never look like a stalled link. Both objects must count their bytes
        (``bytes_sent``/``bytes_received`` on the driver, ``bytes_out``/``bytes_in`` here).
        """
        speed = getattr(self.clock, "speed", 1.0)
        if not isinstance(self.clock, SimClock) or (speed is not None and speed <= 2.0):
            return  # real time (or close to it): delivery is quick enough, pacing would only
            # burn CPU
        self.pacer.peer_received = lambda: int(driver.bytes_received)
        driver.pacer.peer_received = lambda: self.bytes_in

    async def aclose(self) -> None:
        """:meth:`close` as a coroutine (for ``Part.close``)."""
        self.close()

    # --- fault knobs ------------------------------------------------------------------------------

    def unplug(self) -> None:
        """Pull the USB cable: the pty and the symlink disappear; the board keeps running on
        battery power, so its motion watchdog stops the wheels."""
        self.device.unplug()

    def replug(self) -> None:
        """Plug the cable back in: a fresh pty behind the same ``port_path``."""
        self.open()

    def reset(self) -> None:
        """Reboot the board: wheels stop at once, bootloader window, then BOOT/INFO/DISARMED."""
        self._start_boot(RESET_EXTERNAL)

    def inject_garbage(self, data: bytes | int = 64) -> None:
        """Send garbage bytes to the host (``int``: that many pseudo-random bytes)."""
        if isinstance(data, int):
            data = self._rng.integers(0, 256, size=data, dtype=np.uint8).tobytes()
        self._write(data)

    def corrupt_tx(self, frames: int = 1) -> None:
        """Flip one bit in each of the next ``frames`` frames sent to the host (CRC errors)."""
        self._corrupt_tx += frames

    def truncate_tx(self, frames: int = 1) -> None:
        """Cut the next ``frames`` frames sent to the host short (truncated frames)."""
        self._truncate_tx += frames

    def corrupt_rx(self, duration_s: float) -> None:
        """For ``duration_s``, every frame from the host arrives corrupted (counted as a CRC
        error by the board and dropped)."""
        self._corrupt_rx_until = self.clock.now() + duration_s

    def stall(self, duration_s: float) -> None:
        """For ``duration_s`` the board neither sends nor reads (a hung USB link); its own
        watchdogs keep running and stop the wheels."""
        self._stalled_until = self.clock.now() + duration_s

    # --- internals --------------------------------------------------------------------------------

    def _now_ms(self) -> int:
        return int(self.clock.now() * 1000.0) & 0xFFFFFFFF

    def _start_boot(self, cause: int) -> None:
        self.firmware.duties = (0,) * 6
        self.firmware.state = p.McuState.BOOT
        self.servos.write((0,) * 6, self.firmware.steer, 50, self._now_ms())
        self._booted = False
        self._booting_until = self.clock.now() + self.boot_delay_s
        self._pending_reset_cause = cause

    def _send(self, frame: bytes) -> None:
        if self._corrupt_tx > 0:
            self._corrupt_tx -= 1
            b = bytearray(frame)
            b[-3 if len(b) > 7 else -1] ^= 0x10
            frame = bytes(b)
        elif self._truncate_tx > 0:
            self._truncate_tx -= 1
            frame = frame[: max(3, len(frame) // 2)]
        self._write(frame)

    def _write(self, data: bytes) -> None:
        if not self.device.host_open or self._stalled():
            return
        if self.device.write(data) < len(data):
            log.debug("pty buffer full: %d bytes dropped", len(data))

    def _stalled(self) -> bool:
        return self.clock.now() < self._stalled_until

    def _on_bytes(self, data: bytes) -> None:
        if not self._booted or self._stalled():
            return  # the bootloader (or a hung board) drops what it gets
        if self.clock.now() < self._corrupt_rx_until:
            b = bytearray(data)
            for i in range(len(b) - 1):
                if b[i] == p.SYNC0 and b[i + 1] == p.SYNC1 and i + 5 < len(b):
                    b[i + 5] ^= 0x01
            data = bytes(b)
        self.firmware.on_bytes(data, self._now_ms())

    def _poll_host_open(self) -> None:
        """While nobody has the port open, watch for a client opening it (DTR reset)."""
        if self.device.poll_host():
            self.opens += 1
            self._start_boot(RESET_EXTERNAL)

    async def run(self) -> None:
        """Serve until cancelled: watch the port, run the firmware loop every ``tick_s``."""
        if not self.device.plugged:
            self.open()
        try:
            async for now in self.clock.every(self.tick_s):
                self._poll_host_open()
                if not self._booted and self._booting_until is not None and \
                        now >= self._booting_until:
                    self._booting_until = None
                    self._booted = True
                    self.boots += 1
                    self.firmware.boot(self._now_ms(), self._pending_reset_cause)
                elif self._booted:
                    self.firmware.tick(self._now_ms())
                if self.device.host_open:
                    await self.pacer.settle()
        finally:
            self.device.stop_reading()
