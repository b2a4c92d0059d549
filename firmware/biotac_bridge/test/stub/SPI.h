// The SPI part of the Arduino API stub (see Arduino.h): each byte takes 2 us of simulated time.
#pragma once
#include "Arduino.h"

struct SPISettings {
  SPISettings(uint32_t, uint8_t, uint8_t) {}
};

struct SPIClass {
  void begin() {}
  void beginTransaction(const SPISettings&) {}
  void endTransaction() {}
  uint8_t transfer(uint8_t) {
    stub::now_us += 2;
    ++stub::spi_bytes;
    return stub::cs_low ? stub::miso_counter++ : 0xFF;
  }
};
inline SPIClass SPI;
