"""BioTac SPI words and the USB bridge's frames: what the reader, the emulator and the firmware share.

The BioTac is an SPI slave (mode 0, MSB first, 4.4 MHz). Every 1/4400 s the master sends one
two-byte command `[cmd, 0x00]` to all sensors at once, waits 50 µs, then clocks a two-byte reply
out of each sensor; the reply read in a slot answers that slot's command. 44 slots make one 10 ms
frame (`FRAME_SCHEDULE`): 22 P_AC samples (2200 Hz) and one each of E01..E19, P_DC, T_AC, T_DC.

Command byte: `0x80 | channel << 1 | p`, reply byte: `data7 << 1 | p`, with `p` making the byte's
bit count odd; a 12-bit reply value is `(b0 >> 1) * 32 + (b1 >> 3)`. Error words (0xA5xx) all fail
that parity test and are told apart by their second byte. Sources: SynTouch's BioTac C library
for the Cheetah adapter as published in kth-ros-pkg/biotac_driver (biotac.h, biotac.c); units
from the BioTac Product Manual V21 (see `UNIT_SOURCES`).

The bridge (firmware/biotac_bridge, docs/hardware/biotac-bridge.md) owns the 4.4 kHz schedule and
streams each frame's raw replies, unmodified, so the host checks parity and error words the same
way for every transport. `FrameParser` turns a byte stream into frames; `BridgeStream` checks them
(CRC, schedule, counter, device time, parity, error words) and counts every fault per channel.
"""
from __future__ import annotations

import binascii
import math
import struct
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from incipient_slip.messages import (
    BIOTAC_CHANNELS, BIOTAC_ERROR_WORDS, PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME, SLOW_RATE_HZ,
)

# --- timing --------------------------------------------------------------------------------

SLOT_RATE_HZ = 4400
SLOTS_PER_FRAME = 44
FRAME_RATE_HZ = SLOT_RATE_HZ // SLOTS_PER_FRAME          # 100
FRAME_US = 1_000_000 // FRAME_RATE_HZ                    # 10 000 µs
AFTER_COMMAND_DELAY_NS = 50_000                          # command -> first read (biotac.h)
INTERWORD_DELAY_NS = 10_000                              # between sensors' reads (biotac.h)
MAX_BIOTACS = 5                                          # chip selects on one bus
assert FRAME_RATE_HZ == SLOW_RATE_HZ and FRAME_RATE_HZ * PAC_SAMPLES_PER_FRAME == PAC_RATE_HZ


