// Links the compile-checked sketch (curio_base.ino) with the stubs.
#include "Arduino.h"
HardwareSerialStub Serial, Serial1, Serial2;
uint8_t MCUSR = 0;
void setup();
void loop();
int main() {
  setup();
  loop();
  return 0;
}
