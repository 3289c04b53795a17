// LX-16A bus-servo packets (see lx16a.h).
#include "lx16a.h"

#include <string.h>

namespace curio {
namespace lx16a {

uint8_t checksum(uint8_t id, uint8_t len, uint8_t cmd, const uint8_t* params, uint8_t n) {
  uint16_t sum = (uint16_t)id + len + cmd;
  for (uint8_t i = 0; i < n; ++i) sum += params[i];
  return (uint8_t)(~sum);
}

uint8_t build(uint8_t* out, uint8_t id, uint8_t cmd, const uint8_t* params, uint8_t n) {
  uint8_t len = (uint8_t)(n + 3);
  out[0] = 0x55;
  out[1] = 0x55;
  out[2] = id;
  out[3] = len;
  out[4] = cmd;
  if (n) memcpy(out + 5, params, n);
  out[5 + n] = checksum(id, len, cmd, params, n);
  return (uint8_t)(n + 6);
}

uint8_t read_request(uint8_t* out, uint8_t id, uint8_t cmd) { return build(out, id, cmd, 0, 0); }

uint8_t motor_mode(uint8_t* out, uint8_t id, int16_t duty) {
  if (duty > 1000) duty = 1000;
  if (duty < -1000) duty = -1000;
  uint8_t p[4] = {1, 0, (uint8_t)duty, (uint8_t)((uint16_t)duty >> 8)};
  return build(out, id, OR_MOTOR_MODE_WRITE, p, 4);
}

uint8_t position_mode(uint8_t* out, uint8_t id) {
  uint8_t p[4] = {0, 0, 0, 0};
  return build(out, id, OR_MOTOR_MODE_WRITE, p, 4);
}

uint8_t move_time(uint8_t* out, uint8_t id, uint16_t pos, uint16_t time_ms) {
  if (pos > 1000) pos = 1000;
  if (time_ms > 30000) time_ms = 30000;
  uint8_t p[4] = {(uint8_t)pos, (uint8_t)(pos >> 8), (uint8_t)time_ms, (uint8_t)(time_ms >> 8)};
  return build(out, id, MOVE_TIME_WRITE, p, 4);
}

uint8_t angle_offset_adjust(uint8_t* out, uint8_t id, int8_t trim) {
  uint8_t p[1] = {(uint8_t)trim};
  return build(out, id, ANGLE_OFFSET_ADJUST, p, 1);
}

void Parser::drop(uint8_t n) {
  if (n >= n_) {
    n_ = 0;
    return;
  }
  memmove(buf_, buf_ + n, n_ - n);
  n_ = (uint8_t)(n_ - n);
}

void Parser::push(uint8_t byte) {
  if (n_ >= sizeof(buf_)) drop(1);
  buf_[n_++] = byte;
}

bool Parser::next(Packet& out) {
  while (n_ > 0) {
    if (buf_[0] != 0x55) { drop(1); continue; }
    if (n_ < 2) return false;
    if (buf_[1] != 0x55) { drop(1); continue; }
    if (n_ < 4) return false;
    uint8_t len = buf_[3];
    if (len < 3 || len > MAX_PACKET + 3) { drop(1); continue; }
    uint8_t total = (uint8_t)(len + 3);
    if (n_ < total) return false;
    uint8_t n = (uint8_t)(len - 3);
    if (buf_[total - 1] != checksum(buf_[2], len, buf_[4], buf_ + 5, n)) {
      ++bad_checksums;
      drop(1);
      continue;
    }
    out.id = buf_[2];
    out.cmd = buf_[4];
    out.n = n;
    if (n) memcpy(out.params, buf_ + 5, n);
    drop(total);
    return true;
  }
  return false;
}

int16_t reading_from_count(int32_t count) {
  int32_t c = count % 1500;
  if (c < 0) c += 1500;
  if (c < 1190) return (int16_t)c;
  if (c >= 1306) return (int16_t)(c - 1500);
  return (int16_t)(1194 - (c - 1190) / 10);
}

}  // namespace lx16a
}  // namespace curio
