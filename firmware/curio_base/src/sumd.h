// Graupner SUMD receiver frames (portable C++): A8 | status | N | N x u16 big-endian (1/8 us) |
// CRC-16 XMODEM (poly 0x1021, init 0, big-endian) over header and data.
// status 0x01 = valid, 0x81 = failsafe, 0x00 = SUMH. Channels are kept in receiver order.
#ifndef CURIO_SUMD_H
#define CURIO_SUMD_H

#include <stdint.h>

namespace curio {

class SumdDecoder {
 public:
  static const uint8_t MAX_CHANNELS = 16;
  SumdDecoder() : crc_errors(0), n_(0), need_(0) {}
  // Feed one byte; returns true when a complete frame with a good CRC has been decoded.
  bool push(uint8_t byte);
  uint8_t status() const { return status_; }
  uint8_t channels() const { return channels_; }
  uint16_t channel_us(uint8_t i) const { return (uint16_t)(value_[i] >> 3); }
  uint16_t crc_errors;

 private:
  uint8_t buf_[3 + 2 * 32 + 2];
  uint8_t n_;
  uint8_t need_;
  uint8_t status_ = 0;
  uint8_t channels_ = 0;
  uint16_t value_[MAX_CHANNELS] = {0};
};

}  // namespace curio

#endif
