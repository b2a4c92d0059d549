// BioTac USB bridge for a Teensy 4.0/4.1 (Arduino IDE + Teensyduino, USB Type "Serial").
//
// Owns the BioTac's 4.4 kHz SPI schedule and streams each 10 ms frame of raw replies to the
// host over USB-CDC in the format of docs/hardware/biotac-bridge.md (packing and CRC in
// biotac_frame.cpp, which the host test suite checks against the Python decoder).
//
// Host commands (single ASCII bytes): 'S' start streaming, 'X' stop, '?' stop and send the
// properties of every sensor (flex version, firmware version, serial number, CPU speed).
//
// Wiring (docs/hardware.md): SPI0 SCK 13, MOSI 11, MISO 12; one chip select per BioTac on
// CS_PINS, active low. Set N_BIOTACS to the number of sensors wired.
#include <SPI.h>

#include "biotac_frame.h"

using namespace biotac;

constexpr uint8_t N_BIOTACS = 1;
static_assert(N_BIOTACS >= 1 && N_BIOTACS <= kMaxBiotacs, "N_BIOTACS must be 1 to 5 (sensors wired)");
constexpr uint8_t CS_PINS[kMaxBiotacs] = {10, 9, 8, 7, 6};
constexpr uint32_t SPI_HZ = 4400000;           // BioTac: mode 0, MSB first, 4.4 MHz
constexpr uint32_t OVERRUN_SLACK_US = 20;      // a slot starting later than this is an overrun
const SPISettings kSpi(SPI_HZ, MSBFIRST, SPI_MODE0);

static uint8_t replies[kSlotsPerFrame * 2 * N_BIOTACS];
static uint8_t frame[data_frame_bytes(N_BIOTACS)];
static uint8_t property_buf[kPropertyHeaderBytes + kPropertyMaxBytes + 2];
static const uint16_t kPattern = crc16(kFrameSchedule, kSlotsPerFrame);

static bool streaming = false;
static uint32_t counter = 0;
static uint32_t stream_start_us = 0;
static uint32_t slot_index = 0;                // slots since the stream started
static uint16_t pending_status = 0;            // carried into the next frame

static void select_all(bool on) {
  for (uint8_t j = 0; j < N_BIOTACS; ++j) digitalWriteFast(CS_PINS[j], on ? LOW : HIGH);
}

static void select_one(uint8_t j, bool on) { digitalWriteFast(CS_PINS[j], on ? LOW : HIGH); }

// One slot: the command to all sensors, 50 us for them to sample, then two bytes from each.
static void run_slot(uint8_t command, uint8_t* out) {
  SPI.beginTransaction(kSpi);
  select_all(true);
  SPI.transfer(command);
  SPI.transfer(0x00);
  select_all(false);
  delayMicroseconds(kAfterCommandDelayUs);
  for (uint8_t j = 0; j < N_BIOTACS; ++j) {
    select_one(j, true);
    out[2 * j] = SPI.transfer(0x00);
    out[2 * j + 1] = SPI.transfer(0x00);
    select_one(j, false);
    delayMicroseconds(kInterwordDelayUs);
  }
  SPI.endTransaction();
}

// Start of slot k after the stream's start, us; exact over any run length (no drift).
static uint32_t slot_due_us(uint32_t k) {
  return stream_start_us + static_cast<uint32_t>((static_cast<uint64_t>(k) * 1000000u) / kSlotRateHz);
}

static void send_frame(uint32_t device_time_us, uint16_t status) {
  const size_t len = pack_data_frame(frame, counter, device_time_us, replies, N_BIOTACS, status, kPattern);
  ++counter;
  // Never block the schedule on USB: a frame the host cannot take now is dropped, the counter
  // still advances (the host sees the gap) and the next frame says so in its status.
  if (static_cast<size_t>(Serial.availableForWrite()) >= len) {
    Serial.write(frame, len);
  } else {
    pending_status |= kStatusTxDropped;
  }
}

static void read_property(uint8_t j, uint8_t pid) {
  uint8_t data[kPropertyMaxBytes];
  uint8_t len = 0;
  SPI.beginTransaction(kSpi);
  select_one(j, true);
  SPI.transfer(kReadProperty);
  SPI.transfer(pid);
  select_one(j, false);
  delayMicroseconds(kAfterCommandDelayUs);
  if (pid == kPropCpuSpeed) {
    select_one(j, true);
    data[len++] = SPI.transfer(0x00);
    data[len++] = SPI.transfer(0x00);
    select_one(j, false);
  } else {
    // Strings end at 0x00; an absent sensor's MISO reads 0xFF, which ends the read too.
    while (len < kPropertyMaxBytes) {
      select_one(j, true);
      const uint8_t b = SPI.transfer(0x00);
      select_one(j, false);
      delayMicroseconds(kInterwordDelayUs);
      if (b == 0x00 || b == 0xFF) break;
      data[len++] = b;
    }
  }
  SPI.endTransaction();
  const size_t n = pack_property_frame(property_buf, j, pid, data, len);
  Serial.write(property_buf, n);
}

static void send_properties() {
  const uint8_t pids[] = {kPropFlexVersion, kPropFirmwareVersion, kPropSerialNumber, kPropCpuSpeed};
  for (uint8_t j = 0; j < N_BIOTACS; ++j) {
    for (uint8_t pid : pids) read_property(j, pid);
  }
  Serial.send_now();
}

static void handle_host() {
  while (Serial.available() > 0) {
    const int c = Serial.read();
    if (c == 'S' && !streaming) {
      streaming = true;
      stream_start_us = micros();
      slot_index = 0;
      pending_status = kStatusStarted;
    } else if (c == 'X') {
      streaming = false;
    } else if (c == '?') {
      streaming = false;
      send_properties();
    }
  }
}

void setup() {
  for (uint8_t j = 0; j < kMaxBiotacs; ++j) {
    pinMode(CS_PINS[j], OUTPUT);
    digitalWriteFast(CS_PINS[j], HIGH);
  }
  SPI.begin();
  Serial.begin(0);  // USB-CDC: the baud rate is ignored
}

void loop() {
  handle_host();
  if (!streaming) return;
  const uint32_t slot_in_frame = slot_index % kSlotsPerFrame;
  const uint32_t due = slot_due_us(slot_index);
  while (static_cast<int32_t>(micros() - due) < 0) {
  }
  if (micros() - due > OVERRUN_SLACK_US) pending_status |= kStatusOverrun;
  run_slot(kFrameSchedule[slot_in_frame], replies + slot_in_frame * 2 * N_BIOTACS);
  ++slot_index;
  if (slot_in_frame == kSlotsPerFrame - 1) {
    // Device time: the bridge's microsecond clock (since boot) at the frame's first command.
    const uint32_t frame_start_us = slot_due_us(slot_index - kSlotsPerFrame);
    const uint16_t status = pending_status;
    pending_status = 0;  // before sending: send_frame sets kStatusTxDropped for the next frame
    send_frame(frame_start_us, status);
  }
}
