// A stub of the Arduino/Teensyduino API the sketch uses, for running biotac_bridge.ino's
// setup() and loop() on the host (test/sketch_test.cpp). Time is simulated: micros() advances
// 1 us per call (so busy waits end), delayMicroseconds() and each SPI byte advance it too.
// USB: the host's bytes are queued for Serial.read(); Serial.availableForWrite() is what the
// test sets (a full USB buffer is 0); written bytes collect in stub::usb_out.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include <deque>
#include <vector>

namespace stub {
inline uint64_t now_us = 0;
inline std::deque<uint8_t> usb_in;
inline std::vector<uint8_t> usb_out;
inline int usb_free = 4096;          // what availableForWrite() answers
inline uint8_t cs_low = 0;           // bit j: chip select j is active (low)
inline uint8_t miso_counter = 0;     // each selected read returns the next byte
inline uint32_t spi_bytes = 0;
}  // namespace stub

constexpr uint8_t LOW = 0, HIGH = 1, OUTPUT = 1, MSBFIRST = 1, SPI_MODE0 = 0;

inline uint32_t micros() { return static_cast<uint32_t>(stub::now_us++); }
inline void delayMicroseconds(uint32_t us) { stub::now_us += us; }
inline void pinMode(uint8_t, uint8_t) {}
inline void digitalWriteFast(uint8_t pin, uint8_t value) {
  // CS_PINS of the sketch are 10, 9, 8, 7, 6: sensor j is pin 10 - j
  const uint8_t bit = static_cast<uint8_t>(1u << (10 - pin));
  stub::cs_low = value == LOW ? (stub::cs_low | bit) : (stub::cs_low & ~bit);
}

struct UsbSerial {
  void begin(int) {}
  int available() { return static_cast<int>(stub::usb_in.size()); }
  int read() {
    if (stub::usb_in.empty()) return -1;
    const int c = stub::usb_in.front();
    stub::usb_in.pop_front();
    return c;
  }
  int availableForWrite() { return stub::usb_free; }
  size_t write(const uint8_t* data, size_t len) {
    stub::usb_out.insert(stub::usb_out.end(), data, data + len);
    return len;
  }
  void send_now() {}
};
inline UsbSerial Serial;
