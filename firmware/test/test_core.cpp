// Unit tests of the portable firmware core (host build): CRC, frames and their resync, LX-16A
// packets, and the controller's state machine, watchdogs and servo-bus traffic.
#include <stdio.h>
#include <string.h>

#include <vector>

#include "../curio_base/src/controller.h"
#include "../curio_base/src/lx16a.h"
#include "../curio_base/src/protocol.h"
#include "../curio_base/src/sumd.h"
#include "../host/sim_servos.h"

using namespace curio;

static int g_failed = 0;
static int g_checks = 0;
#define CHECK(cond)                                                   \
  do {                                                                \
    ++g_checks;                                                       \
    if (!(cond)) {                                                    \
      ++g_failed;                                                     \
      fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                 \
  } while (0)

static std::vector<uint8_t> hex(const char* s) {
  std::vector<uint8_t> out;
  unsigned v;
  while (sscanf(s, " %2x", &v) == 1) {
    out.push_back((uint8_t)v);
    while (*s == ' ') ++s;
    s += 2;
  }
  return out;
}

static std::vector<uint8_t> frame(uint8_t id, uint8_t seq, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> out(payload.size() + FRAME_OVERHEAD);
  out.resize(encode_frame(out.data(), id, seq, payload.data(), (uint8_t)payload.size()));
  return out;
}

static void test_crc_and_vectors() {
  const uint8_t check[] = "123456789";
  CHECK(crc16(check, 9) == 0x29B1);
  uint8_t hb[4];
  put_u32(hb, 1000);
  CHECK(frame(MSG_HEARTBEAT, 1, std::vector<uint8_t>(hb, hb + 4)) == hex("CA FE 04 01 05 E8 03 00 00 86 0E"));
  CHECK(frame(MSG_ESTOP, 3, {}) == hex("CA FE 00 03 03 AC A9"));
  std::vector<uint8_t> cmd(21);
  int16_t duties[6] = {530, 530, 530, -530, -530, -530};
  for (int i = 0; i < 6; ++i) put_u16(&cmd[2 * i], (uint16_t)duties[i]);
  for (int i = 0; i < 4; ++i) put_u16(&cmd[12 + 2 * i], 500);
  cmd[20] = 1;
  CHECK(frame(MSG_SERVO_CMD, 2, cmd) ==
        hex("CA FE 15 02 02 12 02 12 02 12 02 EE FD EE FD EE FD F4 01 F4 01 F4 01 F4 01 01 C1 02"));  // hardware.md prints a stray trailing 21
}

static std::vector<Frame> parse(FrameParser& p, const std::vector<uint8_t>& bytes, uint32_t t = 0) {
  std::vector<Frame> out;
  Frame f;
  for (uint8_t b : bytes) {
    p.push(b, t);
    while (p.next(f)) out.push_back(f);
  }
  return out;
}

static void test_parser_resync() {
  FrameParser p;
  std::vector<uint8_t> good = frame(MSG_ESTOP, 7, {});
  std::vector<uint8_t> stream = hex("00 CA 13 CA CA FE");  // garbage ending in a false sync
  stream.push_back(0xC8);                                  // LEN 200: waits, then CRC fails
  std::vector<uint8_t> bad = frame(MSG_ARM, 1, {1});
  bad[5] ^= 0x01;                                          // one flipped bit
  stream.insert(stream.end(), bad.begin(), bad.end());
  stream.insert(stream.end(), good.begin(), good.end());
  std::vector<uint8_t> pad(210, 0x55);
  stream.insert(stream.end(), pad.begin(), pad.end());
  stream.insert(stream.end(), good.begin(), good.end());
  std::vector<Frame> got = parse(p, stream);
  CHECK(got.size() == 2);
  CHECK(got.size() == 2 && got[0].seq == 7 && got[0].msg_id == MSG_ESTOP && got[1].len == 0);
  CHECK(p.crc_errors >= 2);
  std::vector<uint8_t> big = hex("CA FE C9 00 00");  // LEN 201 is rejected at once
  parse(p, big);
  CHECK(p.length_errors == 1);
  // A frame cut short is dropped after the 20 ms inter-byte timeout.
  FrameParser q;
  std::vector<uint8_t> half(good.begin(), good.begin() + 4);
  parse(q, half, 0);
  std::vector<Frame> later = parse(q, good, 100);
  CHECK(later.size() == 1 && q.truncated == 1);
}

static void test_lx16a() {
  uint8_t b[16];
  CHECK(std::vector<uint8_t>(b, b + lx16a::read_request(b, 11, lx16a::POS_READ)) == hex("55 55 0B 03 1C D5"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::motor_mode(b, 11, 500)) == hex("55 55 0B 07 1D 01 00 F4 01 DA"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::motor_mode(b, 21, -530)) == hex("55 55 15 07 1D 01 00 EE FD DA"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::position_mode(b, 111)) == hex("55 55 6F 07 1D 00 00 00 00 6C"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::move_time(b, 111, 500, 50)) == hex("55 55 6F 07 01 F4 01 32 00 61"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::angle_offset_adjust(b, 111, -10)) == hex("55 55 6F 04 11 F6 85"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::read_request(b, 11, lx16a::VIN_READ)) == hex("55 55 0B 03 1B D6"));
  CHECK(std::vector<uint8_t>(b, b + lx16a::read_request(b, 0xFE, lx16a::ID_READ)) == hex("55 55 FE 03 0E F0"));
  lx16a::Parser p;
  std::vector<uint8_t> s = hex("55 55 0B 03 1C D5 13 55 55 0B 05 1C 3E FF 00 55 55 0B 05 1C 3E FF 96");
  lx16a::Packet pk;
  std::vector<lx16a::Packet> got;
  for (uint8_t x : s) {
    p.push(x);
    while (p.next(pk)) got.push_back(pk);
  }
  CHECK(got.size() == 2);  // the echoed request and the good reply; the bad checksum is dropped
  CHECK(got.size() == 2 && got[1].n == 2 && get_i16(got[1].params) == -194);
  CHECK(p.bad_checksums == 1);
  CHECK(lx16a::reading_from_count(500) == 500);
  CHECK(lx16a::reading_from_count(1306) == -194);
  CHECK(lx16a::reading_from_count(1200) == 1193);
  CHECK(lx16a::reading_from_count(-1) == -1);
}

struct Capture : HostLink {
  FrameParser parser;
  std::vector<Frame> frames;
  void write(const uint8_t* d, size_t n) override {
    Frame f;
    for (size_t i = 0; i < n; ++i) {
      parser.push(d[i], 0);
      while (parser.next(f)) frames.push_back(f);
    }
  }
  int count(uint8_t id) const {
    int n = 0;
    for (const Frame& f : frames) n += f.msg_id == id;
    return n;
  }
  const Frame* last(uint8_t id) const {
    for (size_t i = frames.size(); i-- > 0;)
      if (frames[i].msg_id == id) return &frames[i];
    return nullptr;
  }
};

static const uint8_t IDS[NUM_SERVOS] = {11, 12, 13, 21, 22, 23, 111, 131, 211, 231};

struct Rig {
  Capture host;
  SimServoBus bus{IDS, NUM_SERVOS};
  Controller ctrl{host, bus};
  uint32_t now = 0;
  uint8_t seq = 0;
  void send(uint8_t id, const std::vector<uint8_t>& payload) {
    for (uint8_t b : frame(id, seq++, payload)) ctrl.on_host_byte(b, now);
  }
  void run(uint32_t ms) {
    for (uint32_t i = 0; i < ms; ++i) {
      ++now;
      bus.advance(now);
      ctrl.poll(now);
    }
  }
  void command(int16_t duty) {
    std::vector<uint8_t> p(21);
    for (int i = 0; i < 6; ++i) put_u16(&p[2 * i], (uint16_t)duty);
    for (int i = 0; i < 4; ++i) put_u16(&p[12 + 2 * i], 500);
    send(MSG_SERVO_CMD, p);
  }
};

static void test_controller() {
  Rig r;
  r.bus.servo(11);  // exists
  r.ctrl.boot(0, 0x01);
  CHECK(r.ctrl.state() == STATE_DISARMED);
  CHECK(r.ctrl.faults() & FAULT_DEFAULT_CONFIG);
  CHECK(r.host.frames.size() >= 3 && r.host.frames[0].msg_id == MSG_STATE && r.host.frames[0].payload[4] == STATE_BOOT);
  CHECK(r.host.count(MSG_INFO) == 1);
  r.run(100);
  CHECK(r.host.count(MSG_SERVO_POS) >= 2);
  const Frame* pos = r.host.last(MSG_SERVO_POS);
  CHECK(pos && get_u16(pos->payload + 4) == 0x3FF);
  // SERVO_CMD before ARM is refused and moves nothing.
  r.command(500);
  const Frame* ack = r.host.last(MSG_ACK);
  CHECK(ack && ack->payload[1] == MSG_SERVO_CMD && ack->payload[2] == ACK_WRONG_STATE);
  // SET_CONFIG with a 300 ms watchdog, then ARM.
  Config c;
  config_defaults(c);
  c.cmd_timeout_ms = 300;
  c.steer_trim[2] = 40;
  std::vector<uint8_t> cp(CONFIG_SIZE);
  config_pack(c, cp.data());
  r.send(MSG_SET_CONFIG, cp);
  ack = r.host.last(MSG_ACK);
  CHECK(ack && ack->payload[1] == MSG_SET_CONFIG && ack->payload[2] == ACK_OK);
  CHECK(!(r.ctrl.faults() & FAULT_DEFAULT_CONFIG));
  cp[1] = cp[2];  // duplicate ids are refused
  r.send(MSG_SET_CONFIG, cp);
  CHECK(r.host.last(MSG_ACK)->payload[2] == ACK_BAD_VALUE);
  r.send(MSG_ARM, {1});
  CHECK(r.ctrl.state() == STATE_ARMED);
  r.run(50);
  CHECK(r.bus.servo(211)->trim == 40);
  CHECK(r.bus.servo(211)->saved_trim == 0);  // not persisted unless flags bit0
  {
    Rig q;
    q.ctrl.boot(0, 0x01);
    Config k;
    config_defaults(k);
    k.steer_trim[0] = -10;
    k.flags = 0x01;
    std::vector<uint8_t> kp(CONFIG_SIZE);
    config_pack(k, kp.data());
    q.send(MSG_SET_CONFIG, kp);
    q.run(50);
    CHECK(q.bus.servo(111)->trim == -10 && q.bus.servo(111)->saved_trim == -10);
  }
  for (int i = 0; i < 10; ++i) {
    r.command(500);
    r.run(50);
  }
  CHECK(r.bus.servo(11)->duty == 500 && r.bus.servo(23)->duty == 500);
  int16_t p0 = get_i16(r.host.last(MSG_SERVO_POS)->payload + 6);
  r.command(500);
  r.run(100);
  int16_t p1 = get_i16(r.host.last(MSG_SERVO_POS)->payload + 6);
  CHECK(p1 != p0);  // the wheels turn and the feedback shows it
  // Motion watchdog: silence for longer than 300 ms stops every wheel and reports TIMEOUT.
  r.run(400);
  CHECK(r.ctrl.state() == STATE_TIMEOUT);
  CHECK(r.ctrl.faults() & FAULT_MOTION_WATCHDOG);
  for (uint8_t i = 0; i < NUM_WHEELS; ++i) CHECK(r.bus.servo(IDS[i])->duty == 0);
  const Frame* st = r.host.last(MSG_STATE);
  CHECK(st && st->payload[4] == STATE_TIMEOUT);
  // The next command resumes without re-arming.
  r.command(-300);
  r.run(60);
  CHECK(r.ctrl.state() == STATE_ARMED && r.bus.servo(12)->duty == -300);
  // ESTOP latches until ARM; SERVO_CMD cannot override it.
  r.send(MSG_ESTOP, {});
  r.run(5);
  CHECK(r.ctrl.state() == STATE_ESTOP && r.bus.servo(12)->duty == 0);
  r.command(800);
  r.run(60);
  CHECK(r.ctrl.state() == STATE_ESTOP && r.bus.servo(12)->duty == 0);
  r.send(MSG_ARM, {1});
  CHECK(r.ctrl.state() == STATE_ARMED);
  // Link watchdog: 2 s without any frame disarms.
  r.run(2100);
  CHECK(r.ctrl.state() == STATE_DISARMED);
  // Heartbeat echo and counters in STATE.
  uint8_t hb[4];
  put_u32(hb, 123456);
  r.send(MSG_HEARTBEAT, std::vector<uint8_t>(hb, hb + 4));
  r.run(110);
  st = r.host.last(MSG_STATE);
  CHECK(st && get_u32(st->payload + 7) == 123456);
  // BATTERY carries the median servo supply.
  r.run(1000);
  const Frame* bat = r.host.last(MSG_BATTERY);
  CHECK(bat && get_u16(bat->payload) == 7400);
  // Unknown ids get ACK UNKNOWN_ID; a silent servo bus clears the valid bits.
  r.send(0x3F, {});
  CHECK(r.host.last(MSG_ACK)->payload[2] == ACK_UNKNOWN_ID);
  r.bus.silent = true;
  r.run(300);
  pos = r.host.last(MSG_SERVO_POS);
  CHECK(pos && get_u16(pos->payload + 4) == 0 && (r.ctrl.faults() & FAULT_SERVO_READ));
}

static void test_sumd() {
  std::vector<uint8_t> f = {0xA8, 0x01, 16};
  for (int i = 0; i < 16; ++i) {
    uint16_t v = (uint16_t)((1100 + 50 * i) * 8);
    f.push_back((uint8_t)(v >> 8));
    f.push_back((uint8_t)v);
  }
  uint16_t crc = crc16(f.data(), f.size(), 0x0000);
  f.push_back((uint8_t)(crc >> 8));
  f.push_back((uint8_t)crc);
  SumdDecoder d;
  int frames = 0;
  std::vector<uint8_t> stream = {0x00, 0xA8, 0x13};  // noise first
  stream.insert(stream.end(), f.begin(), f.end());
  for (uint8_t b : stream) frames += d.push(b);
  CHECK(frames == 1 && d.channels() == 16 && d.status() == 0x01);
  CHECK(d.channel_us(0) == 1100 && d.channel_us(15) == 1850);
  f[5] ^= 0x40;
  for (uint8_t b : f) frames += d.push(b);
  CHECK(frames == 1 && d.crc_errors == 1);
}

static void test_bus_echo_and_raw() {
  // A BusLinker that echoes our own bytes: reads still get the servo's reply, not the echo.
  Rig r;
  r.bus.echo = true;
  r.ctrl.boot(0, 0x01);
  r.run(200);
  const Frame* pos = r.host.last(MSG_SERVO_POS);
  CHECK(pos && get_u16(pos->payload + 4) == 0x3FF);
  CHECK(pos && get_i16(pos->payload + 6 + 2 * 6) == 500);  // steering FL reads its position
  // SERVO_RAW while disarmed: an ID_READ is forwarded and its reply returned.
  uint8_t pkt[16];
  uint8_t n = lx16a::read_request(pkt, 131, lx16a::ID_READ);
  std::vector<uint8_t> raw = {n};
  raw.insert(raw.end(), pkt, pkt + n);
  r.send(MSG_SERVO_RAW, raw);
  r.run(100);
  const Frame* rep = r.host.last(MSG_SERVO_RAW_REPLY);
  CHECK(rep && rep->payload[0] == 0 && rep->payload[1] == 7 && rep->payload[2 + 5] == 131);
  // A write gets no reply (its echo is not taken for one): status 1 after the timeout.
  n = lx16a::move_time(pkt, 111, 600, 100);
  raw.assign(1, n);
  raw.insert(raw.end(), pkt, pkt + n);
  r.send(MSG_SERVO_RAW, raw);
  r.run(100);
  rep = r.host.last(MSG_SERVO_RAW_REPLY);
  CHECK(rep && rep->payload[0] == 1 && rep->payload[1] == 0);
  // Refused while armed.
  r.send(MSG_ARM, {1});
  r.send(MSG_SERVO_RAW, raw);
  CHECK(r.host.last(MSG_ACK)->payload[1] == MSG_SERVO_RAW && r.host.last(MSG_ACK)->payload[2] == ACK_WRONG_STATE);
}

int main() {
  test_bus_echo_and_raw();
  test_sumd();
  test_crc_and_vectors();
  test_parser_resync();
  test_lx16a();
  test_controller();
  printf("%d checks, %d failed\n", g_checks, g_failed);
  return g_failed ? 1 : 0;
}
