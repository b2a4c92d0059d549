"""Golden NatNet frames, written field by field from the protocol description (not with the
package's packer), with every block populated so that the parser's skipping is exercised.

`golden_frame(version)` is the payload (after the 4-byte header) a server of that version
sends for the frame described by EXPECTED; `precision_in_4_0` chooses which of the two 4.0
suffixes (with or without the precision timestamp) is written; `populated=False` leaves every
block but the rigid bodies empty (and the bodies without markers), as the emulator sends.
"""
from __future__ import annotations

import struct

BODY_1 = dict(body_id=1, position_m=(0.1, 0.25, -0.5), orientation_xyzw=(0.0, 0.0, 0.38268343, 0.92387953),
              mean_error_m=0.0005, tracking_valid=True)
BODY_7 = dict(body_id=7, position_m=(0.0, 0.0, 0.0), orientation_xyzw=(0.0, 0.0, 0.0, 0.0),
              mean_error_m=0.0, tracking_valid=False)
EXPECTED = dict(frame_number=4242, timecode=0x01020304, timecode_subframe=2, timestamp_s=12.5,
                mid_exposure_ticks=1000, data_received_ticks=2000, transmit_ticks=3000,
                precision_s=55, precision_fraction=66, params=3)


def i32(v): return struct.pack("<i", v)
def i16(v): return struct.pack("<h", v)
def f32(*v): return struct.pack(f"<{len(v)}f", *v)


def block(version, count, body):
    """count, [4.1+: byte count], body."""
    return i32(count) + (i32(len(body)) if version >= (4, 1) else b"") + body


def rigid_body(version, b, populated=True):
    out = i32(b["body_id"]) + f32(*b["position_m"]) + f32(*b["orientation_xyzw"])
    if version[0] < 3 and populated:    # one marker with the body: position, id, size
        out += i32(1) + f32(0.11, 0.26, -0.5) + i32(31) + f32(0.014)
    elif version[0] < 3:
        out += i32(0)
    out += f32(b["mean_error_m"])
    if version >= (2, 6):
        out += i16(1 if b["tracking_valid"] else 0)
    return out


def golden_frame(version, precision_in_4_0=False, populated=True) -> bytes:
    v = tuple(version)

    def other(v_, count, body):     # a block other than the rigid bodies
        return block(v_, count, body) if populated else block(v_, 0, b"")

    out = i32(EXPECTED["frame_number"])
    out += other(v, 1, b"obj\0" + i32(2) + f32(0.1, 0.2, 0.3) + f32(0.4, 0.5, 0.6))      # marker sets
    out += other(v, 1, f32(1.0, 2.0, 3.0))                                                # legacy markers
    out += block(v, 2, rigid_body(v, BODY_1, populated) + rigid_body(v, BODY_7, populated))
    if v >= (2, 1):                                                                       # skeletons
        out += other(v, 1, i32(3) + i32(1) + rigid_body(v, dict(BODY_1, body_id=65537)))
    if v >= (4, 1):                                                                       # assets
        asset = (i32(9) + i32(1) + i32(90) + f32(1, 2, 3) + f32(0, 0, 0, 1) + f32(0.001) + i16(1)
                 + i32(1) + i32(91) + f32(4, 5, 6) + f32(0.01) + i16(0) + f32(0.0002))
        out += other(v, 1, asset)
    if v >= (2, 3):                                                                       # labeled markers
        one = i32(0x00010002) + f32(0.1, 0.2, 0.3) + f32(0.014)
        if v >= (2, 6):
            one += i16(4)
        if v[0] >= 3:
            one += f32(0.0001)
        out += other(v, 2, one + one)
    if v >= (2, 9):                                                                       # force plates
        out += other(v, 1, i32(1) + i32(2) + i32(3) + f32(1, 2, 3) + i32(3) + f32(4, 5, 6))
    if v >= (2, 11):                                                                      # devices
        out += other(v, 1, i32(2) + i32(1) + i32(2) + f32(0.5, 0.25))
    out += struct.pack("<II", EXPECTED["timecode"], EXPECTED["timecode_subframe"])
    out += struct.pack("<d", EXPECTED["timestamp_s"]) if v >= (2, 7) else f32(EXPECTED["timestamp_s"])
    if v[0] >= 3:
        out += struct.pack("<QQQ", EXPECTED["mid_exposure_ticks"], EXPECTED["data_received_ticks"],
                           EXPECTED["transmit_ticks"])
    if v >= (4, 1) or (v == (4, 0) and precision_in_4_0):
        out += struct.pack("<II", EXPECTED["precision_s"], EXPECTED["precision_fraction"])
    out += i16(EXPECTED["params"])
    return out


def golden_server_info(version, name=b"Motive") -> bytes:
    """Server info payload: 256-byte name, app version, NatNet version, [3.0+ stream setup]."""
    out = name.ljust(256, b"\0") + bytes((3, 1, 0, 0)) + bytes(tuple(version) + (0, 0))
    if version[0] >= 3:
        out += struct.pack("<QHB", 10_000_000, 1511, 1) + bytes((239, 255, 42, 99))
    return out
