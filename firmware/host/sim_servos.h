// A simulated LX-16A servo bus for the host build: parses the packets the controller writes,
// models ten servos (wheels in motor mode with the dead zone, steering with slew and trim) and
// answers reads with real reply packets after a short latency.
#ifndef CURIO_SIM_SERVOS_H
#define CURIO_SIM_SERVOS_H

#include <stdint.h>

#include <deque>
#include <map>

#include "../curio_base/src/controller.h"
#include "../curio_base/src/lx16a.h"

namespace curio {

struct SimServo {
  bool motor_mode = false;
  int16_t duty = 0;
  double count = 100.0;     // continuous position, 1500 counts a turn
  double steer_pos = 500.0; // position-mode position 0..1000
  double steer_target = 500.0;
  double steer_speed = 0.0; // units per ms
  int8_t trim = 0;
  int8_t saved_trim = 0;  // EEPROM
  uint16_t vin_mv = 7400;
};

class SimServoBus : public ServoLink {
 public:
  explicit SimServoBus(const uint8_t* ids, uint8_t n);
  void write(const uint8_t* data, uint8_t n) override;
  int read() override;
  void advance(uint32_t now_ms);  // integrate the servo models and release due replies
  const SimServo* servo(uint8_t id) const;
  uint32_t packets = 0;
  uint32_t reads = 0;
  double counts_per_ms_per_duty = 0.0015;  // duty 1000 -> one turn a second
  uint32_t latency_ms = 1;
  bool silent = false;  // every servo stops answering (unplugged bus)
  bool echo = false;    // the half-duplex adapter echoes what the master sends

 private:
  void handle(const lx16a::Packet& p);
  std::map<uint8_t, SimServo> servos_;
  lx16a::Parser parser_;
  std::deque<uint8_t> out_;
  std::deque<std::pair<uint32_t, std::deque<uint8_t>>> pending_;
  uint32_t now_ms_ = 0;
  bool started_ = false;
};

}  // namespace curio

#endif
