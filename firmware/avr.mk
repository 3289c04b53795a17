# Build the sketch for the Arduino Mega 2560 with Debian's AVR toolchain (no downloads):
#   sudo apt-get install gcc-avr avr-libc arduino-core-avr arduino-mk
#   make -f avr.mk                 -> build-mega-atmega2560/curio_base.hex
#   make -f avr.mk upload MONITOR_PORT=/dev/curio-arduino
# arduino-cli (README.md) builds the same sketch; this route needs only Debian packages.
BOARD_TAG      = mega
BOARD_SUB      = atmega2560
ARDUINO_DIR    = /usr/share/arduino
TARGET         = curio_base
LOCAL_INO_SRCS = curio_base/curio_base.ino
LOCAL_CPP_SRCS = $(wildcard curio_base/src/*.cpp)
CXXFLAGS_STD   = -std=gnu++11
CFLAGS_STD     = -std=gnu11
# Debian's AVR core is newer than its avr-libc float.h, which lacks DECIMAL_DIG.
CPPFLAGS      += -Icurio_base/src -DDECIMAL_DIG=17
OBJDIR        ?= build-mega-atmega2560
include /usr/share/arduino/Arduino.mk
