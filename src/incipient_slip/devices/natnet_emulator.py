"""A NatNet server on loopback that streams one rigid body the way Motive does, with faults.

    python -m incipient_slip.devices.natnet_emulator --version 4.1 --command-port 41510

It answers a connect (the 4.1-style one or the legacy "Ping") with its server info, keeps a
list of unicast clients (the address their connect came from), answers keepalives and
requests, and streams frames at `rate_hz` to every client's command socket (or to their data
port, as some servers do), or to a multicast group. Frames are built by `natnet.pack_frame`
for the emulated NatNet version, so what goes out is byte for byte what the parser reads.

Faults, switchable while it runs (tests and `rig:=emulated` drive them):
`silent_stop` (frames stop, commands are still answered, as when streaming is switched off),
`tracking_lost` (the body is sent untracked with a zero pose, as Motive sends an occluded body),
`nan_pose` (NaN position), `inject("gap"|"duplicate"|"reorder"|"truncate", n)` for the next n
frames, `restart(version)` (the server goes away and comes back speaking another version,
forgetting its clients), `legacy_connect_only` (ignores the 4.1-style connect).
"""
from __future__ import annotations

import argparse
import math
import select
import socket
import sys
import threading
import time
from collections import Counter, deque

from incipient_slip.devices import natnet as nn
from incipient_slip.devices.emulator import ThreadedEmulator

__all__ = ["NatNetEmulator", "free_udp_port", "free_udp_port_pair", "main"]

CLOCK_HZ = 10_000_000       # ticks per second of the suffix stamps (Motive reports its own)
LATENCY_S = 0.004           # mid-exposure to transmit, as the suffix stamps report it
FAULTS = ("gap", "duplicate", "reorder", "truncate")
# the Motive release that speaks each NatNet version, reported as its app version (not verified)
MOTIVE_VERSION = {(2, 10): (1, 10, 0, 0), (3, 1): (2, 1, 0, 0), (4, 0): (3, 0, 0, 0),
                  (4, 1): (3, 1, 0, 0), (4, 2): (3, 2, 0, 0)}


