// Graupner SUMD decoder (see sumd.h).
#include "sumd.h"

#include "protocol.h"

namespace curio {

bool SumdDecoder::push(uint8_t byte) {
  if (n_ == 0 && byte != 0xA8) return false;
  if (n_ == 1 && byte != 0x01 && byte != 0x81 && byte != 0x00) { n_ = 0; return false; }
  if (n_ == 2) {
    if (byte < 2 || byte > 32) { n_ = 0; return false; }
    need_ = (uint8_t)(3 + 2 * byte + 2);
  }
  buf_[n_++] = byte;
  if (n_ < 3 || n_ < need_) return false;
  n_ = 0;
  uint8_t data_len = (uint8_t)(need_ - 2);
  uint16_t crc = crc16(buf_, data_len, 0x0000);
  uint16_t got = (uint16_t)((buf_[data_len] << 8) | buf_[data_len + 1]);
  if (crc != got) { ++crc_errors; return false; }
  status_ = buf_[1];
  uint8_t n = buf_[2];
  channels_ = n > MAX_CHANNELS ? MAX_CHANNELS : n;
  for (uint8_t i = 0; i < channels_; ++i) value_[i] = (uint16_t)((buf_[3 + 2 * i] << 8) | buf_[4 + 2 * i]);
  return true;
}

}  // namespace curio
