// Curio base controller core (see controller.h).
#include "controller.h"

#include <string.h>

namespace curio {

static const uint8_t DEFAULT_WHEEL_IDS[NUM_WHEELS] = {11, 12, 13, 21, 22, 23};
static const uint8_t DEFAULT_STEER_IDS[NUM_STEER] = {111, 131, 211, 231};

void config_defaults(Config& c) {
  c.proto_ver = PROTO_VERSION;
  memcpy(c.wheel_ids, DEFAULT_WHEEL_IDS, NUM_WHEELS);
  memcpy(c.steer_ids, DEFAULT_STEER_IDS, NUM_STEER);
  memset(c.steer_trim, 0, NUM_STEER);
  c.cmd_timeout_ms = 500;
  c.pos_rate_hz = 30;
  c.status_rate_hz = 1;
  c.steer_move_ms = 50;
  c.flags = 0;
}

void config_pack(const Config& c, uint8_t* out) {
  out[0] = c.proto_ver;
  memcpy(out + 1, c.wheel_ids, NUM_WHEELS);
  memcpy(out + 7, c.steer_ids, NUM_STEER);
  for (uint8_t i = 0; i < NUM_STEER; ++i) out[11 + i] = (uint8_t)c.steer_trim[i];
  put_u16(out + 15, c.cmd_timeout_ms);
  out[17] = c.pos_rate_hz;
  out[18] = c.status_rate_hz;
  put_u16(out + 19, c.steer_move_ms);
  out[21] = c.flags;
}

void config_unpack(const uint8_t* in, Config& c) {
  c.proto_ver = in[0];
  memcpy(c.wheel_ids, in + 1, NUM_WHEELS);
  memcpy(c.steer_ids, in + 7, NUM_STEER);
  for (uint8_t i = 0; i < NUM_STEER; ++i) c.steer_trim[i] = (int8_t)in[11 + i];
  c.cmd_timeout_ms = get_u16(in + 15);
  c.pos_rate_hz = in[17];
  c.status_rate_hz = in[18];
  c.steer_move_ms = get_u16(in + 19);
  c.flags = in[21];
}

bool config_valid(const Config& c) {
  if (c.proto_ver != PROTO_VERSION) return false;
  uint8_t ids[NUM_SERVOS];
  memcpy(ids, c.wheel_ids, NUM_WHEELS);
  memcpy(ids + NUM_WHEELS, c.steer_ids, NUM_STEER);
  for (uint8_t i = 0; i < NUM_SERVOS; ++i) {
    if (ids[i] > 253) return false;
    for (uint8_t j = 0; j < i; ++j)
      if (ids[i] == ids[j]) return false;
  }
  for (uint8_t i = 0; i < NUM_STEER; ++i)
    if (c.steer_trim[i] < -125 || c.steer_trim[i] > 125) return false;
  if (c.cmd_timeout_ms < 50 || c.cmd_timeout_ms > 5000) return false;
  if (c.pos_rate_hz < 1 || c.pos_rate_hz > 40) return false;
  if (c.status_rate_hz < 1 || c.status_rate_hz > 10) return false;
  if (c.steer_move_ms > 30000) return false;
  return true;
}

Controller::Controller(HostLink& host, ServoLink& servos)
    : host_(host), servos_(servos), state_(STATE_BOOT), faults_(0), last_cmd_ms_(0), last_rx_ms_(0),
      last_host_ms_(0), rx_ok_(0), loop_max_us_(0), reset_cause_(0), tx_seq_(0), next_control_ms_(0),
      next_state_ms_(0), next_status_ms_(0), adc_mv_(0xFFFF), booted_(false), head_(0), count_(0),
      waiting_(false), sent_ms_(0), sweep_ms_(0), sweep_active_(false), sweep_mask_(0), vin_slot_(0),
      raw_n_(0) {
  config_defaults(cfg_);
  memset(duty_, 0, sizeof(duty_));
  for (uint8_t i = 0; i < NUM_STEER; ++i) steer_[i] = 500;
  memset(pos_, 0, sizeof(pos_));
  memset(dt_, 0, sizeof(dt_));
  memset(vin_, 0, sizeof(vin_));
  memset(comm_errs_, 0, sizeof(comm_errs_));
}

// --- output ------------------------------------------------------------------------------------

void Controller::send(uint8_t msg_id, const uint8_t* payload, uint8_t len) {
  size_t n = encode_frame(tx_, msg_id, tx_seq_++, payload, len);
  host_.write(tx_, n);
}

void Controller::ack(const Frame& f, uint8_t status) {
  uint8_t p[3] = {f.seq, f.msg_id, status};
  send(MSG_ACK, p, 3);
}

void Controller::send_state(uint32_t now_ms) {
  uint8_t p[18];
  put_u32(p, now_ms);
  p[4] = state_;
  put_u16(p + 5, faults_);
  put_u32(p + 7, last_host_ms_);
  put_u16(p + 11, parser_.crc_errors);
  put_u16(p + 13, rx_ok_);
  put_u16(p + 15, loop_max_us_);
  p[17] = reset_cause_;
  send(MSG_STATE, p, 18);
  loop_max_us_ = 0;
  next_state_ms_ = now_ms + STATE_PERIOD_MS;
}

void Controller::send_info() {
  uint8_t c[CONFIG_SIZE];
  config_pack(cfg_, c);
  uint8_t p[9];
  p[0] = PROTO_VERSION;
  p[1] = FW_MAJOR;
  p[2] = FW_MINOR;
  put_u32(p + 3, FW_BUILD);
  put_u16(p + 7, crc16(c, CONFIG_SIZE));
  send(MSG_INFO, p, 9);
}

void Controller::set_state(uint8_t s, uint32_t now_ms) {
  if (s == state_) return;
  state_ = s;
  send_state(now_ms);
}

// --- servo bus ---------------------------------------------------------------------------------

bool Controller::push_job(uint8_t kind, uint8_t id, uint8_t slot, int16_t a, uint16_t b) {
  if (count_ >= QUEUE_SIZE) return false;
  Job& j = jobs_[(uint8_t)((head_ + count_) % QUEUE_SIZE)];
  j.kind = kind;
  j.id = id;
  j.slot = slot;
  j.a = a;
  j.b = b;
  ++count_;
  return true;
}

void Controller::clear_jobs() {
  head_ = 0;
  count_ = 0;
  waiting_ = false;
  sweep_active_ = false;
}

void Controller::stop_wheels_now() {
  // Drop whatever the bus was doing and tell every wheel duty 0 before anything else.
  memset(duty_, 0, sizeof(duty_));
  clear_jobs();
  for (uint8_t i = 0; i < NUM_WHEELS; ++i) push_job(JOB_MOTOR, cfg_.wheel_ids[i], i, 0, 0);
}

void Controller::init_steering() {
  for (uint8_t i = 0; i < NUM_STEER; ++i) {
    push_job(JOB_POSMODE, cfg_.steer_ids[i], (uint8_t)(NUM_WHEELS + i), 0, 0);
    push_job(JOB_TRIM, cfg_.steer_ids[i], (uint8_t)(NUM_WHEELS + i), cfg_.steer_trim[i], 0);
    // SET_CONFIG flags bit0: also save the trim in the servo's EEPROM (cmd 18). Off by
    // default: the original wrote the EEPROM at every boot, wearing it for nothing.
    if (cfg_.flags & 0x01) push_job(JOB_TRIM_SAVE, cfg_.steer_ids[i], (uint8_t)(NUM_WHEELS + i), 0, 0);
  }
}

void Controller::start_sweep(uint32_t now_ms) {
  bool armed = state_ == STATE_ARMED;
  for (uint8_t i = 0; i < NUM_WHEELS; ++i)
    push_job(JOB_MOTOR, cfg_.wheel_ids[i], i, armed ? duty_[i] : 0, 0);
  for (uint8_t i = 0; i < NUM_STEER; ++i)
    if (steer_[i] != STEER_UNCHANGED)
      push_job(JOB_MOVE, cfg_.steer_ids[i], (uint8_t)(NUM_WHEELS + i), (int16_t)cfg_.steer_move_ms, steer_[i]);
  for (uint8_t i = 0; i < NUM_SERVOS; ++i) {
    uint8_t id = i < NUM_WHEELS ? cfg_.wheel_ids[i] : cfg_.steer_ids[i - NUM_WHEELS];
    push_job(JOB_READ_POS, id, i, 0, 0);
  }
  uint8_t v = vin_slot_;
  vin_slot_ = (uint8_t)((vin_slot_ + 1) % NUM_SERVOS);
  push_job(JOB_READ_VIN, v < NUM_WHEELS ? cfg_.wheel_ids[v] : cfg_.steer_ids[v - NUM_WHEELS], v, 0, 0);
  push_job(JOB_SWEEP_END, 0, 0, 0, 0);
  sweep_active_ = true;
  sweep_ms_ = now_ms;
  sweep_mask_ = 0;
}

void Controller::finish_job(bool ok, const lx16a::Packet* reply, uint32_t now_ms) {
  Job& j = jobs_[head_];
  if (j.kind == JOB_READ_POS) {
    if (ok) {
      pos_[j.slot] = get_i16(reply->params);
      sweep_mask_ |= (uint16_t)(1u << j.slot);
    } else if (comm_errs_[j.slot] < 255) {
      ++comm_errs_[j.slot];
    }
    uint32_t dt = sent_ms_ - sweep_ms_;
    dt_[j.slot] = (uint8_t)(dt > 255 ? 255 : dt);
  } else if (j.kind == JOB_READ_VIN) {
    if (ok) vin_[j.slot] = get_u16(reply->params);
    else if (comm_errs_[j.slot] < 255) ++comm_errs_[j.slot];
  } else if (j.kind == JOB_RAW) {
    uint8_t p[2 + lx16a::MAX_PACKET + 6];
    p[0] = ok ? 0 : 1;
    p[1] = 0;
    if (ok) p[1] = lx16a::build(p + 2, reply->id, reply->cmd, reply->params, reply->n);
    send(MSG_SERVO_RAW_REPLY, p, (uint8_t)(2 + p[1]));
  }
  (void)now_ms;
  head_ = (uint8_t)((head_ + 1) % QUEUE_SIZE);
  --count_;
  waiting_ = false;
}

void Controller::run_servo_bus(uint32_t now_ms) {
  uint8_t pkt[lx16a::MAX_PACKET];
  for (uint8_t guard = 0; guard < QUEUE_SIZE && count_ > 0; ++guard) {
    Job& j = jobs_[head_];
    if (waiting_) {
      int b;
      lx16a::Packet reply;
      while ((b = servos_.read()) >= 0) servo_parser_.push((uint8_t)b);
      while (servo_parser_.next(reply)) {
        uint8_t want_cmd = j.kind == JOB_READ_POS ? lx16a::POS_READ
                           : j.kind == JOB_READ_VIN ? lx16a::VIN_READ : 0;
        bool echo_of_raw = j.kind == JOB_RAW && reply.n + 6 == raw_n_ && reply.cmd == raw_[4] &&
                           memcmp(reply.params, raw_ + 5, reply.n) == 0;
        bool match = j.kind == JOB_RAW ? (!echo_of_raw && (j.id == lx16a::BROADCAST_ID || reply.id == j.id))
                                       : (reply.id == j.id && reply.cmd == want_cmd && reply.n == 2);
        if (match) {  // an echo of our own request has no params and never matches
          finish_job(true, &reply, now_ms);
          break;
        }
      }
      if (waiting_) {
        if ((uint32_t)(now_ms - sent_ms_) <= SERVO_REPLY_TIMEOUT_MS) return;
        finish_job(false, 0, now_ms);
      }
      continue;
    }
    uint8_t n = 0;
    switch (j.kind) {
      case JOB_MOTOR: n = lx16a::motor_mode(pkt, j.id, j.a); break;
      case JOB_POSMODE: n = lx16a::position_mode(pkt, j.id); break;
      case JOB_TRIM: n = lx16a::angle_offset_adjust(pkt, j.id, (int8_t)j.a); break;
      case JOB_TRIM_SAVE: n = lx16a::read_request(pkt, j.id, lx16a::ANGLE_OFFSET_WRITE); break;
      case JOB_MOVE: n = lx16a::move_time(pkt, j.id, j.b, (uint16_t)j.a); break;
      case JOB_READ_POS: n = lx16a::read_request(pkt, j.id, lx16a::POS_READ); break;
      case JOB_READ_VIN: n = lx16a::read_request(pkt, j.id, lx16a::VIN_READ); break;
      case JOB_RAW:
        memcpy(pkt, raw_, raw_n_);
        n = raw_n_;
        break;
      case JOB_SWEEP_END: {
        uint8_t p[36];
        put_u32(p, sweep_ms_);
        put_u16(p + 4, sweep_mask_);
        for (uint8_t i = 0; i < NUM_SERVOS; ++i) put_u16(p + 6 + 2 * i, (uint16_t)pos_[i]);
        memcpy(p + 26, dt_, NUM_SERVOS);
        if (sweep_mask_ != 0x3FF) faults_ |= FAULT_SERVO_READ;
        else faults_ &= (uint16_t)~FAULT_SERVO_READ;
        send(MSG_SERVO_POS, p, 36);
        sweep_active_ = false;
        head_ = (uint8_t)((head_ + 1) % QUEUE_SIZE);
        --count_;
        continue;
      }
    }
    while (servos_.read() >= 0) {}  // stale bytes (echoes of writes) are not replies
    servo_parser_.reset();
    servos_.write(pkt, n);
    sent_ms_ = now_ms;
    if (j.kind == JOB_READ_POS || j.kind == JOB_READ_VIN || j.kind == JOB_RAW) {
      waiting_ = true;
      return;  // come back on the next poll for the reply
    }
    head_ = (uint8_t)((head_ + 1) % QUEUE_SIZE);
    --count_;
  }
}

// --- lifecycle ---------------------------------------------------------------------------------

void Controller::boot(uint32_t now_ms, uint8_t reset_cause) {
  config_defaults(cfg_);
  reset_cause_ = reset_cause;
  state_ = STATE_BOOT;
  faults_ = FAULT_DEFAULT_CONFIG;
  if (reset_cause & 0x0C) faults_ |= FAULT_RESET_WATCHDOG;  // brown-out or watchdog reset
  for (uint8_t i = 0; i < NUM_STEER; ++i) steer_[i] = 500;
  parser_ = FrameParser();
  rx_ok_ = 0;
  last_host_ms_ = 0;
  tx_seq_ = 0;
  stop_wheels_now();  // first thing on the bus: every wheel to duty 0
  init_steering();
  run_servo_bus(now_ms);
  send_state(now_ms);
  send_info();
  last_rx_ms_ = now_ms;
  last_cmd_ms_ = now_ms;
  next_control_ms_ = now_ms;
  next_status_ms_ = now_ms;
  booted_ = true;
  set_state(STATE_DISARMED, now_ms);
}

// --- input -------------------------------------------------------------------------------------

void Controller::on_host_byte(uint8_t byte, uint32_t now_ms) {
  parser_.push(byte, now_ms);
  Frame f;
  while (parser_.next(f)) {
    ++rx_ok_;
    last_rx_ms_ = now_ms;
    handle_frame(f, now_ms);
  }
}

void Controller::handle_frame(const Frame& f, uint32_t now_ms) {
  switch (f.msg_id) {
    case MSG_SERVO_CMD: {
      if (f.len != 21) { ack(f, ACK_BAD_LENGTH); return; }
      if (state_ != STATE_ARMED && state_ != STATE_TIMEOUT) { ack(f, ACK_WRONG_STATE); return; }
      for (uint8_t i = 0; i < NUM_WHEELS; ++i) {
        int16_t d = get_i16(f.payload + 2 * i);
        duty_[i] = d > 1000 ? 1000 : (d < -1000 ? -1000 : d);
      }
      for (uint8_t i = 0; i < NUM_STEER; ++i) {
        uint16_t s = get_u16(f.payload + 12 + 2 * i);
        if (s != STEER_UNCHANGED) steer_[i] = s > 1000 ? 1000 : s;
      }
      last_cmd_ms_ = now_ms;
      faults_ &= (uint16_t)~FAULT_MOTION_WATCHDOG;
      set_state(STATE_ARMED, now_ms);
      return;
    }
    case MSG_HEARTBEAT:
      if (f.len != 4) { ack(f, ACK_BAD_LENGTH); return; }
      last_host_ms_ = get_u32(f.payload);
      return;
    case MSG_SET_CONFIG: {
      if (f.len != CONFIG_SIZE) { ack(f, ACK_BAD_LENGTH); return; }
      Config c;
      config_unpack(f.payload, c);
      if (!config_valid(c)) { ack(f, ACK_BAD_VALUE); return; }
      if (state_ == STATE_ARMED) { ack(f, ACK_WRONG_STATE); return; }
      cfg_ = c;
      faults_ &= (uint16_t)~FAULT_DEFAULT_CONFIG;
      stop_wheels_now();  // the wheel ids may have changed: make sure the new ones stand still
      init_steering();
      ack(f, ACK_OK);
      return;
    }
    case MSG_ESTOP:
      if (f.len != 0) { ack(f, ACK_BAD_LENGTH); return; }
      stop_wheels_now();
      set_state(STATE_ESTOP, now_ms);
      ack(f, ACK_OK);
      return;
    case MSG_ARM:
      if (f.len != 1) { ack(f, ACK_BAD_LENGTH); return; }
      if (f.payload[0] > 1) { ack(f, ACK_BAD_VALUE); return; }
      memset(duty_, 0, sizeof(duty_));
      if (f.payload[0] == 1) {
        if (state_ == STATE_BOOT) { ack(f, ACK_WRONG_STATE); return; }
        last_cmd_ms_ = now_ms;
        faults_ &= (uint16_t)~FAULT_MOTION_WATCHDOG;
        set_state(STATE_ARMED, now_ms);
      } else {
        stop_wheels_now();
        set_state(STATE_DISARMED, now_ms);
      }
      ack(f, ACK_OK);
      return;
    case MSG_GET_INFO:
      send_info();
      return;
    case MSG_SERVO_RAW:
      if (state_ == STATE_ARMED) { ack(f, ACK_WRONG_STATE); return; }
      if (f.len < 7 || f.payload[0] != f.len - 1 || f.payload[0] > sizeof(raw_)) { ack(f, ACK_BAD_LENGTH); return; }
      memcpy(raw_, f.payload + 1, f.payload[0]);
      raw_n_ = f.payload[0];
      if (!push_job(JOB_RAW, raw_[2], 0, 0, 0)) ack(f, ACK_BUSY);
      return;
    default:
      ack(f, ACK_UNKNOWN_ID);
      return;
  }
}

// --- periodic ----------------------------------------------------------------------------------

void Controller::send_status(uint32_t now_ms) {
  uint8_t p[74];
  put_u32(p, now_ms);
  uint16_t sorted[NUM_SERVOS];
  uint8_t n = 0;
  for (uint8_t i = 0; i < NUM_SERVOS; ++i) {
    uint8_t* e = p + 4 + 7 * i;
    e[0] = i < NUM_WHEELS ? cfg_.wheel_ids[i] : cfg_.steer_ids[i - NUM_WHEELS];
    put_u16(e + 1, vin_[i]);
    e[3] = 0xFF;                      // temperature not read
    e[4] = i < NUM_WHEELS ? 1 : 0;    // mode as commanded
    e[5] = 0xFF;                      // LED error not read
    e[6] = comm_errs_[i];
    if (vin_[i] > 0) {                // insertion sort of the valid readings
      uint8_t k = n++;
      while (k > 0 && sorted[k - 1] > vin_[i]) { sorted[k] = sorted[k - 1]; --k; }
      sorted[k] = vin_[i];
    }
  }
  send(MSG_SERVO_STATUS, p, 74);
  uint16_t median = 0;
  if (n) median = (n & 1) ? sorted[n / 2] : (uint16_t)(((uint32_t)sorted[n / 2 - 1] + sorted[n / 2]) / 2);
  uint8_t b[4];
  put_u16(b, median);
  put_u16(b + 2, adc_mv_);
  send(MSG_BATTERY, b, 4);
}

void Controller::report_rc(uint32_t now_ms, const uint16_t* ch_us, uint8_t n, uint8_t flags, uint8_t counter) {
  if (n > 16) n = 16;
  uint8_t p[7 + 32];
  put_u32(p, now_ms);
  p[4] = flags;
  p[5] = counter;
  p[6] = n;
  for (uint8_t i = 0; i < n; ++i) put_u16(p + 7 + 2 * i, ch_us[i]);
  send(MSG_RC, p, (uint8_t)(7 + 2 * n));
}

void Controller::poll(uint32_t now_ms) {
  if (!booted_) return;
  if (state_ == STATE_ARMED && (uint32_t)(now_ms - last_cmd_ms_) > cfg_.cmd_timeout_ms) {
    stop_wheels_now();
    faults_ |= FAULT_MOTION_WATCHDOG;
    set_state(STATE_TIMEOUT, now_ms);
  }
  if ((state_ == STATE_ARMED || state_ == STATE_TIMEOUT) && (uint32_t)(now_ms - last_rx_ms_) > LINK_TIMEOUT_MS) {
    stop_wheels_now();
    set_state(STATE_DISARMED, now_ms);
  }
  if ((int32_t)(now_ms - next_control_ms_) >= 0 && !sweep_active_) {
    next_control_ms_ += 1000u / cfg_.pos_rate_hz;
    if ((int32_t)(now_ms - next_control_ms_) > 0) next_control_ms_ = now_ms;
    start_sweep(now_ms);
  }
  run_servo_bus(now_ms);
  if ((int32_t)(now_ms - next_status_ms_) >= 0) {
    next_status_ms_ += 1000u / cfg_.status_rate_hz;
    if ((int32_t)(now_ms - next_status_ms_) > 0) next_status_ms_ = now_ms;
    send_status(now_ms);
  }
  if ((int32_t)(now_ms - next_state_ms_) >= 0) send_state(now_ms);
}

}  // namespace curio
