// Host test driver for biotac_frame.cpp: built with the system compiler by
// tests/devices/test_biotac_firmware.py, which feeds it requests on stdin and compares every
// answer byte for byte with the Python implementation (src/incipient_slip/devices/biotac.py).
//
// Requests, one per line, answers one line of lower-case hex each:
//   crc HEX                                   -> CRC-16 of the bytes
//   data COUNTER TIME_US N STATUS PATTERN HEX -> a data frame (HEX: 44 x N x 2 reply bytes)
//   prop SENSOR PROPERTY_ID HEX               -> a property frame ("-" for no data)
//   schedule                                  -> the 44 commands of a frame
//   commands                                  -> command_byte(0..63)
//   parity                                    -> with_odd_parity(0..127)
// Before reading requests it checks the CRC's check value and that the written-out schedule
// equals the commands computed from channel indices; it exits 1 if not.
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "biotac_frame.h"

using namespace biotac;

static std::vector<uint8_t> from_hex(const std::string& text) {
  std::vector<uint8_t> out;
  if (text == "-") return out;
  for (size_t i = 0; i + 1 < text.size(); i += 2) {
    out.push_back(static_cast<uint8_t>(std::strtoul(text.substr(i, 2).c_str(), nullptr, 16)));
  }
  return out;
}

static void print_hex(const uint8_t* data, size_t len) {
  for (size_t i = 0; i < len; ++i) std::printf("%02x", data[i]);
  std::printf("\n");
}

static int self_check() {
  const char* check = "123456789";
  if (crc16(reinterpret_cast<const uint8_t*>(check), 9) != 0x29B1) {
    std::fprintf(stderr, "crc16 check value is not 0x29B1\n");
    return 1;
  }
  uint8_t expected[kSlotsPerFrame];
  for (int e = 0; e < 19; ++e) {
    expected[2 * e] = command_byte(static_cast<uint8_t>(17 + e));
    expected[2 * e + 1] = command_byte(0);
  }
  const uint8_t tail[6] = {command_byte(1), command_byte(0), command_byte(2), command_byte(0),
                           command_byte(3), command_byte(0)};
  std::memcpy(expected + 38, tail, 6);
  if (std::memcmp(expected, kFrameSchedule, kSlotsPerFrame) != 0) {
    std::fprintf(stderr, "kFrameSchedule differs from the commands of its channels\n");
    return 1;
  }
  return 0;
}

int main() {
  if (self_check() != 0) return 1;
  std::string line;
  std::vector<uint8_t> out(data_frame_bytes(kMaxBiotacs) + kPropertyMaxBytes);
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string op;
    in >> op;
    if (op == "crc") {
      std::string hex;
      in >> hex;
      std::vector<uint8_t> data = from_hex(hex);
      std::printf("%04x\n", crc16(data.data(), data.size()));
    } else if (op == "data") {
      unsigned long counter, time_us, n, status, pattern;
      std::string hex;
      in >> counter >> time_us >> n >> status >> pattern >> hex;
      std::vector<uint8_t> replies = from_hex(hex);
      if (replies.size() != kSlotsPerFrame * 2u * n) {
        std::printf("error: %zu reply bytes for n=%lu\n", replies.size(), n);
        continue;
      }
      size_t len = pack_data_frame(out.data(), static_cast<uint32_t>(counter), static_cast<uint32_t>(time_us),
                                   replies.data(), static_cast<uint8_t>(n), static_cast<uint16_t>(status),
                                   static_cast<uint16_t>(pattern));
      if (len == 0) std::printf("error: n=%lu out of range\n", n);
      else print_hex(out.data(), len);
    } else if (op == "prop") {
      unsigned long sensor, pid;
      std::string hex;
      in >> sensor >> pid >> hex;
      std::vector<uint8_t> data = from_hex(hex);
      size_t len = pack_property_frame(out.data(), static_cast<uint8_t>(sensor), static_cast<uint8_t>(pid),
                                       data.data(), static_cast<uint8_t>(data.size()));
      if (len == 0) std::printf("error: %zu property bytes\n", data.size());
      else print_hex(out.data(), len);
    } else if (op == "schedule") {
      print_hex(kFrameSchedule, kSlotsPerFrame);
    } else if (op == "commands") {
      uint8_t cmds[64];
      for (int i = 0; i < 64; ++i) cmds[i] = command_byte(static_cast<uint8_t>(i));
      print_hex(cmds, 64);
    } else if (op == "parity") {
      uint8_t bytes[128];
      for (int i = 0; i < 128; ++i) bytes[i] = with_odd_parity(static_cast<uint8_t>(i));
      print_hex(bytes, 128);
    } else if (!op.empty()) {
      std::printf("error: unknown request %s\n", op.c_str());
    }
    std::fflush(stdout);
  }
  return 0;
}
