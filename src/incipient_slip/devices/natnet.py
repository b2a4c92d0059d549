"""NatNet (OptiTrack Motive) over UDP: packets, a parser by server version, and a client.

Written from the protocol as OptiTrack's public samples and docs describe it (docs/hardware.md,
"NatNet"); no code of theirs. Every packet is `u16 message id, u16 payload bytes` (little
endian) and a payload. The client connects the way the 4.1 SDK does (a 270-byte `Ping` payload
naming the version it speaks) and falls back to the legacy `"Ping\\0"`; it parses nothing before
the server's info has told it the NatNet version, then parses each frame by that version:

    frame number | marker sets | legacy markers | rigid bodies | skeletons (>= 2.1) |
    assets (>= 4.1) | labeled markers (>= 2.3) | force plates (>= 2.9) | devices (>= 2.11) |
    suffix: timecode, subframe, timestamp (f64 from 2.7), [>= 3.0 three u64 clock stamps],
    [precision timestamp s + fraction: >= 4.1; 4.0 servers differ, so the bytes left decide],
    i16 frame params

From 4.1 every block carries its byte count after its count, so blocks we do not need are
skipped by it, and the rigid-body block is checked against it. Every read is bounds-checked and
the suffix must end exactly at the payload's end: anything else is a `NatNetError` naming the
offset, and the client counts the packet as dropped by reason, never raises.
"""
from __future__ import annotations

import socket
import struct
import time
from collections import Counter
from dataclasses import dataclass

__all__ = [
    "NatNetError", "ServerInfo", "RigidBody", "Frame", "Notice", "NatNetClient",
    "VERSIONS", "NAT_CONNECT", "NAT_SERVERINFO", "NAT_REQUEST", "NAT_RESPONSE",
    "NAT_REQUEST_MODELDEF", "NAT_MODELDEF", "NAT_REQUEST_FRAMEOFDATA", "NAT_FRAMEOFDATA",
    "NAT_MESSAGESTRING", "NAT_DISCONNECT", "NAT_KEEPALIVE", "NAT_UNRECOGNIZED_REQUEST",
    "split_packet", "pack_packet", "pack_connect", "pack_legacy_ping", "connect_version",
    "pack_server_info", "parse_server_info", "pack_frame", "parse_frame",
    "DEFAULT_COMMAND_PORT", "DEFAULT_DATA_PORT", "DEFAULT_MULTICAST_ADDRESS",
]

NAT_CONNECT = 0
NAT_SERVERINFO = 1
NAT_REQUEST = 2
NAT_RESPONSE = 3
NAT_REQUEST_MODELDEF = 4
NAT_MODELDEF = 5
NAT_REQUEST_FRAMEOFDATA = 6
NAT_FRAMEOFDATA = 7
NAT_MESSAGESTRING = 8
NAT_DISCONNECT = 9
NAT_KEEPALIVE = 10
NAT_UNRECOGNIZED_REQUEST = 100

DEFAULT_COMMAND_PORT = 1510
DEFAULT_DATA_PORT = 1511
DEFAULT_MULTICAST_ADDRESS = "239.255.42.99"
# The NatNet versions this parser is tested against (Motive 1.x/2.x, 2.x, 3.0, 3.1, 3.2+).
VERSIONS = ((2, 10), (3, 1), (4, 0), (4, 1), (4, 2))
CLIENT_VERSION = (4, 1, 0, 0)
CONNECT_PAYLOAD_BYTES = 271   # "Ping", zeros, requested version at 265..268, a closing NUL
SERVER_NAME_BYTES = 256
MAX_PAYLOAD = 0xFFFF

_I16, _U16, _I32, _U32 = struct.Struct("<h"), struct.Struct("<H"), struct.Struct("<i"), struct.Struct("<I")
_U64, _F32, _F64 = struct.Struct("<Q"), struct.Struct("<f"), struct.Struct("<d")
_HEADER = struct.Struct("<HH")
_POSE = struct.Struct("<i3f4f")          # id, position (m), quaternion x y z w
_VERSION4 = struct.Struct("4B")
_SERVER_3 = struct.Struct("<QHB4B")     # clock Hz, data port, multicast flag, multicast address
_TIMECODE = struct.Struct("<II")         # timecode, subframe (also: precision s, fraction)
_STAMPS = struct.Struct("<QQQ")          # mid-exposure, data received, transmit (ticks)


