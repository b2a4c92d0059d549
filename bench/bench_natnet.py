"""NatNet benchmark: parse time per frame (ours vs the least any parser must do), and the
latency the motion-capture device path adds (mocap_bridge: UDP poll -> /object/pose callback).

* parse: `natnet.parse_frame` on the frame the emulator sends (one rigid body, every other
  block empty) for each NatNet version, timed in alternating blocks against a bare
  `struct.unpack_from` of the body's pose at its known offset (no checks, no other blocks):
  median time per frame over the blocks, with the spread (min..max of the block medians), and
  the ratio ours / bare.
* device path: the emulator (120 Hz, its own process) -> mocap_bridge (its own process) ->
  a subscriber here. The bridge stamps each pose with its receive time less the latency the
  frame's clock stamps report (4 ms in the emulator), so `callback time - stamp - 4 ms` is the
  time from the bridge reading the datagram to our callback (publish, ZeroMQ, decode); the
  bridge polls its sockets every `poll_s` (2 ms), which adds up to that much before it reads.
"""
from __future__ import annotations

import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
import timeit

from incipient_slip.devices import natnet as nn
from incipient_slip.devices.natnet_emulator import LATENCY_S
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import ObjectPose

BLOCKS, PER_BLOCK = 7, 5000
POSES = 600                      # 5 s at 120 Hz


def bench_parse() -> None:
    print("parse time per frame, us (median of 7 blocks, min..max):")
    for version in nn.VERSIONS:
        frame = nn.Frame(1, (nn.RigidBody(1, (0.01, 0.02, 0.03), (0.0, 0.0, 0.0, 1.0)),))
        payload = nn.split_packet(nn.pack_frame(frame, version))[1]
        offset = 4 + 2 * (8 if version >= (4, 1) else 4) + (8 if version >= (4, 1) else 4)
        pose = struct.Struct("<i3f4f")
        ours, bare = [], []
        for _ in range(BLOCKS):        # alternate, so machine noise hits both alike
            ours.append(timeit.timeit(lambda: nn.parse_frame(payload, version), number=PER_BLOCK) / PER_BLOCK)
            bare.append(timeit.timeit(lambda: pose.unpack_from(payload, offset), number=PER_BLOCK) / PER_BLOCK)
        o, b = statistics.median(ours) * 1e6, statistics.median(bare) * 1e6
        print(f"  NatNet {version[0]}.{version[1]}: ours {o:6.2f} ({min(ours)*1e6:.2f}..{max(ours)*1e6:.2f})"
              f"  bare {b:5.2f} ({min(bare)*1e6:.2f}..{max(bare)*1e6:.2f})  ratio {o / b:5.1f}")


class Probe(Node):
    def __init__(self, graph_dir):
        super().__init__("bench_probe", graph_dir=graph_dir, heartbeat_s=0)
        self.delays_ms: list[float] = []
        self.create_subscription(ObjectPose, self.on_pose)

    def on_pose(self, msg: ObjectPose):
        self.delays_ms.append((time.time_ns() - msg.stamp_ns) / 1e6 - LATENCY_S * 1e3)


def bench_device_path() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        command_port = s.getsockname()[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        data_port = s.getsockname()[1]
    graph_dir = tempfile.mkdtemp(prefix="bn", dir="/tmp")
    env = {"SLIP_GRAPH_DIR": graph_dir}
    import os
    env = dict(os.environ, **env)
    emulator = subprocess.Popen([sys.executable, "-m", "incipient_slip.devices.natnet_emulator",
                                 "--command-port", str(command_port), "--data-port", str(data_port)],
                                env=env, stderr=subprocess.PIPE)
    emulator.stderr.readline()          # serving
    bridge = subprocess.Popen([sys.executable, "-m", "incipient_slip.nodes.mocap_bridge",
                               f"command_port:={command_port}", f"data_port:={data_port}"],
                              env=env, stderr=subprocess.DEVNULL)
    probe = Probe(graph_dir)
    try:
        deadline = time.monotonic() + 60
        while len(probe.delays_ms) < POSES + 60 and time.monotonic() < deadline:
            probe.spin_once(0.01)
    finally:
        probe.close()
        for proc in (bridge, emulator):
            proc.terminate()
            proc.wait()
    d = sorted(probe.delays_ms[60:])   # the first half second is start-up
    q = statistics.quantiles(d, n=100)
    print(f"device path (bridge reads datagram -> subscriber callback), {len(d)} poses: "
          f"median {statistics.median(d):.3f} ms, p25..p75 {q[24]:.3f}..{q[74]:.3f} ms, p99 {q[98]:.3f} ms "
          f"(+ up to poll_s = 2 ms before the bridge reads)")


if __name__ == "__main__":
    bench_parse()
    bench_device_path()
