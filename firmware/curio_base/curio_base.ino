// Curio base controller for the Arduino Mega 2560: the thin Arduino layer around the portable
// core in src/ (protocol, state machine, watchdogs, LX-16A bus scheduler, SUMD decoder).
//
//   Serial  (USB, 115200) : the Pi, framed protocol (hardware.md section 3.2)
//   Serial1 (pins 18/19)  : BusLinker TTL header -> LX-16A servo bus, 115200
//   Serial2 (RX2, pin 17) : Graupner SUMD receiver output, 115200
//   A0 (optional)         : battery divider (set CURIO_ADC_DIVIDER to the ratio, 0 = none)
//
// The wheels are stopped in setup() before anything else (Controller::boot), so a reset never
// leaves them running. See firmware/README.md for flashing with arduino-cli.
#include <avr/wdt.h>

#include "src/controller.h"
#include "src/sumd.h"

#ifndef CURIO_USE_WDT
#define CURIO_USE_WDT 0  // 1: hardware watchdog (needs a bootloader that clears WDRF, e.g. optiboot)
#endif
#ifndef CURIO_ADC_DIVIDER
#define CURIO_ADC_DIVIDER 0.0f  // e.g. 3.0 for a 20k/10k divider on A0
#endif

// MCUSR is saved before the core runs, then cleared (reset cause for STATE.reset_cause).
uint8_t g_mcusr __attribute__((section(".noinit")));
void save_mcusr(void) __attribute__((naked)) __attribute__((used)) __attribute__((section(".init3")));
void save_mcusr(void) {
  g_mcusr = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

class SerialHost : public curio::HostLink {
 public:
  void write(const uint8_t* data, size_t n) override { Serial.write(data, n); }
};

class BusLinker : public curio::ServoLink {
 public:
  void write(const uint8_t* data, uint8_t n) override { Serial1.write(data, n); }
  int read() override { return Serial1.read(); }
};

static SerialHost g_host;
static BusLinker g_servos;
static curio::Controller g_ctrl(g_host, g_servos);
static curio::SumdDecoder g_sumd;
static uint32_t g_last_rc_ms = 0;
static uint32_t g_next_rc_report_ms = 0;
static uint8_t g_rc_frames = 0;
static bool g_rc_new = false;

void setup() {
  Serial1.begin(115200);  // servo bus first: boot() stops the wheels on it
  Serial.begin(115200);
  Serial2.begin(115200);
  g_ctrl.boot(millis(), g_mcusr);
#if CURIO_USE_WDT
  wdt_enable(WDTO_250MS);
#endif
}

void loop() {
  uint32_t start_us = micros();
  uint32_t now = millis();
  while (Serial.available() > 0) g_ctrl.on_host_byte((uint8_t)Serial.read(), now);
  while (Serial2.available() > 0) {
    if (g_sumd.push((uint8_t)Serial2.read())) {
      ++g_rc_frames;
      g_rc_new = true;
      if (g_sumd.status() != 0x81) g_last_rc_ms = now;
    }
  }
  bool rc_enabled = (g_ctrl.config().flags & 0x02) != 0;  // SET_CONFIG flags bit1
  if (rc_enabled && (int32_t)(now - g_next_rc_report_ms) >= 0) {  // 20 Hz RC report
    g_next_rc_report_ms = now + 50;
    if (g_rc_frames > 0) {
      uint16_t ch[curio::SumdDecoder::MAX_CHANNELS];
      uint8_t n = g_sumd.channels();
      for (uint8_t i = 0; i < n; ++i) ch[i] = g_sumd.channel_us(i);
      uint8_t flags = (g_rc_new ? 0x01 : 0) | (g_sumd.status() == 0x81 ? 0x02 : 0) |
                      ((now - g_last_rc_ms) > 100 ? 0x04 : 0) | (g_sumd.status() == 0x00 ? 0x08 : 0);
      g_ctrl.report_rc(now, ch, n, flags, g_rc_frames);
      g_rc_new = false;
    }
  }
  if (CURIO_ADC_DIVIDER > 0.0f) g_ctrl.set_adc_mv((uint16_t)(analogRead(A0) * (5000.0f / 1023.0f) * CURIO_ADC_DIVIDER));
  g_ctrl.poll(now);
  uint32_t took = micros() - start_us;
  g_ctrl.note_loop_us((uint16_t)(took > 65535u ? 65535u : took));
#if CURIO_USE_WDT
  wdt_reset();
#endif
}