class NatNetError(ValueError):
    """A packet that breaks the protocol; `reason` is a short key for drop counters."""

    def __init__(self, reason: str, detail: str):
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


@dataclass(frozen=True)
class ServerInfo:
    """The server's answer to a connect: its name and versions (and from 3.0 its stream setup)."""

    app_name: str
    app_version: tuple
    natnet_version: tuple
    clock_hz: int = 0               # ticks per second of the three suffix stamps (0: unknown)
    data_port: int = 0
    multicast: bool = False
    multicast_address: str = ""

    @property
    def version(self) -> tuple:
        """(major, minor) of the bitstream the server sends."""
        return tuple(self.natnet_version[:2])


@dataclass(frozen=True)
class RigidBody:
    """One rigid body of a frame: position in metres, quaternion (x, y, z, w)."""

    body_id: int
    position_m: tuple
    orientation_xyzw: tuple
    mean_error_m: float = 0.0
    tracking_valid: bool = True


@dataclass(frozen=True)
class Frame:
    """One frame of data: its number, rigid bodies (top level only) and the suffix's times."""

    frame_number: int
    rigid_bodies: tuple
    timecode: int = 0
    timecode_subframe: int = 0
    timestamp_s: float = 0.0                 # Motive's frame time, s since its start
    mid_exposure_ticks: int = 0              # >= 3.0: camera mid-exposure, server clock ticks
    data_received_ticks: int = 0             # >= 3.0: data reached Motive
    transmit_ticks: int = 0                  # >= 3.0: frame sent
    precision_s: int = 0                     # >= 4.1 (some 4.0): precision timestamp, s
    precision_fraction: int = 0
    params: int = 0                          # bit 0 recording, bit 1 tracked models changed

    def rigid_body(self, body_id: int) -> RigidBody | None:
        """The rigid body with this streaming id, or None when the frame does not hold it."""
        for body in self.rigid_bodies:
            if body.body_id == body_id:
                return body
        return None


@dataclass(frozen=True)
class Notice:
    """Something the client wants its user to know: kind is connected, version_change,
    no_data or data_resumed; text is one line for a log."""

    kind: str
    text: str


# --- packets ------------------------------------------------------------------------------

