// Curio base link: frame encoder and incremental parser (see protocol.h).
#include "protocol.h"

#include <string.h>

namespace curio {

uint16_t crc16_update(uint16_t crc, uint8_t byte) {
  crc ^= (uint16_t)byte << 8;
  for (uint8_t i = 0; i < 8; ++i) {
    crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc) {
  for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
  return crc;
}

size_t encode_frame(uint8_t* out, uint8_t msg_id, uint8_t seq, const uint8_t* payload, uint8_t len) {
  out[0] = SYNC0;
  out[1] = SYNC1;
  out[2] = len;
  out[3] = seq;
  out[4] = msg_id;
  if (len) memcpy(out + 5, payload, len);
  put_u16(out + 5 + len, crc16(out + 2, (size_t)len + 3));
  return (size_t)len + FRAME_OVERHEAD;
}

FrameParser::FrameParser() : crc_errors(0), length_errors(0), truncated(0), frames(0), n_(0), last_ms_(0) {}

void FrameParser::reset() { n_ = 0; }

void FrameParser::drop(uint16_t n) {
  if (n >= n_) {
    n_ = 0;
    return;
  }
  memmove(buf_, buf_ + n, n_ - n);
  n_ -= n;
}

void FrameParser::push(uint8_t byte, uint32_t now_ms) {
  if (n_ > 0 && (uint32_t)(now_ms - last_ms_) > INTER_BYTE_TIMEOUT_MS) {
    ++truncated;
    n_ = 0;
  }
  last_ms_ = now_ms;
  if (n_ >= sizeof(buf_)) drop(1);  // cannot happen with LEN <= 200, kept for safety
  buf_[n_++] = byte;
}

bool FrameParser::next(Frame& out) {
  while (n_ > 0) {
    if (buf_[0] != SYNC0) { drop(1); continue; }
    if (n_ < 2) return false;
    if (buf_[1] != SYNC1) { drop(1); continue; }
    if (n_ < 5) return false;
    uint8_t len = buf_[2];
    if (len > MAX_PAYLOAD) { ++length_errors; drop(1); continue; }
    uint16_t total = (uint16_t)len + FRAME_OVERHEAD;
    if (n_ < total) return false;
    uint16_t crc = get_u16(buf_ + 5 + len);
    if (crc != crc16(buf_ + 2, (size_t)len + 3)) { ++crc_errors; drop(1); continue; }
    out.len = len;
    out.seq = buf_[3];
    out.msg_id = buf_[4];
    if (len) memcpy(out.payload, buf_ + 5, len);
    drop(total);
    ++frames;
    return true;
  }
  return false;
}

}  // namespace curio
