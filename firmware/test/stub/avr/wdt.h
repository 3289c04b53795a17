// Stand-in for <avr/wdt.h> (compile check only).
#ifndef CURIO_WDT_STUB_H
#define CURIO_WDT_STUB_H
#include <stdint.h>
extern uint8_t MCUSR;
#define WDTO_250MS 4
inline void wdt_disable() {}
inline void wdt_enable(int) {}
inline void wdt_reset() {}
#endif