def pack_packet(message_id: int, payload: bytes = b"") -> bytes:
    """A packet: header (id, payload length) and payload."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"NatNet payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    return _HEADER.pack(message_id, len(payload)) + payload


def split_packet(data: bytes) -> tuple[int, memoryview]:
    """(message id, payload) of a datagram whose length matches its header; NatNetError else."""
    if len(data) < 4:
        raise NatNetError("short", f"{len(data)} bytes, a header needs 4")
    message_id, size = _HEADER.unpack_from(data, 0)
    if len(data) - 4 != size:
        raise NatNetError("length", f"header says {size} payload bytes, datagram has {len(data) - 4}")
    return message_id, memoryview(data)[4:]


def pack_connect(version: tuple = CLIENT_VERSION) -> bytes:
    """The 4.1-style connect: "Ping", zeros, the requested NatNet version at 265..268, NUL."""
    payload = bytearray(CONNECT_PAYLOAD_BYTES)
    payload[0:4] = b"Ping"
    payload[265:269] = bytes(version)
    return pack_packet(NAT_CONNECT, bytes(payload))


def pack_legacy_ping() -> bytes:
    """The connect of clients before 4.1: the text "Ping" and its NUL."""
    return pack_packet(NAT_CONNECT, b"Ping\0")


def connect_version(payload) -> tuple | None:
    """The NatNet version a connect payload requests, None for a legacy ping (server side)."""
    if len(payload) >= 269 and bytes(payload[0:4]) == b"Ping":
        return tuple(payload[265:269])
    return None


def pack_request(text: str) -> bytes:
    """A command request (id 2): NUL-terminated text such as "Bitstream"."""
    return pack_packet(NAT_REQUEST, text.encode() + b"\0")


def pack_server_info(info: ServerInfo) -> bytes:
    """The server-info packet for `info` (the 3.0+ fields only when its version has them)."""
    name = info.app_name.encode()[:SERVER_NAME_BYTES - 1].ljust(SERVER_NAME_BYTES, b"\0")
    payload = name + _VERSION4.pack(*info.app_version) + _VERSION4.pack(*info.natnet_version)
    if info.natnet_version[0] >= 3:
        payload += _SERVER_3.pack(info.clock_hz, info.data_port, int(info.multicast),
                                  *socket.inet_aton(info.multicast_address or "0.0.0.0"))
    return pack_packet(NAT_SERVERINFO, payload)


class _Reader:
    """A bounds-checked little-endian cursor over a payload."""

    __slots__ = ("buf", "pos", "end")

    def __init__(self, buf: memoryview, pos: int = 0, end: int | None = None):
        self.buf, self.pos, self.end = buf, pos, len(buf) if end is None else end

    def need(self, n: int, what: str) -> int:
        pos = self.pos
        if n < 0 or pos + n > self.end:
            raise NatNetError("truncated", f"{what} needs {n} bytes at offset {pos}, "
                                           f"{self.end - pos} left")
        self.pos = pos + n
        return pos

    def unpack(self, st: struct.Struct, what: str):
        return st.unpack_from(self.buf, self.need(st.size, what))

    def i32(self, what: str) -> int:
        return _I32.unpack_from(self.buf, self.need(4, what))[0]

    def count(self, what: str, item_bytes: int) -> int:
        """A block's element count, refused when negative or when its items cannot fit."""
        n = self.i32(what)
        if n < 0 or n * item_bytes > self.end - self.pos:
            raise NatNetError("count", f"{what} {n} at offset {self.pos - 4} does not fit the "
                                       f"{self.end - self.pos} bytes left")
        return n

    def cstring(self, what: str) -> str:
        start = self.pos
        stop = bytes(self.buf[start:self.end]).find(b"\0")
        if stop < 0:
            raise NatNetError("truncated", f"{what} at offset {start} has no closing NUL")
        self.pos = start + stop + 1
        return bytes(self.buf[start:start + stop]).decode("utf-8", "replace")


def parse_server_info(payload) -> ServerInfo:
    """The ServerInfo in a server-info payload (id 1); NatNetError when it is malformed."""
    r = _Reader(memoryview(payload))
    name = bytes(r.buf[r.need(SERVER_NAME_BYTES, "server name"):r.pos]).split(b"\0", 1)[0]
    app_version = r.unpack(_VERSION4, "application version")
    natnet_version = r.unpack(_VERSION4, "NatNet version")
    clock_hz = data_port = multicast = 0
    address = ""
    if natnet_version[0] >= 3:
        clock_hz, data_port, multicast, *quad = r.unpack(_SERVER_3, "stream setup (>= 3.0)")
        address = ".".join(map(str, quad))
    if r.pos != r.end:
        raise NatNetError("trailing", f"server info has {r.end - r.pos} bytes after its fields")
    if natnet_version[0] < 2:
        raise NatNetError("version", f"NatNet {'.'.join(map(str, natnet_version))} is older "
                                     f"than 2.10, the oldest this client parses")
    return ServerInfo(name.decode("utf-8", "replace"), tuple(app_version), tuple(natnet_version),
                      clock_hz, data_port, bool(multicast), address)


def _block_size(r: _Reader, version: tuple, what: str) -> int | None:
    """From 4.1, the byte count after a block's count; None before 4.1."""
    if version < (4, 1):
        return None
    size = r.i32(f"{what} byte count")
    if size < 0 or size > r.end - r.pos:
        raise NatNetError("count", f"{what} byte count {size} at offset {r.pos - 4} does not "
                                   f"fit the {r.end - r.pos} bytes left")
    return size


def _rigid_body(r: _Reader, version: tuple) -> RigidBody:
    body_id, x, y, z, qx, qy, qz, qw = r.unpack(_POSE, "rigid body pose")
    if version[0] < 3:                       # before 3.0 the markers travel with the body
        n = r.count("rigid body marker count", 20)
        r.need(20 * n, "rigid body markers")  # positions (12), ids (4), sizes (4)
    error = _F32.unpack_from(r.buf, r.need(4, "rigid body mean error"))[0]
    params = _I16.unpack_from(r.buf, r.need(2, "rigid body params"))[0]
    return RigidBody(body_id, (x, y, z), (qx, qy, qz, qw), error, bool(params & 1))


