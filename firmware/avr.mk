# Build the sketch for the Arduino Mega 2560 with avr-gcc and the Arduino AVR core from Debian
# (no downloads, no Arduino IDE, no Java):
#   sudo apt-get install make gcc-avr avr-libc arduino-core-avr    (+ avrdude to flash)
#   make -f avr.mk                 -> build-mega-atmega2560/curio_base.hex
#   make -f avr.mk upload MONITOR_PORT=/dev/curio-arduino
# The flags are those of the core's platform.txt (Arduino 1.8, board "mega", cpu atmega2560).
# arduino-cli (README.md) builds the same sketch.

ARDUINO_DIR ?= /usr/share/arduino/hardware/arduino/avr
CORE_DIR    := $(ARDUINO_DIR)/cores/arduino
VARIANT_DIR := $(ARDUINO_DIR)/variants/mega
OBJDIR      ?= build-mega-atmega2560
TARGET      := curio_base
MCU         := atmega2560
MONITOR_PORT ?= /dev/curio-arduino
CC  := avr-gcc
CXX := avr-g++
AR  := avr-gcc-ar

DEFINES  := -mmcu=$(MCU) -DF_CPU=16000000L -DARDUINO=10819 -DARDUINO_AVR_MEGA2560 \
            -DARDUINO_ARCH_AVR
# Debian's AVR core is newer than its avr-libc float.h, which lacks DECIMAL_DIG.
INCLUDES := -I$(CORE_DIR) -I$(VARIANT_DIR) -Icurio_base/src -DDECIMAL_DIG=17
COMMON   := -c -g -Os -Wall -Wextra -ffunction-sections -fdata-sections -MMD -flto
CFLAGS   := $(COMMON) -std=gnu11 -fno-fat-lto-objects
CXXFLAGS := $(COMMON) -std=gnu++11 -fpermissive -fno-exceptions -fno-threadsafe-statics \
            -Wno-error=narrowing
LDFLAGS  := -Wall -Wextra -Os -g -flto -fuse-linker-plugin -Wl,--gc-sections -mmcu=$(MCU)

CORE_C   := $(wildcard $(CORE_DIR)/*.c)
CORE_CPP := $(wildcard $(CORE_DIR)/*.cpp)
CORE_S   := $(wildcard $(CORE_DIR)/*.S)
CORE_OBJ := $(patsubst $(CORE_DIR)/%,$(OBJDIR)/core/%.o,$(CORE_C) $(CORE_CPP) $(CORE_S))
OUR_CPP  := $(wildcard curio_base/src/*.cpp)
OUR_OBJ  := $(patsubst %,$(OBJDIR)/%.o,$(OUR_CPP)) $(OBJDIR)/curio_base/$(TARGET).ino.o

all: $(OBJDIR)/$(TARGET).hex

$(OBJDIR)/core/%.c.o: $(CORE_DIR)/%.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(DEFINES) $(INCLUDES) $< -o $@

$(OBJDIR)/core/%.cpp.o: $(CORE_DIR)/%.cpp
	@mkdir -p $(dir $@)
	$(CXX) $(CXXFLAGS) $(DEFINES) $(INCLUDES) $< -o $@

$(OBJDIR)/core/%.S.o: $(CORE_DIR)/%.S
	@mkdir -p $(dir $@)
	$(CC) -c -g -x assembler-with-cpp -flto -MMD $(DEFINES) $(INCLUDES) $< -o $@

$(OBJDIR)/curio_base/src/%.cpp.o: curio_base/src/%.cpp
	@mkdir -p $(dir $@)
	$(CXX) $(CXXFLAGS) $(DEFINES) $(INCLUDES) $< -o $@

# The sketch is C++ with Arduino.h included first (what the IDE's preprocessing does for it).
$(OBJDIR)/curio_base/$(TARGET).ino.o: curio_base/$(TARGET).ino
	@mkdir -p $(dir $@)
	$(CXX) $(CXXFLAGS) $(DEFINES) $(INCLUDES) -x c++ -include Arduino.h $< -o $@

$(OBJDIR)/core.a: $(CORE_OBJ)
	$(AR) rcs $@ $^

$(OBJDIR)/$(TARGET).elf: $(OUR_OBJ) $(OBJDIR)/core.a
	$(CC) $(LDFLAGS) -o $@ $(OUR_OBJ) $(OBJDIR)/core.a -lm

$(OBJDIR)/$(TARGET).hex: $(OBJDIR)/$(TARGET).elf
	avr-objcopy -O ihex -R .eeprom $< $@

upload: $(OBJDIR)/$(TARGET).hex
	avrdude -p $(MCU) -c wiring -P $(MONITOR_PORT) -b 115200 -D -U flash:w:$<:i

clean:
	rm -rf $(OBJDIR)

-include $(CORE_OBJ:.o=.d) $(OUR_OBJ:.o=.d)

.PHONY: all upload clean
