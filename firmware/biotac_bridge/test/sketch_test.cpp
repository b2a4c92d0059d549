// Runs the bridge sketch itself (biotac_bridge.ino: setup(), loop()) on the host against the
// Arduino API stub in stub/, driven by tests/devices/test_biotac_firmware.py through stdin.
//
// Requests, one per line, each answered with one line:
//   host TEXT     -> "ok": queue the bytes of TEXT as sent by the host ('S', 'X', '?')
//   usb N         -> "ok": Serial.availableForWrite() answers N from now on
//   loop K        -> "ok": call loop() K times
//   out           -> the bytes the sketch wrote to USB since the last "out", hex ("-": none)
//   time          -> the simulated micros(), decimal
#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>

#include <SPI.h>

#include "../biotac_bridge.ino"

int main() {
  setup();
  std::string line;
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string what;
    in >> what;
    if (what == "host") {
      std::string text;
      in >> text;
      for (char c : text) stub::usb_in.push_back(static_cast<uint8_t>(c));
    } else if (what == "usb") {
      in >> stub::usb_free;
    } else if (what == "loop") {
      long k = 0;
      in >> k;
      for (long i = 0; i < k; ++i) loop();
    } else if (what == "out") {
      for (uint8_t b : stub::usb_out) std::printf("%02x", b);
      std::printf(stub::usb_out.empty() ? "-\n" : "\n");
      stub::usb_out.clear();
      std::fflush(stdout);
      continue;
    } else if (what == "time") {
      std::printf("%llu\n", static_cast<unsigned long long>(stub::now_us));
      std::fflush(stdout);
      continue;
    } else {
      std::printf("error: unknown request %s\n", what.c_str());
      std::fflush(stdout);
      continue;
    }
    std::printf("ok\n");
    std::fflush(stdout);
  }
  return 0;
}