def _skip_block(r: _Reader, version: tuple, what: str, skip) -> None:
    """Steps over a block we do not use: by its byte count from 4.1, else element by element."""
    n = r.count(f"{what} count", 4)
    size = _block_size(r, version, what)
    if size is not None:
        r.need(size, what)
        return
    for _ in range(n):
        skip(r)


def _skip_marker_set(r: _Reader) -> None:
    r.cstring("marker set name")
    r.need(12 * r.count("marker set marker count", 12), "marker set markers")


def _skip_skeleton(r: _Reader, version: tuple) -> None:
    r.need(4, "skeleton id")
    for _ in range(r.count("skeleton rigid body count", 38)):
        _rigid_body(r, version)


def _skip_channels(r: _Reader) -> None:
    """A force plate or device: id, channel count, per channel a frame count and f32 values."""
    r.need(4, "plate/device id")
    for _ in range(r.count("channel count", 4)):
        r.need(4 * r.count("channel frame count", 4), "channel values")


def parse_frame(payload, version: tuple) -> Frame:
    """The Frame in a frame-of-data payload (id 7) sent by a server of NatNet `version`."""
    version = tuple(version[:2])
    r = _Reader(memoryview(payload))
    frame_number = r.i32("frame number")
    _skip_block(r, version, "marker sets", _skip_marker_set)
    _skip_block(r, version, "legacy markers", lambda r: r.need(12, "legacy marker"))
    n = r.count("rigid body count", 38 if version[0] >= 3 else 42)
    size = _block_size(r, version, "rigid bodies")
    start = r.pos
    bodies = tuple(_rigid_body(r, version) for _ in range(n))
    if size is not None and r.pos - start != size:
        raise NatNetError("count", f"rigid bodies took {r.pos - start} bytes, their byte "
                                   f"count says {size}")
    if version >= (2, 1):
        _skip_block(r, version, "skeletons", lambda r: _skip_skeleton(r, version))
    if version >= (4, 1):                    # assets: only reachable by the byte count
        _skip_block(r, version, "assets", None)
    if version >= (2, 3):
        lm_bytes = 20 + (2 if version >= (2, 6) else 0) + (4 if version[0] >= 3 else 0)
        _skip_block(r, version, "labeled markers", lambda r: r.need(lm_bytes, "labeled marker"))
    if version >= (2, 9):
        _skip_block(r, version, "force plates", _skip_channels)
    if version >= (2, 11):
        _skip_block(r, version, "devices", _skip_channels)
    timecode, subframe = r.unpack(_TIMECODE, "timecode")
    if version >= (2, 7):
        timestamp = _F64.unpack_from(r.buf, r.need(8, "timestamp"))[0]
    else:
        timestamp = _F32.unpack_from(r.buf, r.need(4, "timestamp"))[0]
    mid = received = transmit = 0
    if version[0] >= 3:
        mid, received, transmit = r.unpack(_STAMPS, "clock stamps (>= 3.0)")
    left = r.end - r.pos
    precision = (version >= (4, 1) or (version == (4, 0) and left == 10))
    want = 10 if precision else 2
    if left != want:
        raise NatNetError("suffix", f"frame suffix has {left} bytes after the timestamps, "
                                    f"NatNet {version[0]}.{version[1]} sends {want}")
    seconds = fraction = 0
    if precision:
        seconds, fraction = r.unpack(_TIMECODE, "precision timestamp")
    params = _I16.unpack_from(r.buf, r.need(2, "frame params"))[0]
    return Frame(frame_number, bodies, timecode, subframe, timestamp, mid, received, transmit,
                 seconds, fraction, params)


