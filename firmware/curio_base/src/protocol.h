// Curio base link: the framed Pi <-> Mega protocol (portable C++, no Arduino headers).
//
// Frame (multi-byte fields little-endian), identical to curio/drivers/arduino/protocol.py:
//   CA FE | LEN | SEQ | MSG_ID | payload[LEN] (0..200) | CRC16 (u16 LE)
// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection) over LEN, SEQ, MSG_ID, payload.
// Specification: shared/reference/hardware.md section 3.2.
#ifndef CURIO_PROTOCOL_H
#define CURIO_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

namespace curio {

const uint8_t SYNC0 = 0xCA;
const uint8_t SYNC1 = 0xFE;
const uint8_t MAX_PAYLOAD = 200;
const uint8_t FRAME_OVERHEAD = 7;
const uint8_t PROTO_VERSION = 1;
const uint16_t STEER_UNCHANGED = 0xFFFF;
const uint32_t INTER_BYTE_TIMEOUT_MS = 20;

enum MsgId {
  MSG_SET_CONFIG = 0x01,
  MSG_SERVO_CMD = 0x02,
  MSG_ESTOP = 0x03,
  MSG_ARM = 0x04,
  MSG_HEARTBEAT = 0x05,
  MSG_GET_INFO = 0x06,
  MSG_SERVO_RAW = 0x07,
  MSG_ACK = 0x80,
  MSG_SERVO_POS = 0x81,
  MSG_SERVO_STATUS = 0x82,
  MSG_RC = 0x83,
  MSG_STATE = 0x84,
  MSG_BATTERY = 0x85,
  MSG_INFO = 0x86,
  MSG_SERVO_RAW_REPLY = 0x87,
  MSG_LOG = 0x8F
};

enum McuState { STATE_BOOT = 0, STATE_DISARMED = 1, STATE_ARMED = 2, STATE_TIMEOUT = 3, STATE_ESTOP = 4 };

enum Fault {
  FAULT_MOTION_WATCHDOG = 1 << 0,
  FAULT_SERVO_READ = 1 << 1,
  FAULT_RC_LOST = 1 << 2,
  FAULT_UART_OVERRUN = 1 << 3,
  FAULT_DEFAULT_CONFIG = 1 << 4,
  FAULT_RESET_WATCHDOG = 1 << 5
};

enum AckStatus { ACK_OK = 0, ACK_BAD_LENGTH = 1, ACK_BAD_VALUE = 2, ACK_BUSY = 3, ACK_UNKNOWN_ID = 4, ACK_WRONG_STATE = 5 };

// CRC-16/CCITT-FALSE; the same MSB-first update as avr-libc's _crc_xmodem_update.
uint16_t crc16_update(uint16_t crc, uint8_t byte);
uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFF);

// Little-endian field helpers.
inline void put_u16(uint8_t* p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
inline void put_u32(uint8_t* p, uint32_t v) { put_u16(p, (uint16_t)v); put_u16(p + 2, (uint16_t)(v >> 16)); }
inline uint16_t get_u16(const uint8_t* p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
inline int16_t get_i16(const uint8_t* p) { return (int16_t)get_u16(p); }
inline uint32_t get_u32(const uint8_t* p) { return (uint32_t)get_u16(p) | ((uint32_t)get_u16(p + 2) << 16); }

// Writes one frame into out (room for len + 7 bytes); returns its size.
size_t encode_frame(uint8_t* out, uint8_t msg_id, uint8_t seq, const uint8_t* payload, uint8_t len);

struct Frame {
  uint8_t seq;
  uint8_t msg_id;
  uint8_t len;
  uint8_t payload[MAX_PAYLOAD];
};

// Incremental receiver. push() one byte, then call next() until it returns false.
// Hunts for CA FE, rejects LEN > 200, checks the CRC; after a failure it restarts the hunt at
// the byte after the failing CA. A partial frame older than 20 ms is dropped (truncated).
class FrameParser {
 public:
  FrameParser();
  void reset();
  void push(uint8_t byte, uint32_t now_ms);
  bool next(Frame& out);
  uint16_t crc_errors;
  uint16_t length_errors;
  uint16_t truncated;
  uint16_t frames;

 private:
  void drop(uint16_t n);
  uint8_t buf_[MAX_PAYLOAD + FRAME_OVERHEAD + 1];
  uint16_t n_;
  uint32_t last_ms_;
};

}  // namespace curio

#endif