def free_udp_port(address: str = "127.0.0.1") -> int:
    """Return a UDP port on `address` that was free just now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((address, 0))
        return s.getsockname()[1]


def free_udp_port_pair(address: str = "127.0.0.1", tries: int = 100) -> int:
    """Return a port p such that p and p + 1 were both free just now: NatNet's command and data
    ports (an emulated rig's server and a client that follows the 1510/1511 convention)."""
    import random
    for _ in range(tries):
        port = random.randint(20000, 60000)
        socks = []
        try:
            for p in (port, port + 1):
                socks.append(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
                socks[-1].bind((address, p))
            return port
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise OSError(f"no free UDP port pair on {address} after {tries} tries")


class NatNetEmulator(ThreadedEmulator):
    """Streams one rigid body over NatNet `version` from `address`; a thread, see start()."""

    THREAD_NAME = "natnet-emulator"

    def __init__(self, version=(4, 1), *, address: str = "127.0.0.1", command_port: int = 0,
                 data_port: int = nn.DEFAULT_DATA_PORT, multicast: bool = False,
                 multicast_address: str = nn.DEFAULT_MULTICAST_ADDRESS, rate_hz: float = 120.0,
                 body_id: int = 1, unicast_to_data_port: bool = False,
                 legacy_connect_only: bool = False, precision_in_4_0: bool = False,
                 app_name: str = "Motive (emulated)"):
        self.version = tuple(version[:2])
        self.address, self.data_port = address, data_port
        self.multicast, self.multicast_address = multicast, multicast_address
        self.rate_hz, self.body_id = rate_hz, body_id
        self.unicast_to_data_port = unicast_to_data_port
        self.legacy_connect_only = legacy_connect_only
        self.precision_in_4_0 = precision_in_4_0
        self.app_name = app_name
        self.silent_stop = self.tracking_lost = self.nan_pose = False
        self.stats: Counter = Counter()
        self.clients: set = set()
        self._requested_port = command_port
        self._lock = threading.Lock()
        self._pose = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        self._faults: deque = deque()
        self._held = None            # a frame held back by "reorder"
        self._frame_number = 0
        self._sock: socket.socket | None = None
        super().__init__()
        self._t0 = time.monotonic()

    # --- control (any thread) ---

    @property
    def command_port(self) -> int:
        """The command port it listens on (the bound one when 0 was asked for)."""
        return self._sock.getsockname()[1] if self._sock else self._requested_port

    def set_pose(self, position_m, orientation_xyzw=(0.0, 0.0, 0.0, 1.0)) -> None:
        """The rigid body's pose from now on (metres, quaternion x y z w)."""
        with self._lock:
            self._pose = (tuple(map(float, position_m)), tuple(map(float, orientation_xyzw)))

    def inject(self, fault: str, n: int = 1) -> None:
        """Applies `fault` (gap, duplicate, reorder, truncate) to each of the next n frames."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; one of {', '.join(FAULTS)}")
        with self._lock:
            self._faults.extend([fault] * n)

    def _open(self) -> None:
        """Binds the command port (streaming starts on the thread)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((self.address, self._requested_port))
        if self.multicast:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(self.address))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self._requested_port = sock.getsockname()[1]
        self._sock = sock

    def _close(self) -> None:
        """Closes the port (streaming has stopped)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def restart(self, version) -> None:
        """Goes away and comes back on the same port speaking NatNet `version`, no clients."""
        self.stop()
        self.version = tuple(version[:2])
        self.clients = set()
        self._frame_number = 0
        self._held = None
        self.stats["restarts"] += 1
        self.start()

    def server_info(self) -> nn.ServerInfo:
        """What it answers a connect with."""
        return nn.ServerInfo(self.app_name, MOTIVE_VERSION.get(self.version, (0, 0, 0, 0)),
                             self.version + (0, 0), CLOCK_HZ,
                             self.data_port, self.multicast, self.multicast_address)

    # --- the server thread ---

    def _serve(self) -> None:
        period = 1.0 / self.rate_hz
        due = time.monotonic() + period
        while not self._stop.is_set():
            wait = max(0.0, due - time.monotonic())
            readable, _, _ = select.select([self._sock], [], [], min(wait, 0.05))
            if readable:
                self._on_command()
            now = time.monotonic()
            if now >= due:
                due += period
                if due <= now:          # behind (a stalled machine): skip, do not burst
                    due = now + period
                self._tick(now)

    def _on_command(self) -> None:
        try:
            data, client = self._sock.recvfrom(nn.MAX_PAYLOAD + 4)
        except OSError:
            return
        try:
            message_id, payload = nn.split_packet(data)
        except nn.NatNetError:
            self.stats["bad_commands"] += 1
            return
        self.stats[f"command:{message_id}"] += 1
        if message_id == nn.NAT_CONNECT:
            if self.legacy_connect_only and nn.connect_version(payload) is not None:
                return
            self.clients.add(client)
            self._send(nn.pack_server_info(self.server_info()), client)
        elif message_id == nn.NAT_KEEPALIVE:
            self.clients.add(client)
        elif message_id == nn.NAT_DISCONNECT:
            self.clients.discard(client)
        elif message_id == nn.NAT_REQUEST:
            text = bytes(payload).split(b"\0", 1)[0].decode("utf-8", "replace")
            if text == "Bitstream":
                self._send(nn.pack_packet(nn.NAT_RESPONSE, f"Bitstream,{self.version[0]}.{self.version[1]}"
                                          .encode() + b"\0"), client)
            else:
                self._send(nn.pack_packet(nn.NAT_UNRECOGNIZED_REQUEST), client)
        elif message_id == nn.NAT_REQUEST_MODELDEF:
            self._send(nn.pack_packet(nn.NAT_MODELDEF, b"\0\0\0\0"), client)   # no descriptions
        elif message_id == nn.NAT_REQUEST_FRAMEOFDATA:
            self._send(self._frame_packet(time.monotonic()), client)
        else:
            self._send(nn.pack_packet(nn.NAT_UNRECOGNIZED_REQUEST), client)

    def _frame_packet(self, now: float) -> bytes:
        with self._lock:
            position, orientation = self._pose
        tracked = not self.tracking_lost
        if not tracked:
            position, orientation = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)
        if self.nan_pose:
            position = (math.nan,) * 3
        t = now - self._t0
        ticks = int(t * CLOCK_HZ)
        body = nn.RigidBody(self.body_id, position, orientation, 0.0002 if tracked else 0.0, tracked)
        frame = nn.Frame(self._frame_number, (body,), timestamp_s=t,
                         mid_exposure_ticks=ticks, data_received_ticks=ticks + CLOCK_HZ // 1000,
                         transmit_ticks=ticks + int(LATENCY_S * CLOCK_HZ),
                         precision_s=int(t), precision_fraction=int((t % 1.0) * 2 ** 32))
        return nn.pack_frame(frame, self.version, precision_in_4_0=self.precision_in_4_0)

    def _tick(self, now: float) -> None:
        if self.silent_stop:
            return
        with self._lock:
            fault = self._faults.popleft() if self._faults else None
        if fault == "gap":
            self._frame_number += 1          # one frame number never sent
        packet = self._frame_packet(now)
        self._frame_number += 1
        if fault == "truncate":
            packet = packet[:len(packet) // 2]
        if fault == "reorder":
            self._held = packet              # goes out after the next frame
            self.stats["faults:reorder"] += 1
            return
        self._stream(packet)
        if fault == "duplicate":
            self._stream(packet)
        if self._held is not None:
            self._stream(self._held)
            self._held = None
        if fault:
            self.stats[f"faults:{fault}"] += 1

    def _stream(self, packet: bytes) -> None:
        self.stats["frames_sent"] += 1
        if self.multicast:
            self._send(packet, (self.multicast_address, self.data_port))
            return
        for client in list(self.clients):
            self._send(packet, (client[0], self.data_port) if self.unicast_to_data_port else client)

    def _send(self, packet: bytes, to) -> None:
        try:
            self._sock.sendto(packet, to)
        except OSError:
            self.stats["send_errors"] += 1


def _parse_version(text: str) -> tuple:
    try:
        version = tuple(int(p) for p in text.split("."))[:2]
    except ValueError:
        version = ()
    if version not in nn.VERSIONS:
        raise argparse.ArgumentTypeError(
            f"NatNet version {text!r} is not one of {', '.join(f'{a}.{b}' for a, b in nn.VERSIONS)}")
    return version


def main(argv=None) -> int:
    """Runs an emulated Motive until Ctrl-C; prints what it serves."""
    parser = argparse.ArgumentParser(
        prog="python -m incipient_slip.devices.natnet_emulator",
        description="An emulated OptiTrack Motive NatNet server streaming one rigid body.")
    parser.add_argument("--version", type=_parse_version, default=(4, 1),
                        help="NatNet version to speak: 2.10, 3.1, 4.0, 4.1 or 4.2 (default 4.1)")
    parser.add_argument("--address", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument("--command-port", type=int, default=nn.DEFAULT_COMMAND_PORT,
                        help="command port (default 1510)")
    parser.add_argument("--data-port", type=int, default=nn.DEFAULT_DATA_PORT,
                        help="data port for multicast or --to-data-port (default 1511)")
    parser.add_argument("--multicast", action="store_true", help="stream to the multicast group")
    parser.add_argument("--to-data-port", action="store_true",
                        help="unicast frames to the client's data port instead of its command socket")
    parser.add_argument("--rate-hz", type=float, default=120.0, help="frame rate (default 120)")
    args = parser.parse_args(argv)
    server = NatNetEmulator(args.version, address=args.address, command_port=args.command_port,
                            data_port=args.data_port, multicast=args.multicast,
                            unicast_to_data_port=args.to_data_port, rate_hz=args.rate_hz)
    try:
        server.start()
    except OSError as exc:
        print(f"natnet_emulator: cannot serve on {args.address}:{args.command_port}: {exc}",
              file=sys.stderr)
        return 2
    print(f"natnet_emulator: NatNet {args.version[0]}.{args.version[1]} on "
          f"{args.address}:{server.command_port}, {args.rate_hz:g} Hz", file=sys.stderr, flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        return 0
    finally:
        server.stop()


if __name__ == "__main__":
    sys.exit(main())
