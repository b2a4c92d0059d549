// BioTac bridge: the SPI word layer and the USB frame format, in plain C++ (no Arduino headers),
// so that the same code runs in the firmware and in the host test (test/host_test.cpp).
// The format is documented in docs/hardware/biotac-bridge.md; the Python side is
// src/incipient_slip/devices/biotac.py, and the test suite checks the two byte for byte.
#pragma once
#include <stddef.h>
#include <stdint.h>

namespace biotac {

constexpr uint32_t kSlotRateHz = 4400;
constexpr uint8_t kSlotsPerFrame = 44;
constexpr uint32_t kFrameUs = 10000;
constexpr uint32_t kAfterCommandDelayUs = 50;  // command -> first read
constexpr uint32_t kInterwordDelayUs = 10;     // between the sensors' reads
constexpr uint8_t kMaxBiotacs = 5;
constexpr uint8_t kBridgeVersion = 1;

constexpr uint8_t kSyncData[2] = {0xB1, 0x0C};
constexpr uint8_t kSyncProperty[2] = {0xB1, 0x0D};
constexpr size_t kDataHeaderBytes = 14;   // sync 2, version 1, n 1, counter 4, time 4, pattern 2
constexpr size_t kPropertyHeaderBytes = 6;
constexpr size_t kPropertyMaxBytes = 64;

constexpr uint16_t kStatusOverrun = 0x0001;
constexpr uint16_t kStatusTxDropped = 0x0002;
constexpr uint16_t kStatusStarted = 0x0004;

constexpr uint8_t kReadProperty = 0x61;
constexpr uint8_t kPropFlexVersion = 0x10;
constexpr uint8_t kPropFirmwareVersion = 0x13;
constexpr uint8_t kPropSerialNumber = 0x15;
constexpr uint8_t kPropCpuSpeed = 0x61;

// The byte data7 << 1 | p whose bit count is odd (commands and reply bytes).
uint8_t with_odd_parity(uint8_t data7);
// True when the byte's bit count is odd.
bool has_odd_parity(uint8_t byte);
// The sampling command of channel index (PAC 0, PDC 1, TAC 2, TDC 3, E01..E19 17..35).
uint8_t command_byte(uint8_t channel);
// The 12-bit value of a reply (parity not checked).
uint16_t decode_word(uint8_t b0, uint8_t b1);

// The 44 commands of one frame: E01 PAC E02 PAC ... E19 PAC PDC PAC TAC PAC TDC PAC.
extern const uint8_t kFrameSchedule[kSlotsPerFrame];

// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection): "123456789" -> 0x29B1.
uint16_t crc16(const uint8_t* data, size_t len, uint16_t crc = 0xFFFF);

// Size of a data frame for n sensors.
constexpr size_t data_frame_bytes(uint8_t n) { return kDataHeaderBytes + kSlotsPerFrame * 2u * n + 4; }

// Writes one data frame into out (capacity data_frame_bytes(n)); replies are 44 x n x 2 raw
// bytes, slot-major. Returns the bytes written, 0 if n is out of range.
size_t pack_data_frame(uint8_t* out, uint32_t counter, uint32_t device_time_us,
                       const uint8_t* replies, uint8_t n, uint16_t status, uint16_t pattern);

// Writes one property frame (raw bytes as read, terminator excluded). Returns bytes written,
// 0 if len exceeds kPropertyMaxBytes.
size_t pack_property_frame(uint8_t* out, uint8_t sensor, uint8_t property_id,
                           const uint8_t* data, uint8_t len);

}  // namespace biotac