def pack_frame(frame: Frame, version: tuple, *, precision_in_4_0: bool = False) -> bytes:
    """The frame-of-data packet a server of NatNet `version` sends for `frame` (emulator side):
    no marker sets, legacy markers, skeletons, assets, labeled markers, plates or devices."""
    version = tuple(version[:2])
    counted = version >= (4, 1)

    def block(count: int, body: bytes) -> bytes:
        return _I32.pack(count) + (_I32.pack(len(body)) if counted else b"") + body

    out = [_I32.pack(frame.frame_number), block(0, b""), block(0, b"")]
    bodies = b""
    for body in frame.rigid_bodies:
        bodies += _POSE.pack(body.body_id, *body.position_m, *body.orientation_xyzw)
        if version[0] < 3:
            bodies += _I32.pack(0)           # no markers with the body
        bodies += _F32.pack(body.mean_error_m) + _I16.pack(1 if body.tracking_valid else 0)
    out.append(block(len(frame.rigid_bodies), bodies))
    if version >= (2, 1):
        out.append(block(0, b""))
    if version >= (4, 1):
        out.append(block(0, b""))
    for since in ((2, 3), (2, 9), (2, 11)):
        if version >= since:
            out.append(block(0, b""))
    out.append(_TIMECODE.pack(frame.timecode, frame.timecode_subframe))
    out.append(_F64.pack(frame.timestamp_s) if version >= (2, 7) else _F32.pack(frame.timestamp_s))
    if version[0] >= 3:
        out.append(_STAMPS.pack(frame.mid_exposure_ticks, frame.data_received_ticks,
                                frame.transmit_ticks))
    if version >= (4, 1) or (version == (4, 0) and precision_in_4_0):
        out.append(_TIMECODE.pack(frame.precision_s, frame.precision_fraction))
    out.append(_I16.pack(frame.params))
    return pack_packet(NAT_FRAMEOFDATA, b"".join(out))


# --- the client -----------------------------------------------------------------------------

MOTIVE_SETTINGS = ("in Motive's Streaming pane check that Broadcast Frame Data is on, that "
                   "Local Interface is the address this computer reaches (not loopback unless "
                   "Motive runs here), and that Transmission Type matches multicast:={mc}; "
                   "for multicast, that the network passes {group}:{port}")
RESTART_JUMP_FRAMES = 240   # a frame number this far back is a restarted stream, not a late frame
BAD_FRAMES_BEFORE_RECHECK = 10


MIN_CONNECT_GAP_S = 0.05     # the shortest wait between two connect attempts


