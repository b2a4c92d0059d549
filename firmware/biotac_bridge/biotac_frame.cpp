// See biotac_frame.h. Multi-byte fields are little endian (the byte order of the Teensy and
// RP2040 and of the host), written byte by byte so the code does not depend on it.
#include "biotac_frame.h"

namespace biotac {

bool has_odd_parity(uint8_t byte) {
  byte ^= byte >> 4;
  byte ^= byte >> 2;
  byte ^= byte >> 1;
  return byte & 1u;
}

uint8_t with_odd_parity(uint8_t data7) {
  uint8_t byte = static_cast<uint8_t>((data7 & 0x7Fu) << 1);
  return has_odd_parity(byte) ? byte : static_cast<uint8_t>(byte | 1u);
}

uint8_t command_byte(uint8_t channel) { return with_odd_parity(static_cast<uint8_t>(0x40u | channel)); }

uint16_t decode_word(uint8_t b0, uint8_t b1) {
  return static_cast<uint16_t>((b0 >> 1) * 32u + (b1 >> 3));
}

// Written out (parity included) so the table reads like the protocol documentation.
const uint8_t kFrameSchedule[kSlotsPerFrame] = {
    0xA2, 0x80, 0xA4, 0x80, 0xA7, 0x80, 0xA8, 0x80, 0xAB, 0x80, 0xAD, 0x80, 0xAE, 0x80,
    0xB0, 0x80, 0xB3, 0x80, 0xB5, 0x80, 0xB6, 0x80, 0xB9, 0x80, 0xBA, 0x80, 0xBC, 0x80,
    0xBF, 0x80, 0xC1, 0x80, 0xC2, 0x80, 0xC4, 0x80, 0xC7, 0x80, 0x83, 0x80, 0x85, 0x80,
    0x86, 0x80};

uint16_t crc16(const uint8_t* data, size_t len, uint16_t crc) {
  for (size_t i = 0; i < len; ++i) {
    crc ^= static_cast<uint16_t>(data[i]) << 8;
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc & 0x8000u) ? static_cast<uint16_t>((crc << 1) ^ 0x1021u) : static_cast<uint16_t>(crc << 1);
    }
  }
  return crc;
}

static uint8_t* put_u16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
  return p + 2;
}

static uint8_t* put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
  return p + 4;
}

size_t pack_data_frame(uint8_t* out, uint32_t counter, uint32_t device_time_us,
                       const uint8_t* replies, uint8_t n, uint16_t status, uint16_t pattern) {
  if (n < 1 || n > kMaxBiotacs) return 0;
  uint8_t* p = out;
  *p++ = kSyncData[0];
  *p++ = kSyncData[1];
  *p++ = kBridgeVersion;
  *p++ = n;
  p = put_u32(p, counter);
  p = put_u32(p, device_time_us);
  p = put_u16(p, pattern);
  const size_t reply_bytes = kSlotsPerFrame * 2u * n;
  for (size_t i = 0; i < reply_bytes; ++i) *p++ = replies[i];
  p = put_u16(p, status);
  p = put_u16(p, crc16(out + 2, static_cast<size_t>(p - out) - 2));
  return static_cast<size_t>(p - out);
}

size_t pack_property_frame(uint8_t* out, uint8_t sensor, uint8_t property_id,
                           const uint8_t* data, uint8_t len) {
  if (len > kPropertyMaxBytes) return 0;
  uint8_t* p = out;
  *p++ = kSyncProperty[0];
  *p++ = kSyncProperty[1];
  *p++ = kBridgeVersion;
  *p++ = sensor;
  *p++ = property_id;
  *p++ = len;
  for (uint8_t i = 0; i < len; ++i) *p++ = data[i];
  p = put_u16(p, crc16(out + 2, static_cast<size_t>(p - out) - 2));
  return static_cast<size_t>(p - out);
}

}  // namespace biotac