def slot_offset_ns(slot: int) -> int:
    """Return the start of a slot after the frame's start, ns (rounded; slots are 227.27 µs)."""
    return (slot * 1_000_000_000 + SLOT_RATE_HZ // 2) // SLOT_RATE_HZ


# --- parity, commands, words -------------------------------------------------------------

ODD_PARITY = np.array([bin(b).count("1") % 2 == 1 for b in range(256)], dtype=bool)


def with_odd_parity(data7: int) -> int:
    """Return the byte `data7 << 1 | p` whose bit count is odd (BioTac replies and commands)."""
    byte = (data7 & 0x7F) << 1
    return byte if ODD_PARITY[byte] else byte | 1


CHANNELS: dict[str, int] = {"PAC": 0, "PDC": 1, "TAC": 2, "TDC": 3, "HAL": 15, "REV": 16,
                            **{f"E{i:02d}": 16 + i for i in range(1, 20)}}
CHANNEL_OF_INDEX = {index: name for name, index in CHANNELS.items()}


def command_byte(channel: str) -> int:
    """Return the sampling command of a channel: 0x80 | index << 1 | odd parity."""
    return with_odd_parity(0x40 | CHANNELS[channel])


def channel_of_command(cmd: int) -> int:
    """Return the channel index a sampling command names (whether or not it exists)."""
    return (cmd & 0x7E) >> 1


RESEND = 0x20
READ_PROPERTY = 0x61
# Property ids after READ_PROPERTY. The bridge reads the first four the way SynTouch's library
# does (strings up to a 0x00/0xFF terminator; CPU speed two bytes, big endian); the sampling
# frequency and pattern ids are listed for completeness, their reply format is not verified.
PROPERTIES = {"flex_version": 0x10, "firmware_version": 0x13, "serial_number": 0x15,
              "cpu_speed": 0x61, "sampling_frequency": 0x70, "sampling_pattern": 0x73}
PROPERTY_NAMES = {pid: name for name, pid in PROPERTIES.items()}
BRIDGE_PROPERTIES = ("flex_version", "firmware_version", "serial_number", "cpu_speed")
PROPERTY_MAX_BYTES = 64

FRAME_CHANNELS: tuple[str, ...] = tuple(
    name for e in range(1, 20) for name in (f"E{e:02d}", "PAC")) + (
    "PDC", "PAC", "TAC", "PAC", "TDC", "PAC")
FRAME_SCHEDULE: bytes = bytes(command_byte(c) for c in FRAME_CHANNELS)
assert len(FRAME_SCHEDULE) == SLOTS_PER_FRAME

# Channels as the reader reports them (fault counters are arrays in this order; the wire contract).
REPORTED_CHANNELS: tuple[str, ...] = BIOTAC_CHANNELS
_REPORTED_INDEX = {name: i for i, name in enumerate(REPORTED_CHANNELS)}
SLOT_REPORTED = np.array([_REPORTED_INDEX[c] for c in FRAME_CHANNELS], dtype=np.intp)
PAC_SLOTS = np.array([s for s, c in enumerate(FRAME_CHANNELS) if c == "PAC"], dtype=np.intp)
ELECTRODE_SLOTS = np.array([FRAME_CHANNELS.index(f"E{i:02d}") for i in range(1, 20)], dtype=np.intp)
PDC_SLOT, TAC_SLOT, TDC_SLOT = (FRAME_CHANNELS.index(c) for c in ("PDC", "TAC", "TDC"))
PAC_LAST_SLOT_NS = slot_offset_ns(int(PAC_SLOTS[-1]))

ERROR_WORDS: dict[int, str] = {
    0xA545: "parity_error",                 # "EE": the command byte failed its parity
    0xA53F: "unknown_command",              # "E?"
    0xA52E: "insufficient_delay",           # "E."
    0xA52D: "insufficient_sampling_delay",  # "E-": read too soon after the sampling command
    0xA558: "channel_not_recognized",       # "EX"
    0xA55F: "nothing_to_resend",            # "E_"
    0xA552: "read_only",                    # "ER"
    0xA557: "write_error",                  # "EW"
}
ERROR_WORD_OF = {name: word for word, name in ERROR_WORDS.items()}
ERROR_NAMES: tuple[str, ...] = BIOTAC_ERROR_WORDS
assert tuple(ERROR_WORDS.values()) == ERROR_NAMES


def encode_word(value: int) -> bytes:
    """Return the two reply bytes of a 12-bit value, each with odd parity."""
    if not 0 <= value <= 0xFFF:
        raise ValueError(f"a BioTac reply holds 12 bits, got {value}")
    return bytes((with_odd_parity(value >> 5), with_odd_parity((value & 0x1F) << 2)))


def decode_word(b0: int, b1: int) -> int:
    """Return the 12-bit value of a reply (parity not checked)."""
    return (b0 >> 1) * 32 + (b1 >> 3)


def word_status(b0: int, b1: int) -> str:
    """Return "ok", the error word's name, or "parity" for a reply that fails its parity test."""
    if ODD_PARITY[b0] and ODD_PARITY[b1]:
        return "ok"
    return ERROR_WORDS.get(b0 << 8 | b1, "parity")


# --- units -------------------------------------------------------------------------------

UNIT_SOURCES = {
    "pdc_pa_per_count": "BioTac Product Manual V21 (36.5 Pa/bit; not verified here)",
    "pac_pa_per_count": "BioTac Product Manual V21 (0.37 Pa/bit, range +/-0.76 kPa; not verified here)",
    "pac_range_pa": "BioTac Product Manual V21 (+/-0.76 kPa; not verified here)",
    "pac_zero_counts": "assumed: mid-scale of the 12-bit ADC (P_AC is AC-coupled); override per sensor",
    "electrode_reference_kohm": "BioTac Product Manual V21: Z = (4095 / E - 1) * 10 kOhm (not verified here)",
}


@dataclass(frozen=True)
class BiotacUnits:
    """Conversion of raw counts to physical units; one place a lab overrides (`load_units`)."""

    pdc_pa_per_count: float = 36.5
    pac_pa_per_count: float = 0.37
    pac_range_pa: float = 760.0
    pac_zero_counts: int = 2048
    electrode_reference_kohm: float = 10.0

    def electrode_impedance_kohm(self, counts: np.ndarray) -> np.ndarray:
        """Return electrode impedances, kOhm, from raw counts (inf at 0 counts)."""
        counts = np.asarray(counts, dtype=float)
        with np.errstate(divide="ignore"):
            return (4095.0 / counts - 1.0) * self.electrode_reference_kohm


def load_units(path: str | Path | None) -> BiotacUnits:
    """Return the units of a YAML file `{field: value}` over the defaults (None or "": defaults).

    ValueError names the file and the key that is unknown or not a positive finite number.
    """
    if not path:
        return BiotacUnits()
    import yaml
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read the BioTac units file ({exc})") from None
    known = {f.name: f.type for f in fields(BiotacUnits)}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a map of {', '.join(known)}")
    for key, value in data.items():
        if key not in known:
            raise ValueError(f"{path}: unknown unit {key!r}; known: {', '.join(known)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or value < 0:
            raise ValueError(f"{path}: {key} = {value!r} is not a finite number >= 0")
    if "pac_zero_counts" in data:
        data["pac_zero_counts"] = int(data["pac_zero_counts"])
    return BiotacUnits(**data)


# --- bridge frames -----------------------------------------------------------------------

SYNC_DATA = b"\xB1\x0C"
SYNC_PROPERTY = b"\xB1\x0D"
BRIDGE_VERSION = 1
_DATA_HEADER = struct.Struct("<BBIIH")       # version, n_biotacs, counter, device time µs, pattern
_PROPERTY_HEADER = struct.Struct("<BBBB")    # version, sensor, property id, length
DATA_HEADER_BYTES = 2 + _DATA_HEADER.size    # 14
PROPERTY_HEADER_BYTES = 2 + _PROPERTY_HEADER.size

# Status bits the bridge sets in a data frame.
STATUS_OVERRUN = 0x0001      # a slot of this frame started late (schedule overrun)
STATUS_TX_DROPPED = 0x0002   # the USB queue was full: frames before this one were dropped
STATUS_STARTED = 0x0004      # first frame after a start command

# Host -> bridge commands (single ASCII bytes).
CMD_START, CMD_STOP, CMD_PROPERTIES = b"S", b"X", b"?"


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """Return the CRC-16/CCITT-FALSE of data (poly 0x1021, init 0xFFFF; "123456789" -> 0x29B1)."""
    return binascii.crc_hqx(data, crc)


SCHEDULE_CRC = crc16(FRAME_SCHEDULE)


def data_frame_bytes(n_biotacs: int) -> int:
    """Return the size of a data frame for n sensors: header, 44 x n words, status, CRC."""
    return DATA_HEADER_BYTES + SLOTS_PER_FRAME * 2 * n_biotacs + 4


@dataclass(frozen=True)
class DataFrame:
    """One 10 ms bridge frame: raw replies in slot order (slot-major, then sensor)."""

    n_biotacs: int
    counter: int
    device_time_us: int
    pattern: int
    replies: bytes
    status: int


@dataclass(frozen=True)
class PropertyFrame:
    """A property the bridge read from one sensor: the raw bytes, terminator excluded."""

    sensor: int
    property_id: int
    data: bytes

    @property
    def name(self) -> str:
        return PROPERTY_NAMES.get(self.property_id, f"0x{self.property_id:02X}")


@dataclass(frozen=True)
class FrameError:
    """Bytes the parser could not take as a frame: kind "crc", "header" or "skipped" (garbage)."""

    kind: str
    nbytes: int
    detail: str = ""


def pack_data_frame(counter: int, device_time_us: int, replies: bytes, n_biotacs: int,
                    status: int = 0, pattern: int = SCHEDULE_CRC) -> bytes:
    """Return the bytes of a data frame (counter and time wrap at 2**32)."""
    if not 1 <= n_biotacs <= MAX_BIOTACS:
        raise ValueError(f"n_biotacs must be 1..{MAX_BIOTACS}, got {n_biotacs}")
    if len(replies) != SLOTS_PER_FRAME * 2 * n_biotacs:
        raise ValueError(f"{len(replies)} reply bytes for {n_biotacs} sensors, "
                         f"expected {SLOTS_PER_FRAME * 2 * n_biotacs}")
    body = _DATA_HEADER.pack(BRIDGE_VERSION, n_biotacs, counter & 0xFFFFFFFF,
                             device_time_us & 0xFFFFFFFF, pattern) + replies + struct.pack("<H", status)
    return SYNC_DATA + body + struct.pack("<H", crc16(body))


def pack_property_frame(sensor: int, property_id: int, data: bytes) -> bytes:
    """Return the bytes of a property frame."""
    if len(data) > PROPERTY_MAX_BYTES:
        raise ValueError(f"property data of {len(data)} bytes exceeds {PROPERTY_MAX_BYTES}")
    body = _PROPERTY_HEADER.pack(BRIDGE_VERSION, sensor, property_id, len(data)) + data
    return SYNC_PROPERTY + body + struct.pack("<H", crc16(body))


class FrameParser:
    """Splits a byte stream into DataFrame, PropertyFrame and FrameError events.

    Resynchronizes on the sync bytes: after a CRC error it skips only the sync, because a
    corrupted header may have named the wrong length; a true frame boundary is found again at
    the next sync whose CRC holds.
    """

    def __init__(self):
        self.buf = bytearray()

    def feed(self, data: bytes) -> list:
        """Return the events completed by `data`, in stream order."""
        buf = self.buf
        buf += data
        out = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(b"\xB1", pos)
            if start < 0:
                if n > pos:
                    out.append(FrameError("skipped", n - pos))
                pos = n
                break
            if start > pos:
                out.append(FrameError("skipped", start - pos))
                pos = start
            if n - pos < 2:
                break
            kind = buf[pos + 1]
            if kind == 0x0C:
                if n - pos < DATA_HEADER_BYTES:
                    break
                version, count = buf[pos + 2], buf[pos + 3]
                if version != BRIDGE_VERSION or not 1 <= count <= MAX_BIOTACS:
                    out.append(FrameError("header", 2, f"version {version}, n_biotacs {count}"))
                    pos += 2
                    continue
                size = data_frame_bytes(count)
                if n - pos < size:
                    break
                body = bytes(buf[pos + 2:pos + size - 2])
                if crc16(body) != buf[pos + size - 2] | buf[pos + size - 1] << 8:
                    out.append(FrameError("crc", 2, "data frame"))
                    pos += 2
                    continue
                _, count, counter, time_us, pattern = _DATA_HEADER.unpack_from(body)
                out.append(DataFrame(count, counter, time_us, pattern,
                                     body[_DATA_HEADER.size:-2], body[-2] | body[-1] << 8))
                pos += size
            elif kind == 0x0D:
                if n - pos < PROPERTY_HEADER_BYTES:
                    break
                version, sensor, pid, length = _PROPERTY_HEADER.unpack_from(buf, pos + 2)
                if version != BRIDGE_VERSION or length > PROPERTY_MAX_BYTES or sensor >= MAX_BIOTACS:
                    out.append(FrameError("header", 2, f"property frame version {version}, length {length}"))
                    pos += 2
                    continue
                size = PROPERTY_HEADER_BYTES + length + 2
                if n - pos < size:
                    break
                body = bytes(buf[pos + 2:pos + size - 2])
                if crc16(body) != buf[pos + size - 2] | buf[pos + size - 1] << 8:
                    out.append(FrameError("crc", 2, "property frame"))
                    pos += 2
                    continue
                out.append(PropertyFrame(sensor, pid, body[_PROPERTY_HEADER.size:]))
                pos += size
            else:
                out.append(FrameError("skipped", 1))
                pos += 1
        del buf[:pos]
        return out


def decode_property(pid: int, data: bytes) -> str | int:
    """Return a property's value: text for strings, an int for the CPU speed (big endian)."""
    if pid == PROPERTIES["cpu_speed"]:
        return int.from_bytes(data[:2], "big") if len(data) >= 2 else -1
    return data.decode("ascii", errors="replace")


# --- decoding frames and counting faults ---------------------------------------------------

def decode_replies(replies: bytes, n_biotacs: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (values, parity_ok, words) of a frame's replies, each shaped (44, n_biotacs).

    values are 12-bit (meaningless where parity fails); words are the raw 16-bit replies, from
    which error words are named.
    """
    raw = np.frombuffer(replies, dtype=np.uint8).reshape(SLOTS_PER_FRAME, n_biotacs, 2)
    b0, b1 = raw[..., 0], raw[..., 1]
    values = (b0 >> 1).astype(np.uint16) * 32 + (b1 >> 3)
    ok = ODD_PARITY[b0] & ODD_PARITY[b1]
    words = b0.astype(np.uint16) << 8 | b1
    return values, ok, words


@dataclass
class FaultCounters:
    """Every fault the reader counts; per-channel arrays follow REPORTED_CHANNELS."""

    frames_ok: int = 0
    crc_errors: int = 0
    header_errors: int = 0
    bytes_skipped: int = 0
    frames_dropped: int = 0
    frames_repeated: int = 0
    counter_jumps: int = 0
    pattern_mismatches: int = 0
    bridge_overruns: int = 0
    bridge_tx_dropped: int = 0
    pac_frames_refused: int = 0
    slow_frames_refused: int = 0
    parity_errors: np.ndarray = field(default_factory=lambda: np.zeros(len(REPORTED_CHANNELS), np.uint32))
    error_words: np.ndarray = field(default_factory=lambda: np.zeros(len(REPORTED_CHANNELS), np.uint32))
    error_word_kinds: np.ndarray = field(default_factory=lambda: np.zeros(len(ERROR_NAMES), np.uint32))
    last_error_word: str = ""


@dataclass(frozen=True)
class Reading:
    """One accepted frame of one sensor: P_AC and/or slow channels, stamped in device time.

    `pac` is None when a P_AC word of the frame failed, `electrodes` is None when a slow word
    failed (the refused part is counted, never replaced by an older value). `frame_index`
    counts 10 ms frames of device time since the stream's first frame, so a lost frame is a
    jump in it.
    """

    frame_index: int
    device_time_ns: int
    pac: np.ndarray | None            # uint16 (22,) raw 12-bit
    electrodes: np.ndarray | None     # uint16 (19,)
    pdc: int
    tac: int
    tdc: int


class BridgeStream:
    """Checks bridge frames of one sensor and yields Readings; counts every fault.

    Continuity comes from two clocks the bridge sends: its frame counter and its device time.
    When both advance by the same k frames, k - 1 frames were dropped; a frame with the same
    counter and time as the last is a repeat (refused); when they disagree the counter jumped
    (counted) and device time decides. Device time is unwrapped from 32-bit µs.
    """

    def __init__(self, sensor: int = 0):
        self.sensor = sensor
        self.counters = FaultCounters()
        self.parser = FrameParser()
        self.properties: dict[str, str | int] = {}
        self._last_counter: int | None = None
        self._last_time_us = 0
        self._elapsed_us = 0

    def restart(self) -> None:
        """Forgets the stream position (a new connection); counters are kept."""
        self.parser = FrameParser()
        self._last_counter = None
        self._elapsed_us = 0

    def feed(self, data: bytes) -> list[Reading]:
        """Return the readings completed by `data` (properties are stored in `properties`)."""
        out = []
        c = self.counters
        for event in self.parser.feed(data):
            if type(event) is DataFrame:
                reading = self._accept(event)
                if reading is not None:
                    out.append(reading)
            elif type(event) is PropertyFrame:
                if event.sensor == self.sensor:
                    self.properties[event.name] = decode_property(event.property_id, event.data)
            elif event.kind == "crc":
                c.crc_errors += 1
            elif event.kind == "header":
                c.header_errors += 1
            else:
                c.bytes_skipped += event.nbytes
        return out

    def _accept(self, frame: DataFrame) -> Reading | None:
        c = self.counters
        if frame.pattern != SCHEDULE_CRC:
            c.pattern_mismatches += 1     # the slots hold other channels than we would read
            return None
        if self.sensor >= frame.n_biotacs:
            c.header_errors += 1
            return None
        if frame.status & STATUS_OVERRUN:
            c.bridge_overruns += 1
        if frame.status & STATUS_TX_DROPPED:
            c.bridge_tx_dropped += 1
        if self._last_counter is None:
            self._elapsed_us = 0
        else:
            d_counter = (frame.counter - self._last_counter) & 0xFFFFFFFF
            d_us = (frame.device_time_us - self._last_time_us) & 0xFFFFFFFF
            d_frames = (d_us + FRAME_US // 2) // FRAME_US
            if d_counter == 0 and d_us == 0:
                c.frames_repeated += 1
                return None
            if d_counter != d_frames:
                c.counter_jumps += 1
            if d_frames == 0:             # time did not advance: not a new frame
                c.frames_repeated += 1
                return None
            c.frames_dropped += d_frames - 1
            self._elapsed_us += d_us
        self._last_counter, self._last_time_us = frame.counter, frame.device_time_us
        values, ok, words = decode_replies(frame.replies, frame.n_biotacs)
        values, ok, words = values[:, self.sensor], ok[:, self.sensor], words[:, self.sensor]
        if not ok.all():
            self._count_bad_words(ok, words)
        c.frames_ok += 1
        pac_ok = bool(ok[PAC_SLOTS].all())
        slow_ok = bool(ok[ELECTRODE_SLOTS].all() and ok[PDC_SLOT] and ok[TAC_SLOT] and ok[TDC_SLOT])
        c.pac_frames_refused += not pac_ok
        c.slow_frames_refused += not slow_ok
        return Reading(frame_index=(self._elapsed_us + FRAME_US // 2) // FRAME_US,
                       device_time_ns=self._elapsed_us * 1000,
                       pac=values[PAC_SLOTS] if pac_ok else None,
                       electrodes=values[ELECTRODE_SLOTS] if slow_ok else None,
                       pdc=int(values[PDC_SLOT]), tac=int(values[TAC_SLOT]), tdc=int(values[TDC_SLOT]))

    def _count_bad_words(self, ok: np.ndarray, words: np.ndarray) -> None:
        c = self.counters
        for slot in np.flatnonzero(~ok):
            channel = SLOT_REPORTED[slot]
            name = ERROR_WORDS.get(int(words[slot]))
            if name is None:
                c.parity_errors[channel] += 1
            else:
                c.error_words[channel] += 1
                c.error_word_kinds[ERROR_NAMES.index(name)] += 1
                c.last_error_word = f"{name} on {REPORTED_CHANNELS[channel]}"


# --- tare and touch ------------------------------------------------------------------------

class Tare:
    """The untouched baseline of P_DC and the electrodes, and touch detection against it.

    Following the clear-nus BioTac logger: the mean and variance of every channel over `frames`
    untouched frames (3 s); afterwards "touch" is P_DC above mean + `touch_sigma` standard
    deviations for `touch_frames` consecutive frames. A baseline whose P_DC spread exceeds
    `max_pdc_std_counts` is refused (the finger was touched while taring).
    """

    def __init__(self, frames: int = 300, touch_sigma: float = 50.0, touch_frames: int = 5,
                 max_pdc_std_counts: float = 20.0):
        self.frames, self.touch_sigma, self.touch_frames = frames, touch_sigma, touch_frames
        self.max_pdc_std_counts = max_pdc_std_counts
        self.state = "none"          # none | collecting | done | refused
        self.detail = ""
        self.pdc_mean = self.pdc_std = 0.0
        self.electrode_mean = np.zeros(19)
        self.touching = False
        self.pdc_tare_counts = 0     # the last accepted baseline, counts (kept while a new tare runs)
        self._rows: list[np.ndarray] = []
        self._above = 0

    def start(self) -> None:
        """Begins collecting a new baseline (touch detection pauses meanwhile)."""
        self.state, self.detail, self._rows, self.touching, self._above = "collecting", "", [], False, 0

    def add(self, pdc: int, electrodes: np.ndarray) -> None:
        """Adds one slow frame: to the baseline while collecting, to touch detection after."""
        if self.state == "collecting":
            self._rows.append(np.concatenate(([pdc], electrodes)).astype(float))
            if len(self._rows) >= self.frames:
                rows = np.array(self._rows)
                mean, std = rows.mean(axis=0), rows.std(axis=0)
                self._rows = []
                if std[0] > self.max_pdc_std_counts:
                    self.state = "refused"
                    self.detail = (f"P_DC varied by {std[0]:.1f} counts (sd) over the tare; "
                                   f"limit {self.max_pdc_std_counts}: keep the finger untouched")
                    return
                self.state, self.pdc_mean, self.pdc_std = "done", float(mean[0]), float(std[0])
                self.pdc_tare_counts = int(round(self.pdc_mean))
                self.electrode_mean = mean[1:]
                self.detail = f"P_DC {self.pdc_mean:.1f} +/- {self.pdc_std:.2f} counts"
        elif self.state == "done":
            threshold = self.pdc_mean + self.touch_sigma * max(self.pdc_std, 1.0)
            self._above = self._above + 1 if pdc > threshold else 0
            self.touching = self._above >= self.touch_frames


# --- the host side of the bridge ---------------------------------------------------------



def open_serial_port(port: str):
    """Return the bridge's serial port opened non-blocking (pyserial; USB-CDC ignores the baud rate)."""
    import serial        # pyserial: the [hardware] extra, also installed for the tests
    return serial.Serial(port, baudrate=115200, timeout=0, write_timeout=0.5)


class BridgeLink:
    """The bridge on a serial port: handshake, presence check, streaming, unplug and reconnect.

    Non-blocking: `poll()` does what is due now and returns the readings completed since the
    last call; `events` collects (level, text) per state change for the node to log, level
    "info", "warn", or "absent" (a warning that the port cannot be opened, which a node may hold
    back while the device is still expected to appear). A sensor is
    present when its serial number starts with "BT" (SynTouch's check). Failures to open, a
    bridge that does not answer, a missing sensor, an unplug (the port's read fails) or a stream
    that stalls close the port and retry after a back-off that doubles up to `max_backoff_s`.
    """

    def __init__(self, port: str, sensor: int = 0, open_port=open_serial_port,
                 min_backoff_s: float = 0.2, max_backoff_s: float = 5.0,
                 handshake_timeout_s: float = 2.0, stall_timeout_s: float = 1.0, clock=time.monotonic):
        self.port, self.sensor, self.open_port = port, sensor, open_port
        self.min_backoff_s, self.max_backoff_s = min_backoff_s, max_backoff_s
        self.handshake_timeout_s, self.stall_timeout_s = handshake_timeout_s, stall_timeout_s
        self.clock = clock
        self.stream = BridgeStream(sensor)
        self.state = "disconnected"
        self.events: list[tuple[str, str]] = []
        self.reconnects = 0
        self.connections = 0           # successful handshakes; a new one restarts the frame index
        self._serial = None
        self._backoff = min_backoff_s
        self._next_try = 0.0
        self._deadline = 0.0
        self._last_data = 0.0

    @property
    def properties(self) -> dict:
        return self.stream.properties

    def poll(self) -> list[Reading]:
        """Return the readings received now; advances the link's state machine."""
        now = self.clock()
        if self.state in ("disconnected", "no_sensor"):
            if now >= self._next_try:
                self._connect(now)
            return []
        try:
            data = self._serial.read(65536)
        except Exception as exc:        # pyserial raises SerialException or OSError (EIO) on unplug
            self._drop(f"bridge on {self.port} unplugged or failed ({exc}); reconnecting", now)
            self.reconnects += 1
            return []
        if data:
            self._last_data = now
        readings = self.stream.feed(data) if data else []
        if self.state == "handshake":
            self._check_handshake(now)
            return []
        if now - self._last_data > self.stall_timeout_s:
            self._drop(f"no data from the bridge on {self.port} for {self.stall_timeout_s:g} s; reconnecting", now)
            self.reconnects += 1
        return readings

    def close(self) -> None:
        """Stops the bridge's stream (best effort) and closes the port."""
        if self._serial is not None:
            try:
                self._serial.write(CMD_STOP)
            except Exception:
                pass
            try:
                self._serial.close()
            except Exception:
                pass
        self._serial = None

    def _connect(self, now: float) -> None:
        try:
            self._serial = self.open_port(self.port)
            self._serial.write(CMD_STOP + CMD_PROPERTIES)
        except Exception as exc:
            self._serial = None
            self._retry_later(f"cannot open the bridge on {self.port} ({exc})", now, level="absent")
            return
        self.stream.restart()
        self.stream.properties.clear()
        self.state = "handshake"
        self._deadline = now + self.handshake_timeout_s

    def _check_handshake(self, now: float) -> None:
        props = self.stream.properties
        if all(name in props for name in BRIDGE_PROPERTIES):
            serial_number = str(props["serial_number"])
            if not serial_number.startswith("BT"):
                self.close()
                self.state = "no_sensor"
                self._retry_later(f"no BioTac on sensor slot {self.sensor} of the bridge on {self.port} "
                                  f"(serial number {serial_number!r} does not start with 'BT'): "
                                  f"check the sensor's cable and the chip select", now)
                return
            # frames sent before our stop command (a bridge left streaming) are behind us now:
            # continuity starts with the first frame of this stream
            self.stream.restart()
            self._serial.write(CMD_START)
            self.state = "streaming"
            self.connections += 1
            self._last_data = now
            self._backoff = self.min_backoff_s
            self.events.append(("info", f"BioTac {serial_number} (firmware {props['firmware_version']}) on "
                               f"{self.port}: streaming"))
        elif now > self._deadline:
            self._drop(f"the bridge on {self.port} did not answer the property request within "
                       f"{self.handshake_timeout_s:g} s: is the bridge firmware flashed and the port right?", now)

    def _drop(self, why: str, now: float) -> None:
        self.close()
        self.state = "disconnected"
        self._retry_later(why, now)

    def _retry_later(self, why: str, now: float, level: str = "warn") -> None:
        self.events.append((level, f"{why}; next attempt in {self._backoff:.1f} s"))
        self._next_try = now + self._backoff
        self._backoff = min(self._backoff * 2, self.max_backoff_s)