class NatNetClient:
    """Connects to a NatNet server and returns its frames; non-blocking, one thread.

    `poll()` reads every datagram waiting on the command socket (where unicast frames arrive)
    and the data socket (the data port: multicast, or servers that send unicast there), sends
    what is due (connect, legacy ping, keepalive once a second in unicast) and runs the
    watchdog; it returns the new frames and notices. Frames come out in frame-number order:
    duplicates and late (reordered) frames are dropped and counted, gaps are counted.
    `stats` counts everything by name (frames, dropped:<reason>, missed_frames, ...).
    """

    def __init__(self, server_address: str = "127.0.0.1", *, local_address: str = "127.0.0.1",
                 command_port: int = DEFAULT_COMMAND_PORT, data_port: int = DEFAULT_DATA_PORT,
                 multicast: bool = False, multicast_address: str = DEFAULT_MULTICAST_ADDRESS,
                 keepalive_s: float = 1.0, connect_timeout_s: float = 1.0,
                 no_data_s: float = 1.0, backoff_max_s: float = 8.0, connect_by: float | None = None,
                 clock=time.monotonic):
        self.server = (server_address, command_port)
        self.local_address, self.data_port = local_address, data_port
        self.multicast, self.multicast_address = multicast, multicast_address
        self.keepalive_s, self.connect_timeout_s = keepalive_s, connect_timeout_s
        self.no_data_s, self.backoff_max_s = no_data_s, backoff_max_s
        self.connect_by = connect_by      # clock time the caller gives up at without server info
        self.clock = clock
        self.stats: Counter = Counter()
        self.server_info: ServerInfo | None = None
        self.status = "CONNECTING"
        self.last_error = ""
        self._sockets: list[socket.socket] = []
        self._cmd: socket.socket | None = None
        self._last_frame: int | None = None
        self._attempt = 0
        self._next_connect = 0.0
        self._next_keepalive = 0.0
        self._last_data = 0.0
        self._notices: list[Notice] = []
        self._bad_in_a_row = 0
        self._last_recheck = -1e9

    # --- life cycle ---

    def open(self) -> "NatNetClient":
        """Opens the sockets (OSError naming the port when one cannot be bound)."""
        cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            cmd.bind((self.local_address, 0))
        except OSError as exc:
            cmd.close()
            raise OSError(f"NatNet local_address {self.local_address}: {exc.strerror} (is it an "
                          f"address of this computer?)") from None
        data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        data.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            if self.multicast:
                data.bind(("", self.data_port))
                data.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                                socket.inet_aton(self.multicast_address)
                                + socket.inet_aton(self.local_address))
            else:
                data.bind((self.local_address, self.data_port))
        except OSError as exc:
            cmd.close()
            data.close()
            raise OSError(f"NatNet data port {self.local_address}:{self.data_port}: {exc}") from None
        for s in (cmd, data):
            s.setblocking(False)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._cmd, self._sockets = cmd, [cmd, data]
        now = self.clock()
        self._last_data = now
        self._next_connect = now
        return self

    def close(self) -> None:
        """Tells the server we leave (unicast) and closes the sockets."""
        if self._cmd is not None and self.server_info is not None:
            try:
                self._cmd.sendto(pack_packet(NAT_DISCONNECT), self.server)
            except OSError:
                pass
        for s in self._sockets:
            s.close()
        self._sockets, self._cmd = [], None

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    @property
    def version(self) -> tuple | None:
        """(major, minor) the server streams, None before its server info arrived."""
        return self.server_info.version if self.server_info else None

    def request(self, text: str) -> None:
        """Sends a command request (e.g. "Bitstream"); the answer is counted, not parsed."""
        self._send(pack_request(text))

    # --- the loop ---

    def poll(self) -> tuple[list[Frame], list[Notice]]:
        """(frames, notices) that arrived or fell due since the last call; never blocks."""
        frames: list[Frame] = []
        for s in self._sockets:
            while True:
                try:
                    data, source = s.recvfrom(MAX_PAYLOAD + 4)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:      # e.g. ICMP port unreachable echoed on the command socket
                    self.stats["socket_errors"] += 1
                    self.last_error = str(exc)
                    break
                frame = self._handle(data, source)
                if frame is not None:
                    frames.append(frame)
        self._tick(self.clock())
        notices, self._notices = self._notices, []
        return frames, notices

    def _drop(self, reason: str, detail: str) -> None:
        self.stats["dropped"] += 1
        self.stats[f"dropped:{reason}"] += 1
        self.last_error = detail

    def _handle(self, data: bytes, source) -> Frame | None:
        if source[0] != self.server[0] and not self.multicast:
            self._drop("foreign_source", f"packet from {source[0]}, server is {self.server[0]}")
            return None
        try:
            message_id, payload = split_packet(data)
            if message_id == NAT_SERVERINFO:
                self._on_server_info(parse_server_info(payload))
                return None
            if message_id != NAT_FRAMEOFDATA:
                self.stats[f"message:{message_id}"] += 1
                return None
            if self.server_info is None:
                self._drop("before_server_info", "frame before the server said its version")
                return None
            frame = parse_frame(payload, self.server_info.version)
        except NatNetError as exc:
            self._drop(exc.reason, str(exc))
            self._bad_in_a_row += 1
            if self._bad_in_a_row >= BAD_FRAMES_BEFORE_RECHECK:
                self._recheck()       # e.g. a multicast server restarted with another version
            return None
        self._bad_in_a_row = 0
        return self._order(frame)

    def _recheck(self) -> None:
        """Asks for the server info again (at most once per connect timeout)."""
        now = self.clock()
        if now - self._last_recheck >= self.connect_timeout_s:
            self._last_recheck = now
            self._bad_in_a_row = 0
            self._send(pack_connect())
            self.stats["rechecks"] += 1

    def _order(self, frame: Frame) -> Frame | None:
        last, number = self._last_frame, frame.frame_number
        if last is not None and number <= last:
            if number == last:
                self._drop("duplicate", f"frame {number} again")
                return None
            if last - number < RESTART_JUMP_FRAMES:
                self._drop("reordered", f"frame {number} after {last}")
                return None
            self.stats["stream_restarts"] += 1
            self._recheck()           # a restarted server may speak another version
        elif last is not None and number > last + 1:
            self.stats["gaps"] += 1
            self.stats["missed_frames"] += number - last - 1
        self._last_frame = number
        self.stats["frames"] += 1
        self._last_data = self.clock()
        if self.status != "STREAMING":
            if self.status == "NO_DATA":
                self._notices.append(Notice("data_resumed", f"frames again from {self._where()}"))
            self.status = "STREAMING"
            self._attempt = 0
        return frame

    def _on_server_info(self, info: ServerInfo) -> None:
        old = self.server_info
        self.stats["server_info"] += 1
        if self.status != "STREAMING":
            self._last_frame = None   # a (re)connected server numbers frames its own way
        self.server_info = info
        self._last_data = self.clock()
        if old is None:
            self._notices.append(Notice("connected", f"{info.app_name} "
                                        f"{'.'.join(map(str, info.app_version))} at {self._where()}, "
                                        f"NatNet {'.'.join(map(str, info.natnet_version))}"))
        elif old.version != info.version:
            self.stats["version_changes"] += 1
            self._last_frame = None
            self._notices.append(Notice("version_change", f"NatNet version changed from "
                                        f"{'.'.join(map(str, old.natnet_version))} to "
                                        f"{'.'.join(map(str, info.natnet_version))} at "
                                        f"{self._where()}: frames are parsed as the new version"))
        if self.status == "CONNECTING":
            self.status = "CONNECTED"

    def _tick(self, now: float) -> None:
        silent = now - self._last_data
        if self.status in ("CONNECTED", "STREAMING") and silent > self.no_data_s:
            self.status = "NO_DATA"
            self.stats["no_data"] += 1
            self._notices.append(Notice("no_data", f"no frame from {self._where()} for "
                                        f"{silent:.1f} s; {self._settings()}; reconnecting"))
            self._next_connect = now
        if self.status in ("CONNECTING", "NO_DATA") and now >= self._next_connect:
            if self.status == "CONNECTING" and self._attempt > 0 and self._attempt % 4 == 0:
                self._notices.append(Notice("no_data", f"no server info from {self._where()} "
                                            f"after {self._attempt} connects; is Motive running "
                                            f"there with streaming on? {self._settings()}"))
            # every other attempt is the legacy ping, for servers that ignore the 4.1 connect
            legacy = self._attempt % 2 == 1
            self._send(pack_legacy_ping() if legacy else pack_connect())
            self.stats["legacy_pings" if legacy else "connects"] += 1
            self._attempt += 1
            self._next_connect = now + self._connect_delay(now)
        if not self.multicast and self.server_info is not None and now >= self._next_keepalive:
            self._send(pack_packet(NAT_KEEPALIVE))
            self.stats["keepalives"] += 1
            self._next_keepalive = now + self.keepalive_s

    def _connect_delay(self, now: float) -> float:
        """Seconds to the next connect attempt: the back-off (connect_timeout_s doubling every
        second attempt up to backoff_max_s), before the first server info at most half the time
        left to `connect_by` (never below MIN_CONNECT_GAP_S), so attempts go on until then."""
        delay = min(self.connect_timeout_s * 2 ** ((self._attempt - 1) // 2), self.backoff_max_s)
        if self.connect_by is not None and self.server_info is None and now < self.connect_by:
            delay = min(delay, max((self.connect_by - now) / 2, MIN_CONNECT_GAP_S))
        return delay

    def _send(self, packet: bytes) -> None:
        if self._cmd is None:         # closed (or never opened): nothing to send on
            return
        try:
            self._cmd.sendto(packet, self.server)
        except OSError as exc:
            self.stats["socket_errors"] += 1
            self.last_error = str(exc)

    def _where(self) -> str:
        return f"{self.server[0]}:{self.server[1]}"

    def _settings(self) -> str:
        return MOTIVE_SETTINGS.format(mc=str(self.multicast).lower(), group=self.multicast_address,
                                      port=self.data_port)
