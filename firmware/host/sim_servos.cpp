// Simulated LX-16A servo bus (see sim_servos.h).
#include "sim_servos.h"

#include <algorithm>
#include <cmath>

namespace curio {

SimServoBus::SimServoBus(const uint8_t* ids, uint8_t n) {
  for (uint8_t i = 0; i < n; ++i) servos_[ids[i]] = SimServo();
}

const SimServo* SimServoBus::servo(uint8_t id) const {
  auto it = servos_.find(id);
  return it == servos_.end() ? nullptr : &it->second;
}

void SimServoBus::write(const uint8_t* data, uint8_t n) {
  if (echo) out_.insert(out_.end(), data, data + n);
  for (uint8_t i = 0; i < n; ++i) parser_.push(data[i]);
  lx16a::Packet p;
  while (parser_.next(p)) handle(p);
}

void SimServoBus::handle(const lx16a::Packet& p) {
  ++packets;
  auto it = servos_.find(p.id);
  if (it == servos_.end() || silent) return;  // unknown id: silence, like the real bus
  SimServo& s = it->second;
  uint8_t reply[lx16a::MAX_PACKET];
  uint8_t n = 0;
  switch (p.cmd) {
    case lx16a::OR_MOTOR_MODE_WRITE:
      if (p.n != 4) return;
      s.motor_mode = p.params[0] == 1;
      s.duty = s.motor_mode ? (int16_t)(p.params[2] | (p.params[3] << 8)) : 0;
      return;
    case lx16a::MOVE_TIME_WRITE: {
      if (p.n != 4 || s.motor_mode) return;
      double target = (double)(uint16_t)(p.params[0] | (p.params[1] << 8));
      double t = (double)(uint16_t)(p.params[2] | (p.params[3] << 8));
      s.steer_target = target;
      double cap = 1.56;  // about 60 degrees in 0.16 s, units per ms
      s.steer_speed = t > 0 ? std::min(cap, std::fabs(target - s.steer_pos) / t) : cap;
      return;
    }
    case lx16a::ANGLE_OFFSET_ADJUST:
      if (p.n == 1) s.trim = (int8_t)p.params[0];
      return;
    case lx16a::ANGLE_OFFSET_WRITE:
      s.saved_trim = s.trim;
      return;
    case lx16a::POS_READ: {
      ++reads;
      int16_t v = s.motor_mode ? lx16a::reading_from_count((int32_t)std::floor(s.count))
                               : (int16_t)std::lround(s.steer_pos);
      uint8_t prm[2] = {(uint8_t)v, (uint8_t)((uint16_t)v >> 8)};
      n = lx16a::build(reply, p.id, lx16a::POS_READ, prm, 2);
      break;
    }
    case lx16a::VIN_READ: {
      uint8_t prm[2] = {(uint8_t)s.vin_mv, (uint8_t)(s.vin_mv >> 8)};
      n = lx16a::build(reply, p.id, lx16a::VIN_READ, prm, 2);
      break;
    }
    case lx16a::ID_READ: {
      uint8_t prm[1] = {p.id};
      n = lx16a::build(reply, p.id, lx16a::ID_READ, prm, 1);
      break;
    }
    default:
      return;
  }
  pending_.emplace_back(now_ms_ + latency_ms, std::deque<uint8_t>(reply, reply + n));
}

void SimServoBus::advance(uint32_t now_ms) {
  if (!started_) {
    started_ = true;
    now_ms_ = now_ms;
  }
  double dt = (double)(uint32_t)(now_ms - now_ms_);
  now_ms_ = now_ms;
  for (auto& kv : servos_) {
    SimServo& s = kv.second;
    if (s.motor_mode) s.count += s.duty * counts_per_ms_per_duty * dt;
    double step = s.steer_speed * dt;
    double err = s.steer_target - s.steer_pos;
    s.steer_pos += std::max(-step, std::min(step, err));
  }
  while (!pending_.empty() && (int32_t)(now_ms - pending_.front().first) >= 0) {
    for (uint8_t b : pending_.front().second) out_.push_back(b);
    pending_.pop_front();
  }
}

int SimServoBus::read() {
  if (out_.empty()) return -1;
  uint8_t b = out_.front();
  out_.pop_front();
  return b;
}

}  // namespace curio
