// Curio base controller core: the state machine, the watchdogs, the servo-bus scheduler and the
// periodic reports. Portable C++ (no Arduino headers); time comes in as now_ms (millis()).
//
// States: BOOT -> DISARMED -> ARMED <-> TIMEOUT, plus ESTOP (latched until ARM).
//  * boot(): the wheels are told duty 0 before anything else, steering goes to position mode
//    with trims, STATE(BOOT) and INFO are sent, then DISARMED with the "default config" fault.
//  * Motion watchdog: ARMED and no valid SERVO_CMD for cmd_timeout_ms -> wheels 0, TIMEOUT,
//    fault bit 0. The next valid SERVO_CMD returns to ARMED.
//  * Link watchdog: ARMED/TIMEOUT and no valid frame of any kind for 2 s -> DISARMED.
//  * Every SET_CONFIG, ESTOP and ARM is answered with ACK; SERVO_CMD only when refused.
// The Python emulator (curio/drivers/arduino/emulator.py, FirmwareModel) mirrors this file.
#ifndef CURIO_CONTROLLER_H
#define CURIO_CONTROLLER_H

#include <stddef.h>
#include <stdint.h>

#include "lx16a.h"
#include "protocol.h"

namespace curio {

const uint8_t FW_MAJOR = 1;
const uint8_t FW_MINOR = 0;
const uint32_t FW_BUILD = 20261121UL;
const uint32_t LINK_TIMEOUT_MS = 2000;
const uint32_t STATE_PERIOD_MS = 100;
const uint32_t SERVO_REPLY_TIMEOUT_MS = 10;
const uint8_t NUM_WHEELS = 6;
const uint8_t NUM_STEER = 4;
const uint8_t NUM_SERVOS = 10;
const uint8_t CONFIG_SIZE = 22;

struct Config {
  uint8_t proto_ver;
  uint8_t wheel_ids[NUM_WHEELS];
  uint8_t steer_ids[NUM_STEER];
  int8_t steer_trim[NUM_STEER];
  uint16_t cmd_timeout_ms;
  uint8_t pos_rate_hz;
  uint8_t status_rate_hz;
  uint16_t steer_move_ms;
  uint8_t flags;
};

void config_defaults(Config& c);
void config_pack(const Config& c, uint8_t* out);  // CONFIG_SIZE bytes
void config_unpack(const uint8_t* in, Config& c);
bool config_valid(const Config& c);

// The link to the Pi (USB serial on the Mega).
class HostLink {
 public:
  virtual void write(const uint8_t* data, size_t n) = 0;

 protected:
  ~HostLink() {}
};

// The servo bus (Serial1 -> BusLinker on the Mega): write whole packets, read bytes (-1: none).
class ServoLink {
 public:
  virtual void write(const uint8_t* data, uint8_t n) = 0;
  virtual int read() = 0;

 protected:
  ~ServoLink() {}
};

class Controller {
 public:
  Controller(HostLink& host, ServoLink& servos);
  void boot(uint32_t now_ms, uint8_t reset_cause);
  void on_host_byte(uint8_t byte, uint32_t now_ms);
  void poll(uint32_t now_ms);  // frames, watchdogs, servo bus, reports
  void report_rc(uint32_t now_ms, const uint16_t* ch_us, uint8_t n, uint8_t flags, uint8_t counter);
  void note_loop_us(uint16_t us) { if (us > loop_max_us_) loop_max_us_ = us; }
  void set_adc_mv(uint16_t mv) { adc_mv_ = mv; }

  uint8_t state() const { return state_; }
  uint16_t faults() const { return faults_; }
  int16_t wheel_duty(uint8_t i) const { return state_ == STATE_ARMED ? duty_[i] : 0; }
  const Config& config() const { return cfg_; }
  uint16_t rx_crc_errors() const { return parser_.crc_errors; }

 private:
  enum JobKind { JOB_MOTOR, JOB_POSMODE, JOB_TRIM, JOB_TRIM_SAVE, JOB_MOVE, JOB_READ_POS, JOB_READ_VIN, JOB_SWEEP_END, JOB_RAW };
  struct Job {
    uint8_t kind;
    uint8_t id;
    uint8_t slot;
    int16_t a;
    uint16_t b;
  };
  static const uint8_t QUEUE_SIZE = 48;

  void handle_frame(const Frame& f, uint32_t now_ms);
  void send(uint8_t msg_id, const uint8_t* payload, uint8_t len);
  void ack(const Frame& f, uint8_t status);
  void send_state(uint32_t now_ms);
  void send_info();
  void set_state(uint8_t s, uint32_t now_ms);
  void stop_wheels_now();
  void init_steering();
  void start_sweep(uint32_t now_ms);
  void run_servo_bus(uint32_t now_ms);
  void finish_job(bool ok, const lx16a::Packet* reply, uint32_t now_ms);
  void send_status(uint32_t now_ms);
  bool push_job(uint8_t kind, uint8_t id, uint8_t slot, int16_t a, uint16_t b);
  void clear_jobs();

  HostLink& host_;
  ServoLink& servos_;
  FrameParser parser_;
  lx16a::Parser servo_parser_;
  Config cfg_;
  uint8_t state_;
  uint16_t faults_;
  int16_t duty_[NUM_WHEELS];
  uint16_t steer_[NUM_STEER];
  uint32_t last_cmd_ms_;
  uint32_t last_rx_ms_;
  uint32_t last_host_ms_;
  uint16_t rx_ok_;
  uint16_t loop_max_us_;
  uint8_t reset_cause_;
  uint8_t tx_seq_;
  uint32_t next_control_ms_;
  uint32_t next_state_ms_;
  uint32_t next_status_ms_;
  uint16_t adc_mv_;
  bool booted_;
  // servo bus
  Job jobs_[QUEUE_SIZE];
  uint8_t head_;
  uint8_t count_;
  bool waiting_;
  uint32_t sent_ms_;
  uint32_t sweep_ms_;
  bool sweep_active_;
  uint16_t sweep_mask_;
  int16_t pos_[NUM_SERVOS];
  uint8_t dt_[NUM_SERVOS];
  uint16_t vin_[NUM_SERVOS];
  uint8_t comm_errs_[NUM_SERVOS];
  uint8_t vin_slot_;
  uint8_t raw_[lx16a::MAX_PACKET + 6];
  uint8_t raw_n_;
  uint8_t tx_[MAX_PAYLOAD + FRAME_OVERHEAD];
};

}  // namespace curio

#endif
