// LX-16A bus-servo packets (portable C++). Same bytes as curio/drivers/arduino/lx16a.py.
//   55 55 | ID | LEN | CMD | params[LEN-3] (little-endian) | CHK = ~(ID+LEN+CMD+sum(params))
// ID 254 is broadcast (no replies except ID_READ). Specification: hardware.md section 4.
#ifndef CURIO_LX16A_H
#define CURIO_LX16A_H

#include <stddef.h>
#include <stdint.h>

namespace curio {
namespace lx16a {

const uint8_t BROADCAST_ID = 0xFE;
const uint8_t MAX_PACKET = 16;  // the largest packet this firmware sends or parses

enum Cmd {
  MOVE_TIME_WRITE = 1,
  MOVE_STOP = 12,
  ID_READ = 14,
  ANGLE_OFFSET_ADJUST = 17,
  ANGLE_OFFSET_WRITE = 18,
  VIN_READ = 27,
  POS_READ = 28,
  OR_MOTOR_MODE_WRITE = 29,
  LOAD_OR_UNLOAD_WRITE = 31
};

uint8_t checksum(uint8_t id, uint8_t len, uint8_t cmd, const uint8_t* params, uint8_t n);
// Each builder writes one packet into out (MAX_PACKET bytes) and returns its length.
uint8_t build(uint8_t* out, uint8_t id, uint8_t cmd, const uint8_t* params, uint8_t n);
uint8_t read_request(uint8_t* out, uint8_t id, uint8_t cmd);
uint8_t motor_mode(uint8_t* out, uint8_t id, int16_t duty);  // duty clamped to -1000..1000
uint8_t position_mode(uint8_t* out, uint8_t id);
uint8_t move_time(uint8_t* out, uint8_t id, uint16_t pos, uint16_t time_ms);
uint8_t angle_offset_adjust(uint8_t* out, uint8_t id, int8_t trim);

struct Packet {
  uint8_t id;
  uint8_t cmd;
  uint8_t n;  // param count
  uint8_t params[MAX_PACKET];
};

// Incremental parser tolerating echoes and stray bytes (hunts 55 55, checks the checksum).
class Parser {
 public:
  Parser() : bad_checksums(0), n_(0) {}
  void reset() { n_ = 0; }
  void push(uint8_t byte);
  bool next(Packet& out);
  uint16_t bad_checksums;

 private:
  void drop(uint8_t n);
  uint8_t buf_[MAX_PACKET + 8];
  uint8_t n_;
};

// The raw POS_READ value of a spinning servo at continuous count c (1500 counts a turn):
// valid 0..1189 and 1306..1499 (read as -194..-1); inside the dead zone it sticks near 1194.
int16_t reading_from_count(int32_t count);

}  // namespace lx16a
}  // namespace curio

#endif
