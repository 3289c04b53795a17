"""The emulator's firmware model: boot, ACK rules, state machine and watchdogs (no I/O)."""

from __future__ import annotations

from curio.drivers.arduino import protocol as p
from curio.drivers.arduino.emulator import FirmwareModel


class Servos:
    """Records what the model tells the servos."""

    def __init__(self) -> None:
        self.writes: list[tuple[tuple[int, ...], tuple[int, ...], int]] = []

    def write(self, duties: tuple[int, ...], steer: tuple[int, ...], move_ms: int,
              now_ms: int) -> None:
        self.writes.append((duties, steer, move_ms))

    def read_positions(self) -> tuple[int, tuple[int, ...], tuple[int, ...]]:
        return 0x3FF, (1, 2, 3, 4, 5, 6), (500,) * 4

    def read_vin_mv(self) -> tuple[int, ...]:
        return (7400, 7300, 7500, 7400, 7400, 7400, 7200, 7400, 7400, 7400)


class Rig:
    def __init__(self) -> None:
        self.servos = Servos()
        self.out = bytearray()
        self.model = FirmwareModel(self.servos, self.out.extend)
        self.dec = p.FrameDecoder()
        self.seq = 0
        self.now = 0

    def send(self, msg: p.Message) -> None:
        self.model.on_bytes(p.encode(msg, self.seq), self.now)
        self.seq = (self.seq + 1) & 0xFF

    def run(self, ms: int) -> None:
        for _ in range(ms // 5):
            self.now += 5
            self.model.tick(self.now)

    def received(self) -> list[p.Message]:
        msgs = [p.decode_message(f) for f in self.dec.feed(bytes(self.out))]
        self.out.clear()
        return msgs


def _servo_cmd(duty: int) -> p.ServoCmd:
    return p.ServoCmd((duty,) * 6, (500,) * 4, 1)


def test_boot_sequence_stops_wheels_first() -> None:
    rig = Rig()
    rig.model.boot(0)
    assert rig.servos.writes[0][0] == (0,) * 6
    msgs = rig.received()
    assert isinstance(msgs[0], p.State) and msgs[0].state == p.McuState.BOOT
    assert isinstance(msgs[1], p.Info) and msgs[1].proto_ver == p.PROTO_VERSION
    assert isinstance(msgs[2], p.State) and msgs[2].state == p.McuState.DISARMED
    assert msgs[2].faults & p.Fault.DEFAULT_CONFIG


def test_arm_drive_watchdog_resume() -> None:
    rig = Rig()
    rig.model.boot(0)
    rig.send(_servo_cmd(400))
    acks = [m for m in rig.received() if isinstance(m, p.Ack)]
    assert acks[-1].status == p.AckStatus.WRONG_STATE
    rig.send(p.SetConfig(cmd_timeout_ms=200))
    acks = [m for m in rig.received() if isinstance(m, p.Ack)]
    assert (acks[-1].acked_id, acks[-1].status) == (p.MsgId.SET_CONFIG, p.AckStatus.OK)
    assert not rig.model.faults & p.Fault.DEFAULT_CONFIG
    rig.send(p.Arm(True))
    rig.send(_servo_cmd(400))
    rig.run(100)
    assert rig.model.state == p.McuState.ARMED
    assert rig.servos.writes[-1][0] == (400,) * 6
    rig.run(200)  # > 200 ms without SERVO_CMD
    assert rig.model.state == p.McuState.TIMEOUT
    assert rig.servos.writes[-1][0] == (0,) * 6
    states = [m for m in rig.received() if isinstance(m, p.State)]
    assert states[-1].state == p.McuState.TIMEOUT
    assert states[-1].faults & p.Fault.MOTION_WATCHDOG
    rig.send(_servo_cmd(-100))
    rig.run(50)
    assert rig.model.state == p.McuState.ARMED
    assert rig.servos.writes[-1][0] == (-100,) * 6


def test_estop_latches_until_arm() -> None:
    rig = Rig()
    rig.model.boot(0)
    rig.send(p.Arm(True))
    rig.send(_servo_cmd(300))
    rig.send(p.Estop())
    assert rig.model.state == p.McuState.ESTOP
    assert rig.servos.writes[-1][0] == (0,) * 6
    rig.send(_servo_cmd(300))
    rig.run(50)
    assert rig.model.state == p.McuState.ESTOP
    assert rig.servos.writes[-1][0] == (0,) * 6
    rig.send(p.Arm(True))
    assert rig.model.state == p.McuState.ARMED


def test_link_watchdog_disarms_and_reports() -> None:
    rig = Rig()
    rig.model.boot(0)
    rig.send(p.Arm(True))
    rig.run(2100)
    assert rig.model.state == p.McuState.DISARMED
    msgs = rig.received()
    assert any(isinstance(m, p.ServoPos) for m in msgs)
    battery = [m for m in msgs if isinstance(m, p.Battery)]
    assert battery and battery[-1].servo_vin_mv == 7400  # the median


def test_bad_frames_are_counted_and_refused() -> None:
    rig = Rig()
    rig.model.boot(0)
    frame = bytearray(p.encode(p.Arm(True), 1))
    frame[-1] ^= 0x01
    rig.model.on_bytes(bytes(frame), 1)
    assert rig.model.state == p.McuState.DISARMED
    assert rig.model.rx_crc_err == 1
    rig.model.on_bytes(p.encode_frame(0x3F, 2), 2)
    rig.model.on_bytes(p.encode_frame(p.MsgId.SET_CONFIG, 3, b"\x01" * 22), 3)
    acks = [m for m in rig.received() if isinstance(m, p.Ack)]
    assert [a.status for a in acks] == [p.AckStatus.UNKNOWN_ID, p.AckStatus.BAD_VALUE]
