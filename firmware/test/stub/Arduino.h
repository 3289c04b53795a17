// Minimal stand-ins for the Arduino API used by curio_base.ino, so the host can at least
// compile-check the Arduino layer (`make ino-check`). Not a simulator; nothing here runs.
#ifndef CURIO_ARDUINO_STUB_H
#define CURIO_ARDUINO_STUB_H
#include <stddef.h>
#include <stdint.h>

struct HardwareSerialStub {
  void begin(unsigned long) {}
  int available() { return 0; }
  int read() { return -1; }
  size_t write(const uint8_t*, size_t n) { return n; }
};
extern HardwareSerialStub Serial, Serial1, Serial2;
inline unsigned long millis() { return 0; }
inline unsigned long micros() { return 0; }
inline int analogRead(uint8_t) { return 0; }
const uint8_t A0 = 54;
#endif
